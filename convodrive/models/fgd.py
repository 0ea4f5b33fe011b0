"""The motion autoencoder behind FGD (Fréchet Gesture Distance), after ProbTalk's evaluator.

ProbTalk measures FGD with features of a convolutional autoencoder trained on the data set: it
reads non-overlapping 90-frame windows of the normalised motion vector and embeds each in 128
dimensions, with three separate networks for the face, the body and the whole (holistic).

Ours keeps that shape (conv encoder over a fixed window, a linear bottleneck, a mirrored decoder)
and leaves out batch normalisation, so that training with N processes equals training with one.
Masked input channels (those a corpus lacks) are zeroed on the way in and skipped by the loss.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn


@dataclasses.dataclass(frozen=True)
class FGDConfig:
    window: int = 90
    """Frames per embedded window (ProbTalk: 90, 3 s)."""
    latent: int = 128
    """Feature size (ProbTalk: 128)."""
    channels: int = 64
    """Width of the first conv layer; the second and third double it."""
    velocity_weight: float = 1.0
    """Weight of the frame-to-frame velocity term of the reconstruction loss."""


def _block(cin: int, cout: int, stride: int) -> nn.Sequential:
    kernel = 4 if stride == 2 else 3
    return nn.Sequential(nn.Conv1d(cin, cout, kernel, stride=stride, padding=1), nn.LeakyReLU(0.2))


def _up(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.ConvTranspose1d(cin, cout, 4, stride=2, padding=1), nn.LeakyReLU(0.2))


class MotionAutoencoder(nn.Module):
    """(B, window, dims) normalised motion -> (B, latent) features -> (B, window, dims) motion."""

    def __init__(self, dims: int, config: FGDConfig) -> None:
        super().__init__()
        c = config.channels
        self.dims, self.window = dims, config.window
        self.reduced = config.window // 4  # two stride-2 convs: floor(floor(w / 2) / 2)
        self.encoder = nn.Sequential(
            _block(dims, c, 1), _block(c, 2 * c, 2), _block(2 * c, 2 * c, 1), _block(2 * c, 4 * c, 2)
        )
        self.to_latent = nn.Sequential(
            nn.Flatten(), nn.Linear(4 * c * self.reduced, 4 * c), nn.LeakyReLU(0.2), nn.Linear(4 * c, config.latent)
        )
        self.from_latent = nn.Sequential(nn.Linear(config.latent, 4 * c * self.reduced), nn.LeakyReLU(0.2))
        self.decoder = nn.Sequential(
            _up(4 * c, 2 * c), _block(2 * c, 2 * c, 1), _up(2 * c, c), nn.Conv1d(c, dims, 3, padding=1)
        )
        self._channels = 4 * c

    def encode(self, motion: torch.Tensor) -> torch.Tensor:
        return self.to_latent(self.encoder(motion.transpose(1, 2)))

    def decode(self, latent: torch.Tensor) -> torch.Tensor:
        h = self.from_latent(latent).view(-1, self._channels, self.reduced)
        out = self.decoder(h)  # 4 * reduced frames: the window, less its remainder modulo 4
        if out.shape[-1] != self.window:
            out = nn.functional.interpolate(out, size=self.window, mode="linear", align_corners=False)
        return out.transpose(1, 2)

    def forward(self, motion: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(motion))


class FGDNetworks(nn.Module):
    """One autoencoder per part (``holistic``, ``body``, ``face``), each reading its own feature slice."""

    def __init__(self, parts: dict[str, list[int]], config: FGDConfig) -> None:
        super().__init__()
        self.config = config
        self.parts = {name: list(index) for name, index in parts.items()}
        for name, index in self.parts.items():
            self.register_buffer(f"index_{name}", torch.tensor(index, dtype=torch.long), persistent=False)
        self.nets = nn.ModuleDict({name: MotionAutoencoder(len(index), config) for name, index in self.parts.items()})

    def part_input(self, name: str, motion: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        index = getattr(self, f"index_{name}")
        part_mask = mask.index_select(-1, index)
        return motion.index_select(-1, index) * part_mask, part_mask

    def reconstruction_loss(
        self, motion: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Masked MSE of positions and velocities, summed over the parts. ``mask``: (B, 1, dims) of 0/1."""
        total = motion.new_zeros(())
        figures = {}
        for name, net in self.nets.items():
            x, m = self.part_input(name, motion, mask)
            y = net(x)
            weight = m.expand_as(x)
            count = weight.sum().clamp(min=1.0)
            pos = ((y - x) ** 2 * weight).sum() / count
            vel_w = weight[:, 1:]
            vel = (((y[:, 1:] - y[:, :-1]) - (x[:, 1:] - x[:, :-1])) ** 2 * vel_w).sum() / vel_w.sum().clamp(min=1.0)
            figures[f"{name}_mse"] = pos.detach()
            total = total + pos + self.config.velocity_weight * vel
        return total, figures


class PartEncoder(nn.Module):
    """The exported graph of one part: masked motion windows -> features."""

    def __init__(self, networks: FGDNetworks, name: str) -> None:
        super().__init__()
        self.networks, self.name = networks, name

    def forward(self, motion: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x, _ = self.networks.part_input(self.name, motion, mask)
        return self.networks.nets[self.name].encode(x)
