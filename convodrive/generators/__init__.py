"""Generator plugins: conversation audio to canonical motion."""
