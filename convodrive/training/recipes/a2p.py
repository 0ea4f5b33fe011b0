"""Recipe ``a2p``: the networks of ``convodrive.models.a2p``, stage by stage, then distilled.

    convodrive train a2p --stage lip     --corpus C --out runs/lip
    convodrive train a2p --stage face    --corpus C --out runs/face  --init runs/lip
    convodrive train a2p --stage vq      --corpus C --out runs/vq
    convodrive train a2p --stage guide   --corpus C --out runs/guide --init runs/vq
    convodrive train a2p --stage body    --corpus C --out runs/body  --init runs/guide
    convodrive train a2p --stage distill --corpus C --out runs/a2p   --init runs/face --init runs/body

The face side (lip, face) and the body side (vq, guide, body) share nothing, so they can train at
once, one per core (``scripts/train_a2p.sh``). Each stage keeps the networks it starts from frozen.

Examples are windows of every take of the train split, cut each step to one random length (so the
short windows of ``live`` mode are trained too), with a known prefix of random length (none a
quarter of the time): the previous window's frames a stream continues from. Each condition is
dropped now and then (classifier-free guidance). The body sees guide poses as it will at run time:
the 1 fps poses of the window (and the second before it) through the frozen VQ-VAE, with the
7 seconds before as the decoder's history, those less than half a second before the window's end
left out (the guide has not heard their audio yet), a few more dropped at random.

Distillation (``distill``): each denoiser's student starts as a copy of it, hears the guidance
scale as an input, and learns by ``distillation`` (``convodrive.training.recipes.a2p_distill``):
``guidance``, the guided teacher's x0 in one pass, sampled by DPM-Solver++ as the teachers are;
or ``consistency``, a few-step sampler of its own on a coarse grid of the guided teacher's DDIM
trajectories.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import FPS, STAGES, A2PConfig
from convodrive.plumbing.errors import UserError
from convodrive.training.config import Preset
from convodrive.training.recipe import Batch, DataSpec, GraphSpec, StepContext, TrainingData
from convodrive.training.recipes.a2p_distill import distill_loss
from convodrive.training.recipes.a2p_losses import HISTORY, body_loss, face_loss, guide_loss, lip_loss, vq_loss
from convodrive.training.staged import StagedRecipe
from convodrive.training.windows import window_data

_SMALL: dict[str, Any] = {
    "face_width": 128,
    "face_layers": 4,
    "face_heads": 4,
    "face_feedforward": 256,
    "face_cond_layers": 1,
    "body_width": 128,
    "body_layers": 3,
    "body_heads": 4,
    "body_feedforward": 256,
    "body_post_layers": 0,
    "lip_width": 64,
    "lip_layers": 3,
    "lip_heads": 4,
    "lip_feedforward": 192,
    "vq_codes": 256,
    "vq_width": 64,
    "vq_residual": True,
    "guide_width": 96,
    "guide_layers": 3,
    "guide_heads": 4,
    "guide_feedforward": 256,
    "guide_band": 48,
    "guide_seconds": 12,
    "window": 150,
    "min_window": 60,
    "context": 48,
    "distillation": "guidance",
    "face_guidance_max": 4.0,
    "face_student_steps": 8,
    "distill_skip": 125,
}
"""The shipped model: teachers and students of both denoisers, about 33 MB as fp32 ONNX (the
mixed export, float denoiser steps and teacher memories and int8 elsewhere, 29.3 MB, fits the
package's 30 MB).

Its students learn by guidance distillation, sampled as the teachers are by DPM-Solver++ (4 body
steps, 8 face steps evenly in log-SNR), over guidance scales 1 to 4 (the generator's defaults are
1.5 for the face and 3 for the body). Consistency students in 4 and 1 steps, from the same teachers
in the same 900 steps, scored FD_g body 15.1 and face 3.7 on the test split (7 x 2) against the
teachers' DDIM default 7.97 and 1.19: their coarse grid (``distill_skip`` 125; a grid of 50 points
drifted further in the few hundred steps a 2-core CPU gives) teaches them a crude trajectory. The
guidance students, 7 x 4: 8.31 and 1.36 against 8.33 and 1.05 (the model card).

