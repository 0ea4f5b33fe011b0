"""FGD (Fréchet Gesture Distance): Fréchet distance of motion-autoencoder features, per part.

The embedder is an exported ``fgd`` model folder (``convodrive train fgd`` then ``export``); the
package ships one trained on a bootstrap corpus (``fgd_model/``, made by scripts/train_fgd.sh).
Motion is cut into non-overlapping windows of the embedder's length (ProbTalk: 90 frames),
normalised with the embedder's own statistics, and embedded in ONNX Runtime (no torch).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from convodrive.eval.distribution import frechet_distance
from convodrive.motion import representation as rep
from convodrive.neural import Graph, SessionOptions, load_model_folder
from convodrive.plumbing.errors import InputFileError

SHIPPED = Path(__file__).with_name("fgd_model")
PARTS = ("holistic", "body", "face")


class FGDEmbedder:
    def __init__(self, folder: str | Path | None = None, threads: int = 1) -> None:
        self.folder = load_model_folder(folder or SHIPPED)
        if self.folder.model != "fgd":
            raise InputFileError(self.folder.path, f"holds a '{self.folder.model}' model, not an FGD embedder")
        self.window = int(self.folder.spec["features"]["window"])
        norm = self.folder.arrays("normalisation.npz")
        self.mean, self.std = norm["mean"], norm["std"]
        options = SessionOptions(threads=threads, device="cpu")
        self.graphs = {p: Graph(self.folder.graph_path(f"encoder_{p}"), options) for p in PARTS}

    def windows(self, features: np.ndarray) -> np.ndarray:
        """(N, window, D) normalised non-overlapping windows of one (T, D) raw feature sequence."""
        n = len(features) // self.window
        cut = np.asarray(features[: n * self.window], np.float32)
        return ((cut - self.mean) / self.std).reshape(n, self.window, rep.FEATURE_DIM).astype(np.float32)

    def embed(self, sequences: list[np.ndarray], masks: list[np.ndarray], part: str) -> np.ndarray:
        """(windows, latent) features of every window of every (T, D) raw sequence."""
        out = []
        for seq, mask in zip(sequences, masks):
            w = self.windows(seq)
            if len(w):
                m = np.broadcast_to(np.asarray(mask, np.float32)[None, None, :], (len(w), 1, rep.FEATURE_DIM)).copy()
                out.append(self.graphs[part](motion=w, mask=m)["features"])
        return np.concatenate(out) if out else np.zeros((0, 1), np.float32)

    def fgd(
        self, generated: list[np.ndarray], real: list[np.ndarray], masks: list[np.ndarray], part: str
    ) -> float | None:
        a, b = self.embed(generated, masks, part), self.embed(real, masks, part)
        return frechet_distance(a, b) if len(a) >= 2 and len(b) >= 2 else None
