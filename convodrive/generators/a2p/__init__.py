"""``a2p``: audio2photoreal's face and body diffusion with guide poses (``generator.py``), its
shipped weights in ``model/`` (scripts/train_a2p.sh)."""
