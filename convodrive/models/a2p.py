"""audio2photoreal (Ng et al., CVPR 2024): dyadic face and body motion.

This file holds ``A2P`` (the networks of each stage); the networks are its siblings:
``a2p_config`` (stages, feature groups, ``A2PConfig``), ``a2p_blocks`` (attention, FiLM, layers),
``a2p_denoiser`` (lip regressor, face and body denoisers), ``a2p_guide`` (VQ-VAE, guide transformer).

Five networks, trained one after another (``STAGES``), then distilled:

1. **Lip regressor** (``LipRegressor``): a small transformer from the voice it hears to the mouth
   (jaw rotation and the ARKit mouth and jaw channels) and that voice's activity. The paper's
   hears self only; ours hears both channels (self first), so partner speech that bleeds into
   self's microphone does not open the mouth. Run with the channels swapped it gives the
   partner's voice activity too.
2. **Face denoiser** (``Denoiser``): a FiLM transformer that predicts clean face motion (x0) from
   noisy face motion, the diffusion step (FiLM on every sub-layer) and the known frames of a
   window (the previous window's last frames: continuation by inpainting), cross-attending to a
   memory of both voices' log-mel plus the lip regressor's output (a second condition).
3. **Residual VQ-VAE** (``GuideVQ``): body poses at 1 fps through a causal conv encoder (receptive
   field 8), ``vq_levels`` EMA codebooks each quantising what the previous left, and a causal
   conv decoder.
4. **Guide transformer** (``GuideTransformer``): autoregressive over the VQ tokens flattened
   time-major (s0q0, s0q1, ..., s1q0, ...), FiLM-modulated by the speaker, cross-attending to
   per-second embeddings of both voices. Each token hears its own second's audio and the
   ``guide_audio_span - 1`` seconds before (second k is the half-open frame span centred on
   frame 30k), never later audio, so its look-ahead is half a second. Self-attention reaches the
   last ``guide_band`` tokens, so sampling carries a KV cache of fixed size across any length
   (``step``): each new token costs one step, not a re-run of its prefix.
5. **Body denoiser**: the face denoiser's network over head, upper body and hands, with a second
   cross-attention to the guide poses (placed at their frames) and the reference's causal conv
   stack on its output.

Classifier-free guidance: every condition (audio, lip, guide poses) is dropped on its own in
training (``cond_drop``); at sampling ``Denoiser.memory`` takes a ``keep`` flag per condition, so
the conditional and unconditional memories are one batch and so is every denoising step.

The memory of a window (each layer's cross-attention keys and values, and the FiLM vector of the
conditions) is computed once (``Denoiser.memory``) and reused by every step (``Denoiser.step``);
the runtime exports the two as graphs. Distillation (``distill`` stage) copies each denoiser into a
student that also hears the guidance scale and learns from the guided teacher, either its x0 (one
pass for the teacher's two) or, by consistency distillation, to jump to the clean motion in one to
four steps (``A2PConfig.distillation``).

Not as the paper: log-mel instead of wav2vec features (aligned with the 30 fps frames, so windows
stream); rotary positions in frame units on the per-head queries and keys (the reference rotates
the un-projected inputs); no time tokens in the cross-attention memory (FiLM carries the step);
the guide's FiLM hears the speaker, not the pooled audio of the whole clip (which a stream has not
heard yet). Shapes: motion (B, T, D) normalised features (``convodrive.motion.representation``),
audio (B, T, 2, bands) log-mel of self and partner. Torch is for training and export only.
"""

from __future__ import annotations

from torch import nn

from convodrive.models.a2p_config import BODY, FACE, LIP_OUTPUTS, STAGES, A2PConfig
from convodrive.models.a2p_denoiser import Denoiser, LipRegressor
from convodrive.models.a2p_guide import GuideTransformer, GuideVQ
from convodrive.models.common import AudioNorm

NETWORKS: dict[str, tuple[str, ...]] = {
    "lip": ("lip",),
    "face": ("lip", "face"),
    "vq": ("vq",),
    "guide": ("vq", "guide"),
    "body": ("vq", "guide", "body"),
    "distill": (
        "lip",
        "face",
        "vq",
        "guide",
        "body",
        "face_student",
        "body_student",
        "face_target",
        "body_target",
    ),
}
"""The networks each stage holds. The face side (lip, face) and the body side (vq, guide, body)
are trained apart, so the two can run at once; ``distill`` starts from both (``--init`` twice)."""
TRAINS: dict[str, tuple[str, ...]] = {"distill": ("face_student", "body_student")}
"""The networks a stage trains (default: the one it is named after); the others stay frozen."""
DERIVED = ("face_target", "body_target")
"""Networks a stage makes from its own (the students' moving averages), not from earlier runs."""


class A2P(nn.Module):
    """The networks of one training stage: those it trains and, frozen, those of earlier stages."""

    def __init__(self, config: A2PConfig, bands: int, speakers: int, stage: str) -> None:
        super().__init__()
        if stage not in STAGES:
            raise ValueError(f"unknown stage {stage!r} (stages: {', '.join(STAGES)})")
        self.config, self.stage = config, stage
        face_dim, body_dim = FACE.stop - FACE.start, BODY.stop - BODY.start
        self.audio_norm = AudioNorm(bands, flatten_voices=True)
        self.lip: LipRegressor | None = None
        self.face: Denoiser | None = None
        self.vq: GuideVQ | None = None
        self.guide: GuideTransformer | None = None
        self.body: Denoiser | None = None
        self.face_student: Denoiser | None = None
        self.body_student: Denoiser | None = None
        self.face_target: Denoiser | None = None
        self.body_target: Denoiser | None = None

        def face(student: bool) -> Denoiser:
            return Denoiser(
                face_dim,
                (2 * bands, LIP_OUTPUTS),
                config.face_width,
                config.face_layers,
                config.face_heads,
                config.face_feedforward,
                config.dropout,
                speakers,
                cond_layers=config.face_cond_layers,
                student=student,
            )

        def body(student: bool) -> Denoiser:
            return Denoiser(
                body_dim,
                (2 * bands,),
                config.body_width,
                config.body_layers,
                config.body_heads,
                config.body_feedforward,
                config.dropout,
                speakers,
                guide_dim=body_dim,
                post_layers=config.body_post_layers,
                student=student,
            )

        makers = {
            "lip": lambda: LipRegressor(bands, config),
            "face": lambda: face(False),
            "vq": lambda: GuideVQ(body_dim, config),
            "guide": lambda: GuideTransformer(bands, speakers, config),
            "body": lambda: body(False),
            "face_student": lambda: face(True),
            "body_student": lambda: body(True),
            "face_target": lambda: face(True),
            "body_target": lambda: body(True),
        }
        for name in NETWORKS[stage]:
            setattr(self, name, makers[name]())
        for name in self.frozen_names:
            getattr(self, name).requires_grad_(False)

    @property
    def trained_names(self) -> tuple[str, ...]:
        return TRAINS.get(self.stage, (self.stage,))

    @property
    def frozen_names(self) -> tuple[str, ...]:
        """The networks trained by earlier stages, which this stage keeps as they are."""
        return tuple(n for n in NETWORKS[self.stage] if n not in self.trained_names)

    @property
    def inherited_names(self) -> tuple[str, ...]:
        """The frozen networks that come from the runs a stage starts from (``--init``)."""
        return tuple(n for n in self.frozen_names if n not in DERIVED)

    def train(self, mode: bool = True) -> A2P:
        super().train(mode)
        for name in self.frozen_names:  # frozen networks stay deterministic (no dropout, no EMA)
            getattr(self, name).eval()
        return self
