"""What the motion networks here share: masked errors, a differentiable Fréchet distance, the audio standardiser.

Torch is for training and export only.
"""

from __future__ import annotations

import torch
from torch import nn


def masked_l1(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Mean |a - b| over the entries ``weight`` (broadcast to a's shape) keeps, weighted by its values."""
    weight = weight.expand_as(a)
    return ((a - b).abs() * weight).sum() / weight.sum().clamp(min=1.0)


def masked_l2(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Mean (a - b)^2 over the entries ``weight`` (broadcast to a's shape) keeps, weighted by its values."""
    weight = weight.expand_as(a)
    return ((a - b).square() * weight).sum() / weight.sum().clamp(min=1.0)


MASKED_ERRORS = {"l1": masked_l1, "l2": masked_l2}
"""The masked errors by the names a config gives them (``vq_loss``, ``refiner_loss``)."""


def frechet_loss(made: torch.Tensor, real: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """The Fréchet distance (FD_g's formula, ``convodrive.eval.distribution``) between Gaussians
    fitted to the rows of ``made`` (N, D) and ``real`` (M, D), differentiable in ``made``.

    A per-frame error is lowest at the conditional mean, which shrinks brief shapes that the
    condition does not pin down; this term asks for the data's spread and its correlations too.
    tr sqrt(Sa Sb) is the sum of the square roots of the eigenvalues of Sb^1/2 Sa Sb^1/2 (symmetric,
    so ``eigvalsh``'s gradient holds); each root is taken as sqrt(x + eps) - sqrt(eps), so that its
    gradient stays finite at the zero eigenvalues of channels that move together (a blink's two
    lids); that raises the distance by at most 2 sqrt(eps) a channel. In float64: the eigenvalues span several decades."""
    a, b = made.double(), real.double().detach()
    mean_a, mean_b = a.mean(0), b.mean(0)
    cov_a, cov_b = torch.cov(a.T), torch.cov(b.T)
    values, vectors = torch.linalg.eigh(cov_b)
    root_b = (vectors * values.clamp(min=0.0).sqrt()) @ vectors.T
    products = torch.linalg.eigvalsh(root_b @ cov_a @ root_b).clamp(min=0.0)
    cross = ((products + eps).sqrt() - eps**0.5).sum()
    distance = (mean_a - mean_b).square().sum() + cov_a.trace() + cov_b.trace() - 2.0 * cross
    return distance.to(made.dtype)


class AudioNorm(nn.Module):
    """Log-mel (B, frames, voices, bands) to zero mean and unit spread per band, with the train
    split's statistics (buffers, so that they travel with the weights into every export).

    ``flatten_voices`` joins the voices into one vector per frame (B, frames, voices * bands), for
    networks that read both voices through one projection.
    """

    def __init__(self, bands: int, *, flatten_voices: bool = False) -> None:
        super().__init__()
        self.flatten_voices = flatten_voices
        self.register_buffer("mean", torch.zeros(bands))
        self.register_buffer("std", torch.ones(bands))

    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        standard = (audio - self.mean) / self.std
        return standard.flatten(2) if self.flatten_voices else standard
