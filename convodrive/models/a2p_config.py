"""The shapes and sizes of audio2photoreal (``a2p``): its stages, the feature groups it predicts, and
``A2PConfig``, every size and rate of its networks."""

from __future__ import annotations

import dataclasses

from convodrive.motion import representation as rep
from convodrive.motion.channels import ARKIT_NAMES

STAGES = ("lip", "face", "vq", "guide", "body", "distill")
FACE = rep.GROUPS["face"]
BODY = rep.GROUPS["body"]
VAD = rep.GROUPS["vad"]
FPS = 30
MOUTH_COLUMNS: tuple[int, ...] = tuple(range(rep.PARTS["jaw"].start, rep.PARTS["jaw"].stop)) + tuple(
    rep.PARTS["arkit"].start + i for i, n in enumerate(ARKIT_NAMES) if n.startswith(("mouth", "jaw"))
)
"""Feature columns of the mouth: the jaw rotation and the ARKit jaw and mouth channels."""
LIP_OUTPUTS = len(MOUTH_COLUMNS) + 1
"""The lip regressor's outputs: the mouth columns, then the voice activity of the voice it hears."""


@dataclasses.dataclass(frozen=True)
class A2PConfig:
    """Hyper-parameters; defaults are the reference implementation's (the ``paper`` preset)."""

    # face denoiser
    face_width: int = 512
    face_layers: int = 8
    face_heads: int = 8
    face_feedforward: int = 1024
    face_cond_layers: int = 2
    """Transformer layers over the condition tokens before the face denoiser attends to them."""
    # body denoiser
    body_width: int = 256
    body_layers: int = 6
    body_heads: int = 8
    body_feedforward: int = 1024
    body_post_layers: int = 6
    """Causal dilated convs on the body denoiser's output (the reference's post_pose_layers)."""
    # lip regressor (the reference: 2 encoder + 4 decoder layers, 512-d, 4 heads)
    lip_width: int = 512
    lip_layers: int = 6
    lip_heads: int = 4
    lip_feedforward: int = 1024
    # residual VQ-VAE of 1 fps body poses
    vq_codes: int = 1024
    vq_levels: int = 4
    vq_width: int = 64
    vq_decay: float = 0.99
    vq_commit: float = 0.02
    vq_residual: bool = False
    """Each causal conv of the VQ-VAE adds its output to its input (the reference's stack does not).
    Without it the small preset's VQ-VAE learned a latent that held the hands but not the arms and
    head: its encoder's continuous output reconstructed the test split's 1 fps poses no better than
    its codes (FD_g body 21; 32 principal components of the poses give 1.5), so the guide poses
    kept a third of the real variance of the head and upper body. With it: FD_g body 6.0 (1500 steps)."""
    # guide transformer
    guide_width: int = 64
    guide_layers: int = 6
    guide_heads: int = 4
    guide_feedforward: int = 1024
    guide_band: int = 80
    """Tokens a token's self-attention reaches (itself included): the KV cache's length (20 s)."""
    guide_audio_span: int = 4
    """Seconds of audio a token hears: its own and those before it."""
    guide_seconds: int = 20
    """Seconds per training sequence of the guide (the reference's 600 frames)."""
    top_p: float = 0.94
    # diffusion
    diffusion_steps: int = 1000
    cond_drop: float = 0.2
    """Probability that a training example loses each condition (classifier-free guidance)."""
    face_velocity_weight: float = 0.0
    body_velocity_weight: float = 2.0
    # windows
    window: int = 600
    """Longest training window, and the ``file`` mode's window (frames)."""
    min_window: int = 240
    context: int = 60
    """Known frames a window continues from (the previous window's last ones); trained up to this."""
    dropout: float = 0.1
    # distillation
    distillation: str = "consistency"
    """How the students learn (``convodrive.training.recipes.a2p_distill``): ``consistency``, a
    few-step sampler of its own on the grid of ``distill_skip``, or ``guidance``, one pass for the
    guided teacher's two, sampled by DPM-Solver++ as the teachers are."""
    distill_skip: int = 20
    """Diffusion steps between neighbouring points of the consistency-distillation grid."""
    distill_ema: float = 0.95
    face_student_steps: int = 0
    """The face student's steps when the generator's ``face_steps`` is 0; 0: as the body's ``steps``."""
    face_guidance_max: float = 10.0
    body_guidance_max: float = 4.0
    """Students learn every guidance scale in [1, max] (the reference samples face 10, body 2)."""

    def check(self) -> None:
        """ValueError naming the first inconsistent setting."""
        for part in ("face", "body", "lip", "guide"):
            if getattr(self, f"{part}_width") % (2 * getattr(self, f"{part}_heads")):
                raise ValueError(f"{part}_width must be a multiple of twice {part}_heads (rotary halves)")
        if self.distillation not in ("consistency", "guidance"):
            raise ValueError(f"distillation must be consistency or guidance, not {self.distillation!r}")
        if not 0 < self.min_window <= self.window or not 0 <= self.context < self.min_window:
            raise ValueError("need 0 <= context < min_window <= window")
        if self.guide_band < 2 or self.guide_audio_span < 1 or self.guide_seconds < 2:
            raise ValueError("guide_band >= 2, guide_audio_span >= 1 and guide_seconds >= 2 are needed")
        if self.diffusion_steps % self.distill_skip:
            raise ValueError("diffusion_steps must be a multiple of distill_skip")
