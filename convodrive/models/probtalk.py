"""ProbTalk (Liu et al., CVPR 2024): holistic co-speech motion in three stages, one readable file.

1. **PQ-VAE.** A conv encoder with three stride-2 steps turns 8 frames of motion into one token;
   its latent is split into G groups, each quantised with its own codebook of K codes (product
   quantisation: K**G combinations for the memory of G*K codes), updated by EMA with dead codes
   reset to live encoder outputs; a mirrored conv decoder turns codes back into motion.
2. **Predictor.** A transformer over the (token x group) grid of codes, with a 2D sinusoidal
   position (time encoding + group encoding), cross-attending to a memory of the conditions (the
   audio and the known motion context, both brought to token rate by conv encoders); the speaker
   modulates every sub-layer through adaptive layer norm. Trained MaskGIT-style (random cosine
   mask ratio, cross-entropy on the masked codes); sampled by ``maskgit_sample`` in T passes.
3. **Refiner.** A transformer over frames that takes the decoded coarse motion (known frames
   copied in), the audio and the known-frame mask, and returns the motion with the detail that
   quantisation lost (the jaw following syllables, blinks).

Beyond the paper: the partner's log-mel is a second audio stream (``dyadic``), so listening
behaviour is learned too; the speaker's modulation and each layer's cross-attention keys and
values depend only on the window's conditions, so ``Predictor.memory`` computes them once per
window and ``Predictor.logits`` reuses them in every MaskGIT pass (the runtime exports the two as
separate graphs). Batch norm only in the PQ-VAE (``VQ_NORM``, the reference's; its running
statistics make it a fixed affine map at run time); the predictor and refiner use channel-wise layer
norm, so nothing depends on the batch at run time.

Shapes: motion (B, frames, D) normalised features (``convodrive.motion.representation``), audio
(B, frames, 2, bands) log-mel of self and partner, codes (B, tokens, G), tokens flattened
time-major (t0g0, t0g1, ..., t1g0, ...) to (B, tokens*G). Torch is for training and export only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.common import AudioNorm, masked_l1, masked_l2


@dataclasses.dataclass(frozen=True)
class ProbTalkConfig:
    """Hyper-parameters; defaults are the reference implementation's (the ``paper`` preset)."""

    # PQ-VAE
    groups: int = 4
    """G: sub-codebooks, one per slice of the latent."""
    codes: int = 128
    """K: codes per sub-codebook."""
    code_dim: int = 128
    """Dimensions of one group's slice of the latent."""
    vq_channels: tuple[int, ...] = (256, 256, 512, 1024)
    """Encoder widths: after the input projection, then after each stride-2 step (3 steps: 8 frames a token)."""
    vq_layers: int = 2
    """Conv layers in each residual stack of the encoder and decoder."""
    vq_skip: bool = False
    """A linear path beside the encoder's and the decoder's conv stacks: one conv over each token's 8
    frames and half of each neighbour's, and back by ``OverlapAdd`` (so no steps at token borders),
    added to the stack's output (False: the stacks alone, the reference's). Without it the
    small preset's stacks underfit: trained without quantisation for 1000 steps they reconstruct
    the test split at FD_g body 38.8, where that linear path alone reaches 0.31."""
    vq_sphere: bool = True
    """Quantise each group's slice as a unit vector, by cosine distance (False: as it is, by
    Euclidean distance). The sphere drops each slice's length, which is most of the motion's
    amplitude for a near-linear encoder: with ``vq_skip`` and the small preset's stacks, 1000 steps
    reconstruct the test split (quantised) at FD_g body 15.8 on the sphere and 9.8 off it."""
    commitment: float = 0.25
    ema_decay: float = 0.99
    velocity_weight: float = 1.0
    acceleration_weight: float = 0.0
    """Weight of the PQ-VAE's error on the second difference (0: none, the paper's). The velocity
    term alone left the small preset's reconstruction shivering (5.8 times the corpus's body
    acceleration on the test split): the second difference weighs that frame-to-frame noise four
    times as much as the first does."""
    vq_loss: str = "l1"
    """Reconstruction and velocity error of the PQ-VAE: ``l1`` (the paper's) or ``l2`` (squared)."""
    balance_parts: bool = False
    """Weigh every part of the feature layout alike in the PQ-VAE's and the refiner's error, however many
    channels it has (False: every channel alike, the paper's). Channel-alike lets 180 hand channels
    outvote 12 of the head: the codes go to the hands and the head is left at its mean."""
    eyelid_part: bool = False
    """With ``balance_parts``: the eyelids (eyeBlinkLeft, eyeBlinkRight) count as a part of their own,
    not as 2 of ARKit's 52 channels. Blinks fill 1 frame in 60; weighed as 2 channels of 52 the
    PQ-VAE left them out (its reconstruction's lids never passed a third of the real blink's
    height), and so the sampled codes never blinked. FD_g face of the real validation motion with
    its blinks taken out: 6.7."""
    spine_part: bool = False
    """With ``balance_parts``: spine1..3 (the first 18 channels of the upper body) count as a part of
    their own. Their motion is slow posture drift and breathing, a few hundredths of a radian; as 18
    of the upper body's 66 channels the PQ-VAE left them at their mean, which alone cost 13 of its
    reconstruction's 22.6 FD_g body on the validation split (9.5 without them). Weighed as a part
    (small preset, seed 0) it helped little: validation recon FD_g body 28.7 against 32.0 at step
    3000 of 8000, face 9.7 against 9.2, the spine still about 11 of the body's FD at step 2300; off
    in the presets."""
    # conditions
    dyadic: bool = True
    """Hear the partner's audio as a second stream (False: self only, to measure what it adds)."""
    audio_channels: int = 256
    context_channels: tuple[int, ...] = (128, 128, 256, 512)
    """Motion-context encoder widths: first layer, then after each stride-2 step."""
    # predictor
    width: int = 512
    heads: int = 8
    layers: int = 6
    feedforward: int = 2048
    position: str = "2d"
    """``2d``: time encoding + group encoding of each code (the paper's); ``1d``: one encoding of the flat index."""
    # refiner
    refiner_width: int = 512
    refiner_heads: int = 8
    refiner_layers: int = 6
    refiner_feedforward: int = 2048
    refiner_noise: float = 0.05
    """Noise added to the VQ reconstructions the refiner learns to refine (the reference's 0.05)."""
    speaker_dim: int = 512
    """Size of the speaker embedding that modulates every sub-layer."""
    dropout: float = 0.1
    # training windows
    window: int = 184
    """Frames per training window (a multiple of 8: 23 tokens, the paper's 180 frames rounded up)."""
    min_window: int = 48
    """Shortest random crop, so the short windows of ``live`` mode are seen in training."""
    context_frames: int = 30
    """Known frames of the reference's context masks (and of the ``file`` mode's windows)."""

    @property
    def frames_per_token(self) -> int:
        return 2 ** (len(self.vq_channels) - 1)

    @property
    def mask_id(self) -> int:
        """The token id of a masked code (one past the last code)."""
        return self.codes

    def check(self) -> None:
        """ValueError naming the first inconsistent setting."""
        if len(self.vq_channels) < 2 or len(self.context_channels) != len(self.vq_channels):
            raise ValueError("vq_channels and context_channels need the same length, at least 2")
        if self.width % self.heads or self.refiner_width % self.refiner_heads:
            raise ValueError("width must be a multiple of heads (predictor and refiner)")
        if self.vq_loss not in ("l1", "l2"):
            raise ValueError(f"vq_loss must be 'l1' or 'l2', got {self.vq_loss!r}")
        if self.position not in ("2d", "1d"):
            raise ValueError(f"position must be '2d' or '1d', got {self.position!r}")
        f = self.frames_per_token
        if self.window % f or self.min_window % f or not f <= self.min_window <= self.window:
            raise ValueError(f"window and min_window must be multiples of {f} with min_window <= window")
        if not 0 <= self.context_frames < self.window:
            raise ValueError("context_frames must be below window")


