"""The face side of a2p and the denoiser both sides use: the lip regressor, and the FiLM transformer
that predicts clean motion from noisy motion (``Denoiser``: the face denoiser, and over head,
upper body and hands with the guide poses, the body denoiser), its condition memory and the body's
causal conv stack."""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.a2p_blocks import EncoderLayer, FiLMLayer, frame_positions, sinusoid
from convodrive.models.a2p_config import LIP_OUTPUTS, A2PConfig


class LipRegressor(nn.Module):
    """Audio (B, T, 2*bands) normalised, the voice whose mouth it predicts first -> (B, T,
    ``LIP_OUTPUTS``): the mouth columns (normalised features) and that voice's activity."""

    def __init__(self, bands: int, config: A2PConfig) -> None:
        super().__init__()
        w = config.lip_width
        self.input = nn.Linear(2 * bands, w)
        self.layers = nn.ModuleList(
            EncoderLayer(w, config.lip_heads, config.lip_feedforward, config.dropout) for _ in range(config.lip_layers)
        )
        self.norm = nn.LayerNorm(w)
        self.output = nn.Linear(w, LIP_OUTPUTS)

    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        positions = frame_positions(audio.shape[0], audio.shape[1], audio.device)
        x = self.input(audio)
        for layer in self.layers:
            x = layer(x, positions)
        return self.output(self.norm(x))


@dataclasses.dataclass
class Memory:
    """What a denoiser attends to, made once per window: per layer and cross-attention the keys
    and values (layers, B, H, S, dh) and the score bias, and the FiLM vector of the conditions."""

    keys: list[torch.Tensor]
    values: list[torch.Tensor]
    biases: list[torch.Tensor | None]
    film: torch.Tensor


