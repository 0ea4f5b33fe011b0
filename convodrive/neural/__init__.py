"""The ONNX Runtime side of learned models: model folders, sessions, streaming windows (NumPy only).

Everything a run loads for a learned generator comes from here; torch never does (docs/ARCHITECTURE.md,
"The runtime is torch-free"). Training and export live in ``convodrive.training``.
"""

from convodrive.neural.folder import MODEL_FORMAT, MODEL_FORMAT_VERSION, ModelFolder, load_model_folder, sha256_file
from convodrive.neural.session import Graph, SessionOptions, available_devices

__all__ = [
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
    "Graph",
    "ModelFolder",
    "SessionOptions",
    "available_devices",
    "load_model_folder",
    "sha256_file",
]