# --------------------------------------------------------------------------------------- blocks
class ChannelNorm(nn.Module):
    """Layer norm over the channels of (B, C, T), frame by frame: no batch statistics."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.norm(x.transpose(1, 2)).transpose(1, 2)


def conv_block(
    cin: int, cout: int, kind: str = "same", kernel: int = 3, norm: Callable[[int], nn.Module] = ChannelNorm
) -> nn.Sequential:
    """Conv, norm, LeakyReLU(0.2). ``down``: stride 2 (kernel 4); ``up``: transposed, stride 2."""
    if kind == "down":
        conv: nn.Module = nn.Conv1d(cin, cout, 4, stride=2, padding=1)
    elif kind == "up":
        conv = nn.ConvTranspose1d(cin, cout, 4, stride=2, padding=1)
    else:
        conv = nn.Conv1d(cin, cout, kernel, padding=kernel // 2)
    return nn.Sequential(conv, norm(cout), nn.LeakyReLU(0.2))


class ResidualStack(nn.Module):
    """``layers`` conv blocks and a conv, added to the input (the reference's Res_CNR_Stack)."""

    def __init__(self, channels: int, layers: int, norm: Callable[[int], nn.Module] = ChannelNorm) -> None:
        super().__init__()
        self.body = nn.Sequential(
            *[conv_block(channels, channels, norm=norm) for _ in range(layers)],
            nn.Conv1d(channels, channels, 3, padding=1),
            norm(channels),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(x + self.body(x), 0.2)


class GatedConv(nn.Module):
    """tanh(a) * sigmoid(b) of one conv's two halves, plus a residual 1x1 (PixelCNN's gate, as in
    the reference's motion-context encoder); ``stride`` 2 halves the frames."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1) -> None:
        super().__init__()
        pad = (kernel - stride) // 2 if stride > 1 else kernel // 2
        self.conv = nn.Conv1d(cin, 2 * cout, kernel, stride=stride, padding=pad)
        self.skip = nn.Conv1d(cin, cout, 1, stride=stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = self.conv(x).chunk(2, dim=1)
        return self.skip(x) + torch.tanh(a) * torch.sigmoid(b)


def sinusoid(positions: torch.Tensor, dim: int) -> torch.Tensor:
    """(..., dim) sine/cosine encodings of (...) positions (Vaswani et al.), computed, not tabled,
    so exported graphs take any length."""
    half = torch.arange(dim // 2, device=positions.device, dtype=torch.float32)
    freq = torch.exp(half * (-math.log(10000.0) * 2.0 / dim))
    angle = positions.to(torch.float32).unsqueeze(-1) * freq
    return torch.stack([angle.sin(), angle.cos()], dim=-1).flatten(-2)


# --------------------------------------------------------------------------------------- PQ-VAE
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
        error = masked_l1 if self.config.vq_loss == "l1" else masked_l2
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


# ---------------------------------------------------------------------------------- transformer
class SelfAttention(nn.Module):
    def __init__(self, width: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.heads, self.dropout = heads, dropout
        self.qkv = nn.Linear(width, 3 * width)
        self.out = nn.Linear(width, width)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, c = x.shape
        q, k, v = self.qkv(x).view(b, n, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.out(y.transpose(1, 2).reshape(b, n, c))


class CrossAttention(nn.Module):
    """Attention from the sequence to a memory whose keys and values (``kv``) are computed once
    per window and reused for every pass over it."""

    def __init__(self, width: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.heads, self.dropout = heads, dropout
        self.q = nn.Linear(width, width)
        self.kv_proj = nn.Linear(width, 2 * width)
        self.out = nn.Linear(width, width)

    def kv(self, memory: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, M, C) memory -> keys and values (B, heads, M, C/heads)."""
        b, m, c = memory.shape
        k, v = self.kv_proj(memory).view(b, m, 2, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        return k, v

    def forward(self, x: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        b, n, c = x.shape
        q = self.q(x).view(b, n, self.heads, c // self.heads).transpose(1, 2)
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.out(y.transpose(1, 2).reshape(b, n, c))


def modulate(x: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Adaptive layer norm: normalise, then scale and shift by the speaker's (B, C) values."""
    return F.layer_norm(x, x.shape[-1:]) * (1 + scale.unsqueeze(1)) + shift.unsqueeze(1)


class Layer(nn.Module):
    """Self-attention, cross-attention to the conditions, feed-forward; pre-norm, each norm
    modulated by the speaker (the paper's AdaIN after every sub-layer, as adaptive layer norm)."""

    def __init__(self, width: int, heads: int, feedforward: int, dropout: float, style_dim: int) -> None:
        super().__init__()
        self.self_attn = SelfAttention(width, heads, dropout)
        self.cross_attn = CrossAttention(width, heads, dropout)
        self.ff = nn.Sequential(
            nn.Linear(width, feedforward), nn.GELU(), nn.Dropout(dropout), nn.Linear(feedforward, width)
        )
        self.drop = nn.Dropout(dropout)
        self.style = nn.Linear(style_dim, 6 * width)
        nn.init.zeros_(self.style.weight)  # starts as plain layer norm, whatever the speaker
        nn.init.zeros_(self.style.bias)

    def forward(self, x: torch.Tensor, k: torch.Tensor, v: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
        """``style``: (B, 6, C) scale/shift pairs of the three sub-layers (``styles``)."""
        x = x + self.drop(self.self_attn(modulate(x, style[:, 0], style[:, 1])))
        x = x + self.drop(self.cross_attn(modulate(x, style[:, 2], style[:, 3]), k, v))
        return x + self.drop(self.ff(modulate(x, style[:, 4], style[:, 5])))


class ConditionedTransformer(nn.Module):
    """Layers over a sequence, conditioned on a memory (cross-attention) and a speaker (modulation).

    What depends only on the conditions is split out: ``prepare`` gives every layer's keys and
    values of the memory and its speaker modulation, ``forward`` runs the layers with them.
    """

    def __init__(
        self, width: int, heads: int, layers: int, feedforward: int, dropout: float, speakers: int, speaker_dim: int
    ) -> None:
        super().__init__()
        self.speaker = nn.Embedding(max(1, speakers), speaker_dim)
        self.layers = nn.ModuleList([Layer(width, heads, feedforward, dropout, speaker_dim) for _ in range(layers)])
        self.norm = nn.LayerNorm(width)

    def prepare(self, memory: torch.Tensor, speaker: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Stacked keys (L, B, H, M, C/H), values (same) and styles (L, B, 6, C)."""
        e = F.silu(self.speaker(speaker))
        keys, values, styles = [], [], []
        for layer in self.layers:
            k, v = layer.cross_attn.kv(memory)
            keys.append(k)
            values.append(v)
            styles.append(layer.style(e).view(e.shape[0], 6, -1))
        return torch.stack(keys), torch.stack(values), torch.stack(styles)

    def forward(self, x: torch.Tensor, keys: torch.Tensor, values: torch.Tensor, styles: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x, keys[i], values[i], styles[i])
        return self.norm(x)


# ------------------------------------------------------------------------------------ conditions
def audio_streams(audio: torch.Tensor, dyadic: bool) -> torch.Tensor:
    """(B, T, 2, bands) log-mel -> (B, streams*bands, T): both voices, or self only."""
    streams = audio if dyadic else audio[:, :, :1]
    return streams.flatten(2).transpose(1, 2)


class AudioEncoder(nn.Module):
    """(B, streams*bands, T) normalised log-mel -> (B, channels, T/8): one conv, then three stride-2
    blocks each with a residual conv (the reference's ConditionEncoder)."""

    def __init__(self, cin: int, channels: int, steps: int, dropout: float) -> None:
        super().__init__()
        self.project = nn.Sequential(nn.Conv1d(cin, channels, 1), ChannelNorm(channels), nn.LeakyReLU(0.1))
        self.down = nn.ModuleList([conv_block(channels, channels, "down") for _ in range(steps)])
        self.refine = nn.ModuleList([conv_block(channels, channels) for _ in range(steps)])
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.drop(self.project(x))
        for down, refine in zip(self.down, self.refine):
            x = down(x)
            x = self.drop(x + refine(x))
        return x


class ContextEncoder(nn.Module):
    """Known frames and their mask (B, D+1, T) -> (B, C, T/8): gated convs (the first kernel 7),
    each stride-2 step between two of them (the reference's 10-layer motion-context encoder)."""

    def __init__(self, cin: int, channels: tuple[int, ...]) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.Conv1d(cin, channels[0], 1), GatedConv(channels[0], channels[0], 7)]
        for c_in, c_out in zip(channels[:-1], channels[1:]):
            layers += [GatedConv(c_in, c_out, 4, stride=2), GatedConv(c_out, c_out, 3)]
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


# ------------------------------------------------------------------------------------- predictor
class Predictor(nn.Module):
    """Codes from audio, known motion and speaker: MaskGIT over the (token x group) grid."""

    def __init__(self, dim: int, bands: int, speakers: int, config: ProbTalkConfig) -> None:
        super().__init__()
        self.config = config
        steps = len(config.vq_channels) - 1
        streams = 2 if config.dyadic else 1
        self.audio_encoder = AudioEncoder(streams * bands, config.audio_channels, steps, config.dropout)
        self.context_encoder = ContextEncoder(dim + 1, config.context_channels)
        self.condition = nn.Linear(config.audio_channels + config.context_channels[-1], config.width)
        self.token = nn.Embedding(config.codes + 1, config.width)  # + the mask id
        self.drop = nn.Dropout(config.dropout)
        self.transformer = ConditionedTransformer(
            config.width, config.heads, config.layers, config.feedforward, config.dropout, speakers, config.speaker_dim
        )
        self.head = nn.Sequential(
            nn.Linear(config.width, config.width),
            nn.GELU(),
            nn.LayerNorm(config.width),
            nn.Linear(config.width, config.codes),
        )

    def memory(
        self, audio: torch.Tensor, known: torch.Tensor, known_mask: torch.Tensor, speaker: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """What every MaskGIT pass of a window shares: per layer the memory's keys, values and the
        speaker modulation. ``audio`` normalised (B, T, 2, bands); ``known`` (B, T, D) motion,
        zero where unknown; ``known_mask`` (B, T, 1)."""
        a = self.audio_encoder(audio_streams(audio, self.config.dyadic))
        c = self.context_encoder(torch.cat([known * known_mask, known_mask], dim=-1).transpose(1, 2))
        memory = self.condition(torch.cat([a, c], dim=1).transpose(1, 2))
        t = torch.arange(memory.shape[1], device=memory.device)
        memory = self.drop(memory + sinusoid(t, memory.shape[-1]))
        return self.transformer.prepare(memory, speaker)

    def positions(self, n: int, device: torch.device) -> torch.Tensor:
        """(n, C) encodings of the flat token positions: time + group (2d), or the flat index (1d)."""
        index = torch.arange(n, device=device)
        width, groups = self.config.width, self.config.groups
        if self.config.position == "1d":
            return sinusoid(index, width)
        return sinusoid(torch.div(index, groups, rounding_mode="floor"), width) + sinusoid(index % groups, width)

    def logits(
        self, tokens: torch.Tensor, keys: torch.Tensor, values: torch.Tensor, styles: torch.Tensor
    ) -> torch.Tensor:
        """(B, N) token ids (``mask_id`` where unknown) -> (B, N, K) logits of each token's code."""
        x = self.drop(self.token(tokens) + self.positions(tokens.shape[1], tokens.device))
        return self.head(self.transformer(x, keys, values, styles))

    def forward(
        self,
        tokens: torch.Tensor,
        audio: torch.Tensor,
        known: torch.Tensor,
        known_mask: torch.Tensor,
        speaker: torch.Tensor,
    ) -> torch.Tensor:
        return self.logits(tokens, *self.memory(audio, known, known_mask, speaker))


def cosine_mask_ratio(progress: torch.Tensor) -> torch.Tensor:
    """MaskGIT's schedule: the fraction of codes still masked after ``progress`` (0..1) of the passes."""
    return torch.cos(progress * (math.pi / 2))


def maskgit_sample(
    logits_fn: Callable[[torch.Tensor], torch.Tensor],
    batch: int,
    length: int,
    config: ProbTalkConfig,
    iterations: int,
    uniforms: torch.Tensor,
    temperature: float = 1.0,
    choice_temperature: float = 4.5,
) -> torch.Tensor:
    """The torch reference of MaskGIT decoding (the runtime's is ``convodrive.neural.maskgit``).

    All ``length`` tokens start masked. Each pass samples a code for every masked token (inverse
    CDF of softmax(logits / temperature) at a uniform draw), keeps the most confident ones and
    masks the rest again, ``floor(length * cos(pi/2 * (t+1)/T))`` of them, where confidence is the
    log-probability plus Gumbel noise annealed to zero (``choice_temperature * (1 - (t+1)/T)``).
    ``uniforms`` (iterations, 2, batch, length) are the random draws: sampling, then Gumbel.
    """
    mask_id = config.mask_id
    tokens = torch.full((batch, length), mask_id, dtype=torch.long)
    for t in range(iterations):
        unknown = tokens == mask_id
        logp = torch.log_softmax(logits_fn(tokens).double() / temperature, dim=-1)
        cdf = logp.exp().cumsum(-1)
        u = uniforms[t, 0].double().unsqueeze(-1) * cdf[..., -1:]
        sampled = (cdf < u).sum(-1).clamp(max=config.codes - 1)
        sampled = torch.where(unknown, sampled, tokens)
        confidence = torch.gather(logp, -1, sampled.unsqueeze(-1)).squeeze(-1)
        progress = (t + 1) / iterations
        gumbel = -torch.log(-torch.log(uniforms[t, 1].double().clamp(1e-20, 1 - 1e-12)))
        confidence = confidence + choice_temperature * (1 - progress) * gumbel
        confidence = torch.where(unknown, confidence, torch.full_like(confidence, math.inf))
        remask = int(math.floor(length * math.cos(math.pi / 2 * progress)))
        tokens = sampled
        for b in range(batch):
            count = min(remask, int(unknown[b].sum()) - 1)
            if count > 0:
                order = torch.argsort(confidence[b], stable=True)
                tokens[b, order[:count]] = mask_id
    return tokens


# --------------------------------------------------------------------------------------- refiner
class Refiner(nn.Module):
    """Coarse motion (known frames copied in) + audio + known mask -> refined motion, frame by frame.

    The memory is the audio and the mask at frame rate; the output is a correction added to the
    coarse motion (its last layer starts at zero, so an untrained refiner passes motion through),
    and known frames are copied back in."""

    def __init__(self, dim: int, bands: int, speakers: int, config: ProbTalkConfig) -> None:
        super().__init__()
        self.config = config
        width = config.refiner_width
        streams = 2 if config.dyadic else 1
        self.motion_in = nn.Linear(dim + 1, width)
        self.audio_in = nn.Sequential(
            nn.Conv1d(streams * bands + 1, width, 3, padding=1), ChannelNorm(width), nn.LeakyReLU(0.1)
        )
        self.drop = nn.Dropout(config.dropout)
        self.transformer = ConditionedTransformer(
            width,
            config.refiner_heads,
            config.refiner_layers,
            config.refiner_feedforward,
            config.dropout,
            speakers,
            config.speaker_dim,
        )
        self.head = nn.Linear(width, dim)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(
        self, motion: torch.Tensor, audio: torch.Tensor, known_mask: torch.Tensor, speaker: torch.Tensor
    ) -> torch.Tensor:
        t = torch.arange(motion.shape[1], device=motion.device)
        pe = sinusoid(t, self.config.refiner_width)
        memory = self.audio_in(torch.cat([audio_streams(audio, self.config.dyadic), known_mask.transpose(1, 2)], dim=1))
        memory = self.drop(memory.transpose(1, 2) + pe)
        x = self.drop(self.motion_in(torch.cat([motion, known_mask], dim=-1)) + pe)
        refined = motion + self.head(self.transformer(x, *self.transformer.prepare(memory, speaker)))
        return known_mask * motion + (1 - known_mask) * refined


# ---------------------------------------------------------------------------------------- model
STAGES = ("vq", "predictor", "refiner")


class ProbTalk(nn.Module):
    """The three networks, built up to ``stage``; earlier stages are frozen (eval mode, no grads,
    codebooks fixed) while a later one trains."""

    def __init__(self, config: ProbTalkConfig, dim: int, bands: int, speakers: int, stage: str = "refiner") -> None:
        super().__init__()
        config.check()
        if stage not in STAGES:
            raise ValueError(f"stage must be one of {STAGES}, got {stage!r}")
        self.config, self.stage = config, stage
        self.audio_norm = AudioNorm(bands)
        self.vq = PQVAE(dim, config)
        self.predictor = Predictor(dim, bands, speakers, config) if stage != "vq" else None
        self.refiner = Refiner(dim, bands, speakers, config) if stage == "refiner" else None
        self.frozen_names: tuple[str, ...] = STAGES[: STAGES.index(stage)]
        for name in self.frozen_names:
            getattr(self, name).requires_grad_(False)
        self.vq.quantizer.updating = stage == "vq"

    def train(self, mode: bool = True) -> ProbTalk:
        super().train(mode)
        for name in self.frozen_names:
            getattr(self, name).eval()
        return self
