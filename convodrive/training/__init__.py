"""Training: the bootstrap corpus maker, datasets over a corpus, training loops, checkpoints, export.

One loop (``loop.py``, one process or DDP) trains any registered recipe (``registry.py``); a
recipe (``recipe.py``) says how to read its data, build its network, compute its loss, validate
and export. Checkpoints are safetensors plus JSON (``checkpoint.py``); ``export.py`` writes the
ONNX model folders that ``convodrive.neural`` reads. Modules that need torch import it
themselves; importing this package does not, so the corpus maker runs without torch.
"""
