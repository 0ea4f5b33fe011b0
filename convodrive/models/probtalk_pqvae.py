"""ProbTalk's first stage, the PQ-VAE: conv encoder and decoder around a product quantiser (G
codebooks of K codes, EMA updates, dead codes reset to live encoder outputs)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.common import MASKED_ERRORS
from convodrive.models.probtalk_blocks import ResidualStack, conv_block
from convodrive.models.probtalk_config import ProbTalkConfig

VQ_NORM = nn.BatchNorm1d
"""The PQ-VAE's norm, the reference's batch norm: a fixed scale and shift once trained, so windows
decode alike at any length. Not ChannelNorm: normalising each frame over its channels (and
GroupNorm over a whole window) left the autoencoder at the mean motion (validation L1 0.43 after
300 steps, with or without quantisation, where batch norm or none reached 0.33-0.36 and still fell)."""


class MotionEncoder(nn.Module):
    """(B, T, D) motion -> (B, G*code_dim, T/8) latent."""

    def __init__(self, dim: int, config: ProbTalkConfig) -> None:
        super().__init__()
        ch, n = config.vq_channels, config.vq_layers
        layers: list[nn.Module] = [conv_block(dim, ch[0], norm=VQ_NORM), ResidualStack(ch[0], n, VQ_NORM)]
        for cin, cout in zip(ch[:-1], ch[1:]):
            layers += [conv_block(cin, cout, "down", norm=VQ_NORM), ResidualStack(cout, n, VQ_NORM)]
        layers.append(nn.Conv1d(ch[-1], config.groups * config.code_dim, 1))
        self.net = nn.Sequential(*layers)
        f = config.frames_per_token  # each token sees its 8 frames and half of each neighbour's
        self.linear = nn.Conv1d(dim, config.groups * config.code_dim, 2 * f, f, f // 2) if config.vq_skip else None

    def forward(self, motion: torch.Tensor) -> torch.Tensor:
        x = motion.transpose(1, 2)
        return self.net(x) if self.linear is None else self.net(x) + self.linear(x)


class OverlapAdd(nn.Module):
    """(B, C, T') -> (B, D, hop*T'): each token writes 2*hop frames faded in and out by a periodic Hann
    window, overlapping half of each neighbour's, so the windows sum to one and the output is
    continuous whatever the neighbouring codes. (Unwindowed kernels, or a token per hop frames,
    stepped at every border: the PQ-VAE's reconstruction moved twice as fast at one frame in 8.)"""

    def __init__(self, channels: int, dim: int, hop: int) -> None:
        super().__init__()
        self.conv = nn.ConvTranspose1d(channels, dim, 2 * hop, hop, hop // 2)
        self.register_buffer("window", torch.hann_window(2 * hop, periodic=True), persistent=False)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        conv = self.conv
        return F.conv_transpose1d(latent, conv.weight * self.window, conv.bias, conv.stride, conv.padding)


class MotionDecoder(nn.Module):
    """(B, G*code_dim, T') latent -> (B, 8T', D) motion."""

    def __init__(self, dim: int, config: ProbTalkConfig) -> None:
        super().__init__()
        ch, n = config.vq_channels[::-1], config.vq_layers
        layers: list[nn.Module] = [nn.Conv1d(config.groups * config.code_dim, ch[0], 1)]
        for cin, cout in zip(ch[:-1], ch[1:]):
            layers += [ResidualStack(cin, n, VQ_NORM), conv_block(cin, cout, "up", norm=VQ_NORM)]
        layers += [ResidualStack(ch[-1], n, VQ_NORM), nn.Conv1d(ch[-1], dim, 1)]
        self.net = nn.Sequential(*layers)
        self.linear = (
            OverlapAdd(config.groups * config.code_dim, dim, config.frames_per_token) if config.vq_skip else None
        )

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        y = self.net(latent) if self.linear is None else self.net(latent) + self.linear(latent)
        return y.transpose(1, 2)


DEAD_SHARE = 0.03
"""A code is dead below this fraction of a fair share of the latents (3 %: with EMA decay 0.99, a
code at a fair share that stops being chosen is dead after about 350 steps)."""


class ProductQuantizer(nn.Module):
    """G codebooks of K codes, each quantising its slice of the latent; EMA updates, dead-code reset.

    With ``vq_sphere`` slices and codes live on the unit sphere (cosine distance, as in ViT-VQGAN):
    with the reference's stacks alone, quantising the latent as it is let the commitment loss and
    the EMA shrink latents and codes together until a few codes served every latent. With
    ``vq_skip``'s linear path the dead-code reset keeps every code in use off the sphere too (all
    4 x 128 at step 1000), and the slices keep their length, the motion's amplitude.

    A code is dead when its running usage (EMA of how many latents chose it per step) falls below
    ``DEAD_SHARE`` of a fair share (latents per step / K); it is replaced by a random latent of the
    current batch with a fair share of usage, so no code stays unused and a replaced code keeps its
    place for hundreds of steps. (A fixed threshold of one latent per step replaced every code left
    unchosen for a single step, over and over at small batches: codes churned, meant nothing, and
    the decoder learnt to ignore them.) The first update draws every code from the batch. Under
    DDP the usage statistics are summed over processes and process 0's resets are broadcast, so
    every process keeps the same codebooks.
    """

    def __init__(self, config: ProbTalkConfig) -> None:
        super().__init__()
        g, k, d = config.groups, config.codes, config.code_dim
        self.groups, self.codes, self.dim = g, k, d
        self.decay, self.eps, self.sphere = config.ema_decay, 1e-5, config.vq_sphere
        self.register_buffer("codebooks", F.normalize(torch.randn(g, k, d), dim=-1))
        self.register_buffer("usage", torch.zeros(g, k))
        self.register_buffer("sums", torch.zeros(g, k, d))
        self.updating = True
        """Update the codebooks in training mode (False once a later stage freezes the VQ)."""

    def split(self, latent: torch.Tensor) -> torch.Tensor:
        """(B, G*d, T') -> (B, T', G, d) slices, unit vectors with ``vq_sphere``."""
        b, _, t = latent.shape
        z = latent.transpose(1, 2).reshape(b, t, self.groups, self.dim)
        return F.normalize(z, dim=-1) if self.sphere else z

    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """(B, T', G, d) latents -> (B, T', G) indices of the nearest code of each group's book."""
        books = self.codebooks  # (G, K, d)
        dist = (
            z.pow(2).sum(-1, keepdim=True)
            - 2 * torch.einsum("btgd,gkd->btgk", z, books)
            + books.pow(2).sum(-1)  # (G, K) broadcasts over (B, T')
        )
        return dist.argmin(-1)

    def lookup(self, codes: torch.Tensor) -> torch.Tensor:
        """(B, T', G) indices -> (B, G*d, T') quantised latent."""
        b, t, g = codes.shape
        group = torch.arange(g, device=codes.device).expand(b, t, g)
        q = self.codebooks[group, codes]  # (B, T', G, d)
        return q.reshape(b, t, g * self.dim).transpose(1, 2)

    def forward(
        self, latent: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Quantised latent (straight-through gradients), codes (B, T', G) and the commitment MSE."""
        z = self.split(latent)
        if self.training and self.updating:
            self._update(z.detach(), generator)
        codes = self.nearest(z.detach())
        q = self.lookup(codes)
        slices = z.flatten(2).transpose(1, 2)  # (B, G*d, T'), as the codes see them
        commitment = F.mse_loss(slices, q.detach())
        return slices + (q - slices).detach(), codes, commitment

    @torch.no_grad()
    def _update(self, z: torch.Tensor, generator: torch.Generator | None) -> None:
        flat = z.reshape(-1, self.groups, self.dim).transpose(0, 1)  # (G, N, d)
        onehot = F.one_hot(self.nearest(z).reshape(-1, self.groups).T, self.codes).to(z.dtype)  # (G, N, K)
        counts, sums = onehot.sum(1), torch.einsum("gnk,gnd->gkd", onehot, flat)
        distributed = torch.distributed.is_available() and torch.distributed.is_initialized()
        if distributed:
            torch.distributed.all_reduce(counts)
            torch.distributed.all_reduce(sums)
        first = bool(self.usage.sum() == 0)
        self.usage.mul_(self.decay).add_(counts, alpha=1 - self.decay)
        self.sums.mul_(self.decay).add_(sums, alpha=1 - self.decay)
        total = self.usage.sum(-1, keepdim=True)
        smoothed = (self.usage + self.eps) / (total + self.codes * self.eps) * total  # Laplace smoothing
        centroids = self.sums / smoothed.unsqueeze(-1)
        self.codebooks.copy_(F.normalize(centroids, dim=-1) if self.sphere else centroids)
        fair = (total / self.codes).expand_as(self.usage)
        dead = torch.ones_like(self.usage, dtype=torch.bool) if first else self.usage < DEAD_SHARE * fair
        if dead.any():
            n = flat.shape[1]
            pick = torch.randint(n, (self.groups, self.codes), generator=generator, device="cpu").to(flat.device)
            fresh = torch.gather(flat, 1, pick.unsqueeze(-1).expand(-1, -1, self.dim))
            self.codebooks[dead] = fresh[dead]
            self.usage[dead] = fair[dead]  # a fair share: hundreds of steps to be chosen before it counts as dead
            self.sums[dead] = fresh[dead] * fair[dead].unsqueeze(-1)
        if distributed:
            for buffer in (self.codebooks, self.usage, self.sums):
                torch.distributed.broadcast(buffer, 0)


class PQVAE(nn.Module):
    def __init__(self, dim: int, config: ProbTalkConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = MotionEncoder(dim, config)
        self.quantizer = ProductQuantizer(config)
        self.decoder = MotionDecoder(dim, config)

    def encode(self, motion: torch.Tensor) -> torch.Tensor:
        """(B, T, D) -> (B, T/8, G) codes."""
        return self.quantizer.nearest(self.quantizer.split(self.encoder(motion)))

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """(B, T', G) codes -> (B, 8T', D) motion."""
        return self.decoder(self.quantizer.lookup(codes))

    def forward(
        self, motion: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reconstruction, codes and commitment loss of (B, T, D) motion, T a multiple of 8."""
        quantised, codes, commitment = self.quantizer(self.encoder(motion), generator)
        return self.decoder(quantised), codes, commitment

    def loss(
        self,
        motion: torch.Tensor,
        mask: torch.Tensor,
        generator: torch.Generator | None = None,
        weight: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The paper's reconstruction + velocity error + beta * commitment (+ the acceleration error
        when ``acceleration_weight`` is set); ``mask`` (B, 1, D) skips
        the channels a corpus lacks, ``weight`` (D,) weighs the others (None: alike). The paper's
        error is L1; ``vq_loss="l2"`` squares it instead."""
        recon, codes, commitment = self(motion * mask, generator)
        error = MASKED_ERRORS[self.config.vq_loss]
        counted = mask if weight is None else mask * weight
        rec = error(recon, motion, counted)
        vel = error(recon.diff(dim=1), motion.diff(dim=1), counted)
        total = rec + self.config.velocity_weight * vel + self.config.commitment * commitment
        figures = {self.config.vq_loss: rec, "velocity": vel, "commitment": commitment}
        if self.config.acceleration_weight:
            acc = error(recon.diff(n=2, dim=1), motion.diff(n=2, dim=1), counted)
            total = total + self.config.acceleration_weight * acc
            figures["acceleration"] = acc
        used = sum(codes[..., g].unique().numel() for g in range(codes.shape[-1])) / codes.shape[-1]
        return total, {**figures, "codes_used": torch.tensor(float(used))}
