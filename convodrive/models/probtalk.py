"""ProbTalk (Liu et al., CVPR 2024): holistic co-speech motion in three stages.

This file holds ``ProbTalk`` and the refiner; the other networks are its siblings:
``probtalk_config`` (``ProbTalkConfig``), ``probtalk_blocks`` (conv blocks, the conditioned
transformer, the condition encoders), ``probtalk_pqvae`` (stage 1), ``probtalk_predictor`` (stage 2
and ``maskgit_sample``).

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

import numpy as np
import torch
from torch import nn

from convodrive.models.common import AudioNorm
from convodrive.models.probtalk_blocks import ChannelNorm, ConditionedTransformer, audio_streams, sinusoid
from convodrive.models.probtalk_config import ProbTalkConfig
from convodrive.models.probtalk_pqvae import PQVAE
from convodrive.models.probtalk_predictor import Predictor
from convodrive.motion import representation as rep


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
        self.register_buffer("shown_low", torch.full((dim,), -torch.inf), persistent=False)
        self.register_buffer("shown_high", torch.full((dim,), torch.inf), persistent=False)
        """Normalised bounds of the channels the run clips (``set_shown_range``; none by default)."""
        self.vq = PQVAE(dim, config)
        self.predictor = Predictor(dim, bands, speakers, config) if stage != "vq" else None
        self.refiner = Refiner(dim, bands, speakers, config) if stage == "refiner" else None
        self.frozen_names: tuple[str, ...] = STAGES[: STAGES.index(stage)]
        for name in self.frozen_names:
            getattr(self, name).requires_grad_(False)
        self.decoder_frozen = stage == "vq" and bool(config.vq_decoder_from)
        """The vq stage fits an encoder to a given decoder and codebooks (``vq_decoder_from``)."""
        if self.decoder_frozen:
            self.vq.decoder.requires_grad_(False)
        self.vq.quantizer.updating = stage == "vq" and not self.decoder_frozen

    def set_shown_range(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Bound the ARKit shapes where the run clips them (``representation.shape_bounds``)."""
        low, high = rep.shape_bounds(mean, std)
        self.shown_low.copy_(torch.from_numpy(low))
        self.shown_high.copy_(torch.from_numpy(high))

    def train(self, mode: bool = True) -> ProbTalk:
        super().train(mode)
        for name in self.frozen_names:
            getattr(self, name).eval()
        if self.decoder_frozen:
            self.vq.decoder.eval()
        return self
