"""A probtalk model folder's PQ-VAE decoder and codebooks, read back from its ONNX graph into torch.

The vq stage with ``vq_decoder_from`` fits a new encoder to them: the refiner learns to correct
the decoder it runs after, so a refiner retrained for shipped weights whose torch checkpoints are
gone needs that decoder's reconstructions of the true codes. Export folds each batch norm into the
convolution before it; read back, the norms are set to the identity (zero mean, unit variance, no
scale or shift) and the folded weights go to the convolutions. A parity check against ONNX
Runtime says whether the graph was read right.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from convodrive.models.probtalk_pqvae import PQVAE
from convodrive.neural.folder import load_model_folder
from convodrive.plumbing.errors import UserError
from convodrive.training.staged import check_same_data

PREFIX = "owner.vq.decoder."
"""Export's name for the decoder's weights (``GraphModule`` holds the model as ``owner``)."""
PARITY_TOLERANCE = 1e-4
FOLDER_NORMALISATION = ("mean", "std")
"""The normalisation a model folder keeps (the audio's is inside its graphs)."""


def load_exported_decoder(folder: str | Path, vq: PQVAE, normalisation: dict[str, np.ndarray]) -> float:
    """Set ``vq``'s decoder and codebooks to those of ``folder``'s graph; returns the parity (max
    abs difference of decoded random codes against ONNX Runtime). The folder's motion
    normalisation must be this corpus's (``normalisation``: the run's data spec arrays)."""
    import onnx
    from onnx import numpy_helper

    found = load_model_folder(folder)  # every file's sha256 checked
    path, theirs = found.graph_path("vq_decoder"), found.arrays("normalisation.npz")
    check_same_data(theirs, normalisation, f"vq_decoder_from={folder}", FOLDER_NORMALISATION)
    try:
        graph = onnx.load(str(path)).graph
    except Exception as exc:  # noqa: BLE001 - protobuf's decode errors are no OSError
        raise UserError(f"{path}: cannot read the ONNX graph ({exc})") from None
    arrays = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    q = vq.quantizer
    books = [a for a in arrays.values() if a.shape == (q.groups, q.codes, q.dim)]
    own = vq.decoder.state_dict()
    buffers = {name for name, _ in vq.decoder.named_buffers()} - set(own)  # not saved: made, not learnt
    weights = {
        k[len(PREFIX) :]: a for k, a in arrays.items() if k.startswith(PREFIX) and k[len(PREFIX) :] not in buffers
    }
    stray = sorted(set(weights) - set(own))
    if len(books) != 1 or stray or any(tuple(own[k].shape) != a.shape for k, a in weights.items()):
        raise UserError(f"{path}: its decoder does not fit this config's PQ-VAE (other groups, codes or channels)")
    state = {k: torch.from_numpy(np.array(a)) for k, a in weights.items()}
    for key, value in own.items():
        if key not in state:
            state[key] = _identity_norm(key, value, vq)
    vq.decoder.load_state_dict(state)
    q.codebooks.copy_(torch.from_numpy(np.array(books[0])))
    worst = decoder_parity(path, vq)
    if not worst <= PARITY_TOLERANCE:
        raise UserError(f"{path}: read back, the decoder differs from the graph by {worst:.3g}")
    return worst


def _identity_norm(key: str, value: torch.Tensor, vq: PQVAE) -> torch.Tensor:
    """A folded batch norm's tensors, so that it passes its input through."""
    eps = next(m.eps for n, m in vq.decoder.named_modules() if key.startswith(f"{n}.") and hasattr(m, "eps"))
    name = key.rsplit(".", 1)[-1]
    if name == "running_var":
        return torch.full_like(value, 1.0 - eps)  # sqrt(var + eps) = 1
    if name == "weight":
        return torch.ones_like(value)
    if name == "num_batches_tracked":
        return value
    return torch.zeros_like(value)  # bias, running_mean


def decoder_parity(path: Path, vq: PQVAE, tokens: int = 23, seed: int = 0) -> float:
    import onnxruntime as ort

    q = vq.quantizer
    codes = np.random.default_rng(seed).integers(0, q.codes, (2, tokens, q.groups)).astype(np.int64)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (theirs,) = session.run(None, {"codes": codes})
    training = vq.training
    vq.eval()
    with torch.no_grad():
        mine = vq.decode(torch.from_numpy(codes)).numpy()
    vq.train(training)
    return float(np.abs(mine - theirs).max())
