"""The transformer blocks every a2p network is made of: rotary self-attention, FiLM, cross-attention,
the encoder and FiLM layers, and sinusoid embeddings of steps and positions."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def rotate(x: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """Rotary position embedding of (B, H, T, dh) at ``positions`` (B, T), in any unit (frames here)."""
    half = x.shape[-1] // 2
    inverse = torch.exp(
        torch.arange(half, dtype=torch.float32, device=x.device) * (-2.0 * math.log(10000.0) / x.shape[-1])
    )
    angle = (positions.to(torch.float32)[..., None] * inverse)[:, None]
    cos, sin = angle.cos(), angle.sin()
    a, b = x[..., :half], x[..., half:]
    return torch.cat([a * cos - b * sin, a * sin + b * cos], dim=-1)


class Attention(nn.Module):
    """Multi-head attention with rotary positions; keys and values can be made once and reused.
    No dropout on the attention weights: on a CPU it costs a quarter of a training step (the
    fused attention kernel cannot run with it), and the residual branches drop out anyway."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.query = nn.Linear(width, width)
        self.key_value = nn.Linear(width, 2 * width)
        self.out = nn.Linear(width, width)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        return x.reshape(b, t, self.heads, d // self.heads).transpose(1, 2)

    def keys_values(self, memory: torch.Tensor, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, H, S, dh) keys (rotated) and values of ``memory`` (B, S, d)."""
        k, v = self.key_value(memory).chunk(2, dim=-1)
        return rotate(self._split(k), positions), self._split(v)

    def attend(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        keys: torch.Tensor,
        values: torch.Tensor,
        bias: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``x`` (B, T, d) at ``positions`` (B, T) attends to keys and values; ``bias`` is added to
        the scores (0 or -inf, broadcast to (B, H, T, S))."""
        q = rotate(self._split(self.query(x)), positions)
        y = F.scaled_dot_product_attention(q, keys, values, attn_mask=bias)
        b, _, t, _ = y.shape
        return self.out(y.transpose(1, 2).reshape(b, t, -1))

    def forward(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        memory: torch.Tensor,
        memory_positions: torch.Tensor,
        bias: torch.Tensor | None = None,
    ) -> torch.Tensor:
        keys, values = self.keys_values(memory, memory_positions)
        return self.attend(x, positions, keys, values, bias)


class FiLM(nn.Module):
    """Feature-wise linear modulation by a conditioning vector: ``x * (1 + scale) + shift``."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.block = nn.Sequential(nn.Mish(), nn.Linear(width, 2 * width))

    def forward(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        scale, shift = self.block(condition)[:, None].chunk(2, dim=-1)
        return x * (1 + scale) + shift


def feedforward(width: int, hidden: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(nn.Linear(width, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, width))


class EncoderLayer(nn.Module):
    """Pre-norm self-attention and feed-forward (the lip regressor, the face condition encoder)."""

    def __init__(self, width: int, heads: int, hidden: int, dropout: float) -> None:
        super().__init__()
        self.norm1, self.norm2 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.attention = Attention(width, heads)
        self.feedforward = feedforward(width, hidden, dropout)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        h = self.norm1(x)
        x = x + self.drop(self.attention(h, positions, h, positions))
        return x + self.drop(self.feedforward(self.norm2(x)))


class CrossAttention(nn.Module):
    """One cross-attention sub-layer of a FiLM layer: its norm, attention and modulation."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.attention = Attention(width, heads)
        self.film = FiLM(width)


class FiLMLayer(nn.Module):
    """The reference's FiLMTransformerDecoderLayer, pre-norm: self-attention, one cross-attention
    per memory, feed-forward; each sub-layer's output modulated by the FiLM vector, then added."""

    def __init__(self, width: int, heads: int, hidden: int, dropout: float, memories: int) -> None:
        super().__init__()
        self.norm1, self.norm3 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.self_attention = Attention(width, heads)
        self.film1, self.film3 = FiLM(width), FiLM(width)
        self.cross = nn.ModuleList(CrossAttention(width, heads) for _ in range(memories))
        self.feedforward = feedforward(width, hidden, dropout)
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        film: torch.Tensor,
        memories: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]],
        self_bias: torch.Tensor | None = None,
        cache: tuple[torch.Tensor, torch.Tensor] | None = None,
        cross_positions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """``memories``: per cross-attention (keys, values, bias); its queries sit at
        ``cross_positions`` (default ``positions``). ``cache``: earlier keys and values of the
        self-attention (autoregressive steps). Returns the output and the self-attention's keys
        and values (the cache with this call's appended)."""
        h = self.norm1(x)
        keys, values = self.self_attention.keys_values(h, positions)
        if cache is not None:
            keys, values = torch.cat([cache[0], keys], dim=2), torch.cat([cache[1], values], dim=2)
        x = x + self.drop(self.film1(self.self_attention.attend(h, positions, keys, values, self_bias), film))
        cross = positions if cross_positions is None else cross_positions
        for sub, (k, v, bias) in zip(self.cross, memories):
            x = x + self.drop(sub.film(sub.attention.attend(sub.norm(x), cross, k, v, bias), film))
        x = x + self.drop(self.film3(self.feedforward(self.norm3(x)), film))
        return x, (keys, values)


def sinusoid(values: torch.Tensor, dim: int) -> torch.Tensor:
    """(B,) -> (B, dim) sinusoidal embedding (diffusion steps, guidance scales)."""
    half = dim // 2
    freqs = torch.exp(torch.arange(half, dtype=torch.float32, device=values.device) * (-math.log(10000.0) / (half - 1)))
    angle = values.to(torch.float32)[:, None] * freqs
    return torch.cat([angle.sin(), angle.cos()], dim=-1)


def frame_positions(batch: int, length: int, device: torch.device) -> torch.Tensor:
    return torch.arange(length, device=device, dtype=torch.float32)[None].expand(batch, length)
