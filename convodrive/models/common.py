"""The two pieces every motion network here shares: masked errors and the audio standardiser.

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