Its VQ-VAE's causal convs are residual (``vq_residual``). Without, trained with the script's 3000
steps, it reconstructed the test split's 1 fps poses at FD_g body 21.3 (head 3.7, upper body 14.4,
hands 0.1), its encoder's continuous latent no better than its codes, where 32 principal components
of the poses reach 1.5; with them, 4.9 (head 0.3, upper body 3.7, hands 0.15). The guide poses the
transformer then samples (test split, top_p 0.94) keep 0.63 of the real variance of the head and
0.73 of the upper body's (1.0 of the hands'), FD_g body 9.6; those of the weights shipped before
this setting, 0.33 and 0.43 (0.93), FD_g body 24.3. The shipped weights have it (their card
compares them with the previous ones)."""
_TINY: dict[str, Any] = {
    "face_width": 16,
    "face_layers": 1,
    "face_heads": 2,
    "face_feedforward": 32,
    "face_cond_layers": 1,
    "body_width": 16,
    "body_layers": 1,
    "body_heads": 2,
    "body_feedforward": 32,
    "body_post_layers": 2,
    "lip_width": 16,
    "lip_layers": 1,
    "lip_heads": 2,
    "lip_feedforward": 32,
    "vq_codes": 16,
    "vq_width": 8,
    "vq_residual": True,
    "guide_width": 16,
    "guide_layers": 1,
    "guide_heads": 2,
    "guide_feedforward": 32,
    "guide_band": 12,
    "guide_audio_span": 2,
    "guide_seconds": 3,
    "window": 60,
    "min_window": 60,
    "context": 48,
    "distill_skip": 100,
}
_TINY_TRAIN = {
    "batch_size": 4,
    "lr": 1e-3,
    "steps": 4,
    "warmup_steps": 1,
    "log_every": 2,
    "val_every": 2,
    "checkpoint_every": 2,
}


class A2PRecipe(StagedRecipe):
    name = "a2p"
    description = (
        "audio2photoreal (Ng et al., CVPR 2024): a face diffusion model conditioned on both voices and a lip "
        "regressor, and a body diffusion model conditioned on both voices and guide poses at 1 fps sampled by an "
        "autoregressive transformer over residual-VQ codes; both distilled into students that hear the guidance scale."
    )
    ModelConfig = A2PConfig
    stages = STAGES
    presets = {
        "paper": Preset(
            "the reference's sizes: face 512-d x 8 layers, body 256-d x 6, lip regressor 512-d, RVQ 4 x 1024 codes, "
            "guide 64-d x 6 layers; 20 s windows",
            {},
            {"batch_size": 32, "lr": 1e-4, "steps": 50000, "warmup_steps": 1000},
        ),
        "small": Preset(
            "the shipped model: face 128-d x 4 layers, body 128-d x 3, lip regressor 64-d x 3, RVQ 4 x 256 codes, "
            "guide 96-d x 3 layers; 5 s windows",
            _SMALL,
            {"batch_size": 32, "lr": 5e-4, "steps": 3000, "warmup_steps": 100, "decay_steps": 2900, "val_every": 500},
        ),
        "tiny": Preset("for tests: a few units, 2 s windows", _TINY, _TINY_TRAIN),
    }
    default_preset = "small"

    # -- data ------------------------------------------------------------------------------------
    def load_data(self, corpus: Path, config: A2PConfig, stage: str) -> TrainingData:
        try:
            config.check()
        except ValueError as exc:
            raise UserError(f"model 'a2p': {exc}") from None
        length, hop = example_length(config, stage)
        return window_data(corpus, length, hop, max(hop, length // 2), {}, stage=stage)

    def network(self, config: A2PConfig, bands: int, speakers: int, stage: str) -> torch.nn.Module:
        return A2P(config, bands, speakers, stage)

    def inherited(self, model: torch.nn.Module) -> tuple[str, ...]:
        assert isinstance(model, A2P)
        return model.inherited_names

    def init_hint(self, stage: str) -> str:
        return "RUN (" + ("--init FACE_RUN --init BODY_RUN" if stage == "distill" else "the previous stage") + ")"

    def after_initialise(self, model: torch.nn.Module, stage: str) -> None:
        """Distillation's students start as copies of their teachers."""
        if stage == "distill":
            for teacher in ("face", "body"):
                student, target = getattr(model, f"{teacher}_student"), getattr(model, f"{teacher}_target")
                copy_matching(getattr(model, teacher), student)
                target.load_state_dict(student.state_dict())

    # -- training --------------------------------------------------------------------------------
    def loss(
        self, model: torch.nn.Module, batch: Batch, ctx: StepContext
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        assert isinstance(model, A2P)
        losses = {
            "lip": lip_loss,
            "face": face_loss,
            "vq": vq_loss,
            "guide": guide_loss,
            "body": body_loss,
            "distill": distill_loss,
        }
        return losses[model.stage](model, batch, ctx.generator)

    def validate(self, model: torch.nn.Module, data: TrainingData, config: A2PConfig, stage: str) -> dict[str, float]:
        assert isinstance(model, A2P)
        return self.mean_validation_figures(model, data, examples=64)

    # -- export ----------------------------------------------------------------------------------
    def export_graphs(
        self, model: torch.nn.Module, config: A2PConfig, spec: DataSpec, stage: str
    ) -> Sequence[GraphSpec]:
        assert isinstance(model, A2P)
        from convodrive.training.recipes.a2p_export import export_graphs

        return export_graphs(model, spec)

    def card(self, config: A2PConfig, spec: DataSpec) -> str:
        speakers = ", ".join(spec.info.get("speakers", []))
        n = config.face_student_steps
        face_steps = {0: "as many steps as the body", 1: "1 step"}.get(n, f"{n} steps")
        students = {
            "guidance": "guidance-distilled: one pass for the teacher's two, sampled by DPM-Solver++",
            "consistency": "consistency-distilled, by their own few-step sampler",
        }[config.distillation]
        return (
            f"{self.description}\n\nFace denoiser {config.face_width}-d x {config.face_layers} layers, body denoiser "
            f"{config.body_width}-d x {config.body_layers} layers, lip regressor {config.lip_width}-d x "
            f"{config.lip_layers}, residual VQ {config.vq_levels} x {config.vq_codes} codes, guide transformer "
            f"{config.guide_width}-d x {config.guide_layers} layers (KV cache of {config.guide_band} tokens); "
            f"cosine schedule of {config.diffusion_steps} steps, x0 prediction; windows up to {config.window} frames, "
            f"continued from up to {config.context} known frames. Speakers: {speakers}.\n\n"
            "Use: `convodrive drive AUDIO --generator a2p -G model=THIS_FOLDER` (options: sampler, steps, "
            "face_steps, eta, guidance_face, guidance_gaze, guidance_lids, guidance_body, guidance_head, top_p, speaker, mode, blend). The teachers run by "
            "default (DDIM), or by DPM-Solver++(2M) in 4 body and 8 face steps (`sampler=dpm`); with "
            f"`sampler=distilled` the students do ({students}), and the distilled face takes "
            f"{face_steps} unless `face_steps` says otherwise."
        )


def example_length(config: A2PConfig, stage: str) -> tuple[int, int]:
    """Frames per training example of ``stage`` and the hop between examples."""
    if stage == "vq":
        return FPS * config.guide_seconds, 7  # a 7-frame hop varies which frames are the 1 fps poses
    if stage == "guide":
        return FPS * (config.guide_seconds + config.guide_audio_span - 1), 37
    if stage in ("body", "distill"):
        return HISTORY + config.window, max(1, config.window // 4)
    return config.window, max(1, config.window // 4)


def copy_matching(source: nn.Module, target: nn.Module) -> None:
    """Copy every tensor of ``source`` into the same-named, same-shaped tensor of ``target``."""
    own = target.state_dict()
    target.load_state_dict(
        {k: v for k, v in source.state_dict().items() if k in own and own[k].shape == v.shape}, strict=False
    )