class PostConv(nn.Module):
    """The reference's post_pose_layers: causal dilated convs (k=3) on the predicted motion,
    averaged with their input; their last projection starts at zero, so training starts from
    the transformer's output."""

    def __init__(self, dim: int, layers: int) -> None:
        super().__init__()
        self.dilations = [(1, 2, 3)[i % 3] for i in range(layers)]
        self.convs = nn.ModuleList(nn.Conv1d(dim, dim, 3, dilation=d) for d in self.dilations)
        self.final = nn.Conv1d(dim, dim, 1)
        nn.init.zeros_(self.final.weight)
        nn.init.zeros_(self.final.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x.transpose(1, 2)
        for conv, d in zip(self.convs, self.dilations):
            h = 0.5 * (h + F.leaky_relu(conv(F.pad(h, (2 * d, 0))), 0.2))
        return x + self.final(h).transpose(1, 2)


class Denoiser(nn.Module):
    """The FiLM transformer denoiser (face or body): x0 from a noisy window.

    Conditions (memory 0): a list of per-frame inputs (audio; for the face also the lip
    regressor's output), each projected and summed into one token per frame; a dropped condition
    is a learned null vector instead. The face runs ``cond_layers`` transformer layers over the
    tokens. The body adds memory 1: its guide poses (B, K, dim) at frame positions, with a learned
    always-present token so that a window without guide poses still attends to something.
    The FiLM vector is the diffusion step's embedding plus the pooled condition tokens, the
    speaker's embedding and, for a distilled student, the guidance scale's embedding.
    """

    def __init__(
        self,
        dim: int,
        conditions: tuple[int, ...],
        width: int,
        layers: int,
        heads: int,
        hidden: int,
        dropout: float,
        speakers: int,
        cond_layers: int = 0,
        guide_dim: int = 0,
        post_layers: int = 0,
        student: bool = False,
    ) -> None:
        super().__init__()
        self.dim, self.width = dim, width
        self.input = nn.Linear(2 * dim + 1, width)
        self.time = nn.Sequential(nn.Linear(width, 4 * width), nn.Mish(), nn.Linear(4 * width, width))
        self.speaker = nn.Embedding(max(1, speakers), width)
        self.condition = nn.ModuleList(nn.Linear(c, width) for c in conditions)
        self.null = nn.Parameter(torch.randn(len(conditions), width) * 0.02)
        self.cond_encoder = nn.ModuleList(EncoderLayer(width, heads, hidden, dropout) for _ in range(cond_layers))
        self.pool = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))
        self.memory_norm = nn.LayerNorm(width)
        self.guided = guide_dim > 0
        if self.guided:
            self.guide_input = nn.Linear(guide_dim, width)
            self.guide_norm = nn.LayerNorm(width)
            self.guide_sink = nn.Parameter(torch.randn(1, 1, width) * 0.02)
        self.layers = nn.ModuleList(
            FiLMLayer(width, heads, hidden, dropout, 2 if self.guided else 1) for _ in range(layers)
        )
        self.norm = nn.LayerNorm(width)
        self.output = nn.Linear(width, dim)
        self.post = PostConv(dim, post_layers) if post_layers else None
        self.guidance: nn.Linear | None = None
        if student:
            self.guidance = nn.Linear(width, width)
            nn.init.zeros_(self.guidance.weight)
            nn.init.zeros_(self.guidance.bias)

    @property
    def conditions(self) -> int:
        return len(self.condition)

    def memory(
        self,
        conditions: list[torch.Tensor],
        keep: torch.Tensor,
        speaker: torch.Tensor,
        guide: torch.Tensor | None = None,
        guide_positions: torch.Tensor | None = None,
        guide_valid: torch.Tensor | None = None,
    ) -> Memory:
        """``conditions`` each (B, T, c_i); ``keep`` (B, n) 1 to hear condition i, 0 to drop it
        (the body's last column drops the guide poses); guide poses (B, K, dim) at
        ``guide_positions`` (B, K) frames of the window, ``guide_valid`` (B, K) 1 where known."""
        b, t = conditions[0].shape[:2]
        tokens = torch.zeros(b, t, self.width, device=conditions[0].device)
        for i, (project, c) in enumerate(zip(self.condition, conditions)):
            k = keep[:, i, None, None]
            tokens = tokens + k * project(c) + (1 - k) * self.null[i]
        positions = frame_positions(b, t, tokens.device)
        for layer in self.cond_encoder:
            tokens = layer(tokens, positions)
        film = self.pool(tokens.mean(dim=1)) + self.speaker(speaker)
        tokens = self.memory_norm(tokens)
        keys, values, biases = [], [], []
        audio_kv = [layer.cross[0].attention.keys_values(tokens, positions) for layer in self.layers]
        keys.append(torch.stack([k for k, _ in audio_kv]))
        values.append(torch.stack([v for _, v in audio_kv]))
        biases.append(None)
        if self.guided:
            assert guide is not None and guide_positions is not None and guide_valid is not None
            sink = self.guide_sink.expand(b, 1, self.width)
            poses = torch.cat([sink, self.guide_input(guide)], dim=1)
            poses = self.guide_norm(poses)
            pos = torch.cat([torch.zeros(b, 1, device=poses.device), guide_positions.to(torch.float32)], dim=1)
            valid = torch.cat([torch.ones(b, 1, device=poses.device), guide_valid * keep[:, -1:]], dim=1)
            guide_kv = [layer.cross[1].attention.keys_values(poses, pos) for layer in self.layers]
            keys.append(torch.stack([k for k, _ in guide_kv]))
            values.append(torch.stack([v for _, v in guide_kv]))
            biases.append(((valid - 1) * 1e9)[:, None, None, :])
        return Memory(keys, values, biases, film)

    def step(
        self,
        noisy: torch.Tensor,
        step: torch.Tensor,
        known: torch.Tensor,
        known_mask: torch.Tensor,
        memory: Memory,
        guidance: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """x0 (B, T, dim) from ``noisy`` (B, T, dim) at diffusion ``step`` (B,), ``known`` frames
        (B, T, dim) where ``known_mask`` (B, T, 1) is 1, and the window's memory."""
        b, t, _ = noisy.shape
        x = self.input(torch.cat([noisy, known * known_mask, known_mask], dim=-1))
        film = self.time(sinusoid(step, self.width)) + memory.film
        if self.guidance is not None:
            assert guidance is not None
            film = film + self.guidance(sinusoid(guidance * 100.0, self.width))
        positions = frame_positions(b, t, x.device)
        for i, layer in enumerate(self.layers):
            memories = [(k[i], v[i], bias) for k, v, bias in zip(memory.keys, memory.values, memory.biases)]
            x, _ = layer(x, positions, film, memories)
        out = self.output(self.norm(x))
        return self.post(out) if self.post is not None else out
