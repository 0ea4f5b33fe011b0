"""Training: the bootstrap corpus maker, datasets over a corpus, training loops, checkpoints, export.

Modules that need torch import it themselves; importing this package does not, so the corpus
maker runs without torch.
"""
