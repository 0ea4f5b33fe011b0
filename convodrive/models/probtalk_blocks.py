"""The blocks ProbTalk's networks share: conv blocks and norms, sinusoid positions, the conditioned
transformer (self- and cross-attention, adaptive layer norm from the speaker), and the encoders that
bring the audio and the known motion context to token rate."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn


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
