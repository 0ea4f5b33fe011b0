"""``probtalk``: ProbTalk's PQ-VAE, MaskGIT predictor and refiner (``generator.py``), its shipped
weights in ``model/`` (scripts/train_probtalk.sh)."""
