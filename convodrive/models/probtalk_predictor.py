"""ProbTalk's second stage: the MaskGIT predictor over the (token x group) grid of codes, and
``maskgit_sample``, the torch reference of the runtime's sampler (``convodrive.neural.maskgit``)."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from convodrive.models.probtalk_blocks import (
    AudioEncoder,
    ConditionedTransformer,
    ContextEncoder,
    audio_streams,
    sinusoid,
)
from convodrive.models.probtalk_config import ProbTalkConfig


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
