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

Distillation (``distill``): each denoiser's student starts as a copy of it and learns consistency
distillation (Song et al. 2023; as latent consistency models do, with the guidance scale as an
input): from a noisy point at grid step n, the guided teacher's DDIM step to grid step n-1, and
the student's exponential moving average's answer there, as the target of the student's answer
at step n; at the grid's first step the target is the teacher's x0 itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import BODY, FACE, FPS, MOUTH_COLUMNS, STAGES, VAD, A2PConfig
from convodrive.models.a2p_denoiser import Denoiser, Memory
from convodrive.models.a2p_guide import CausalConvs
from convodrive.models.common import masked_l2
from convodrive.neural.diffusion import cosine_schedule, ddim_step, noised
from convodrive.plumbing.errors import UserError
from convodrive.training.config import Preset
from convodrive.training.recipe import Batch, DataSpec, GraphSpec, Recipe, StartingPoint, StepContext, TrainingData
from convodrive.training.windows import window_data

HISTORY = FPS * (CausalConvs.receptive_field() - 1)
"""Frames before a body window whose 1 fps poses the VQ decoder's receptive field reaches."""
GUIDE_REACH = 15
"""A guide pose is known once the audio half a second past it has been heard."""

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
    "distill_skip": 125,
    "face_student_steps": 1,
}
"""The shipped model: teachers and students of both denoisers, about 33 MB as fp32 ONNX (the
mixed export, float denoiser steps and teacher memories and int8 elsewhere, 29.3 MB, fits the
package's 30 MB).

Its students learn on a coarse grid of 8 points (``distill_skip`` 125): in the few hundred steps
the script gives distillation, a finer grid of 50 points left the students far from their teachers
(4 steps, 3 test conversations: FD_g body 51.7 and face 33.7 against the teachers' DDIM 10, 27.6
and 6.6), the consistency targets drifting, where 8 points reached 27.7 and 9.4 in 300 steps.
Its face student samples in one step by default (``face_student_steps``): at 4 it left the jaw open
in more silences (shut on 83 % of self-silent test frames, its teacher 98 %), at 1 it shuts on
97.5 % for a few points of FD_g face (9.4 against 8.8).

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


class A2PRecipe(Recipe):
    name = "a2p"
    description = (
        "audio2photoreal (Ng et al., CVPR 2024): a face diffusion model conditioned on both voices and a lip "
        "regressor, and a body diffusion model conditioned on both voices and guide poses at 1 fps sampled by an "
        "autoregressive transformer over residual-VQ codes; both distilled to a few-step consistency sampler."
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

    def build_model(self, config: A2PConfig, spec: DataSpec, stage: str) -> torch.nn.Module:
        bands = int(spec.info["corpus"]["audio_features"]["bands"])
        model = A2P(config, bands, len(spec.info["speakers"]), stage)
        model.audio_norm.mean.copy_(torch.from_numpy(spec.arrays["audio_mean"]))
        model.audio_norm.std.copy_(torch.from_numpy(spec.arrays["audio_std"]))
        return model

    def initialise(self, model: torch.nn.Module, start: StartingPoint | None, spec: DataSpec, stage: str) -> None:
        """A stage starts from the runs of the stages it builds on (``--init``, repeatable)."""
        assert isinstance(model, A2P)
        needed = model.inherited_names
        if not needed:
            super().initialise(model, start, spec, stage)
            return
        if start is None:
            raise UserError(
                f"model 'a2p': the {stage} stage starts from trained {', '.join(needed)} networks: --init RUN "
                f"({'--init FACE_RUN --init BODY_RUN' if stage == 'distill' else 'the previous stage'})"
            )
        for key in ("mean", "std", "audio_mean", "audio_std"):
            if not np.allclose(start.spec.arrays[key], spec.arrays[key], atol=1e-5):
                raise UserError(f"--init {start.path}: learnt from other data (its normalisation differs)")
        own = model.state_dict()
        for name in needed:
            keys = [k for k in own if k.startswith(f"{name}.")]
            bad = [k for k in keys if k not in start.weights or start.weights[k].shape != own[k].shape]
            if bad:
                raise UserError(
                    f"--init {start.path}: holds no trained {name} network of these settings (mismatch at {bad[0]}): "
                    "train that stage first, with the same preset"
                )
        model.load_state_dict({k: v for k, v in start.weights.items() if k in own}, strict=False)
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
        return (
            f"{self.description}\n\nFace denoiser {config.face_width}-d x {config.face_layers} layers, body denoiser "
            f"{config.body_width}-d x {config.body_layers} layers, lip regressor {config.lip_width}-d x "
            f"{config.lip_layers}, residual VQ {config.vq_levels} x {config.vq_codes} codes, guide transformer "
            f"{config.guide_width}-d x {config.guide_layers} layers (KV cache of {config.guide_band} tokens); "
            f"cosine schedule of {config.diffusion_steps} steps, x0 prediction; windows up to {config.window} frames, "
            f"continued from up to {config.context} known frames. Speakers: {speakers}.\n\n"
            "Use: `convodrive drive AUDIO --generator a2p -G model=THIS_FOLDER` (options: sampler, steps, "
            "face_steps, eta, guidance_face, guidance_body, top_p, speaker, mode, blend). The teachers run by "
            "default (DDIM); with `sampler=distilled` the students do, and the distilled face takes "
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


# --------------------------------------------------------------------------------- batch helpers
def _randint(low: int, high: int, generator: torch.Generator) -> int:
    """An int in [low, high]."""
    return int(torch.randint(low, high + 1, (), generator=generator))


def crop(length: int, config: A2PConfig, generator: torch.Generator) -> tuple[int, int]:
    """Offset and length of this step's window inside a ``length``-frame example (half the time
    the whole, else a random length of at least ``min_window``)."""
    if float(torch.rand((), generator=generator)) < 0.5 or length <= config.min_window:
        return 0, length
    size = _randint(config.min_window, length, generator)
    return _randint(0, length - size, generator), size


def known_prefix(batch: int, frames: int, config: A2PConfig, generator: torch.Generator) -> torch.Tensor:
    """(B, frames, 1): 1 on the known prefix of each example (none a quarter of the time, else
    1 to ``context`` frames)."""
    mask = torch.zeros(batch, frames, 1)
    for b in range(batch):
        if float(torch.rand((), generator=generator)) >= 0.25:
            mask[b, : _randint(1, min(config.context, frames - 1), generator)] = 1.0
    return mask


def keep_flags(batch: int, conditions: int, drop: float, generator: torch.Generator) -> torch.Tensor:
    """(B, n) 0/1: with probability ``drop`` an example loses every condition, else each one with
    probability ``drop / 2`` (classifier-free guidance needs the unconditional model most)."""
    everything = torch.rand(batch, 1, generator=generator) < drop
    each = torch.rand(batch, conditions, generator=generator) < drop / 2
    return (~(everything | each)).float()


def alpha_bar(config: A2PConfig) -> torch.Tensor:
    return torch.from_numpy(cosine_schedule(config.diffusion_steps)).float()


def noised_at(x0: torch.Tensor, steps: torch.Tensor, noise: torch.Tensor, config: A2PConfig) -> torch.Tensor:
    return noised(x0, noise, alpha_bar(config).to(x0.device)[steps][:, None, None])


def denoiser_loss(
    net: Denoiser,
    target: torch.Tensor,
    feature_mask: torch.Tensor,
    memory: Memory,
    config: A2PConfig,
    velocity_weight: float,
    generator: torch.Generator,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """x0 prediction at a uniform random diffusion step, on the frames not known, plus the
    velocity error (over all frames, so the seam with the known prefix counts)."""
    b, t, _ = target.shape
    device = target.device
    known = known_prefix(b, t, config, generator).to(device)
    steps = torch.randint(config.diffusion_steps, (b,), generator=generator).to(device)
    noise = torch.randn(target.shape, generator=generator).to(device)
    x0 = net.step(noised_at(target, steps, noise, config), steps, target, known, memory)
    rec = masked_l2(x0, target, feature_mask * (1 - known))
    vel = seam_velocity_error(x0, target, known, feature_mask)
    return rec + velocity_weight * vel, {"x0": rec.detach(), "velocity": vel.detach()}


def seam_velocity_error(
    x0: torch.Tensor, target: torch.Tensor, known: torch.Tensor, feature_mask: torch.Tensor
) -> torch.Tensor:
    """Velocity error of the motion as sampled, the known frames pinned (the sampler replaces
    them): the step from the last known frame to the first new one counts, which the prediction on
    the known frames, never used, would hide."""
    pinned = known * target + (1 - known) * x0
    return masked_l2(pinned.diff(dim=1), target.diff(dim=1), feature_mask)


def _window(batch: Batch, offset: int, size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return batch["motion"][:, offset : offset + size], batch["audio"][:, offset : offset + size], batch["mask"]


# ------------------------------------------------------------------------------------- the stages
def lip_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Mouth and self's voice activity from the audio as heard; the partner's activity from the
    audio with the channels swapped (the partner's mouth is not in the corpus)."""
    assert model.lip is not None
    offset, size = crop(batch["motion"].shape[1], model.config, generator)
    motion, audio, mask = _window(batch, offset, size)
    heard = model.audio_norm(audio)
    swapped = model.audio_norm(audio.flip(2))
    out = model.lip(torch.cat([heard, swapped]))
    own, other = out[: len(motion)], out[len(motion) :]
    columns = list(MOUTH_COLUMNS)
    mouth = masked_l2(own[..., :-1], motion[..., columns], mask[..., columns])
    vad_self = F.mse_loss(own[..., -1], motion[..., VAD.start])
    vad_other = F.mse_loss(other[..., -1], motion[..., VAD.start + 1])
    return mouth + vad_self + vad_other, {"mouth": mouth.detach(), "vad": (vad_self + vad_other).detach() / 2}


def face_conditions(model: A2P, audio: torch.Tensor) -> list[torch.Tensor]:
    """Both voices (normalised log-mel) and the frozen lip regressor's answer for self."""
    assert model.lip is not None
    heard = model.audio_norm(audio)
    with torch.no_grad():
        lip = model.lip(heard)
    return [heard, lip]


def face_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    assert model.face is not None
    offset, size = crop(batch["motion"].shape[1], model.config, generator)
    motion, audio, mask = _window(batch, offset, size)
    conditions = face_conditions(model, audio)
    keep = keep_flags(len(motion), 2, model.config.cond_drop, generator).to(motion.device)
    memory = model.face.memory(conditions, keep, batch["speaker"])
    return denoiser_loss(
        model.face,
        motion[..., FACE],
        mask[..., FACE],
        memory,
        model.config,
        model.config.face_velocity_weight,
        generator,
    )


def second_poses(motion: torch.Tensor, phase: int) -> torch.Tensor:
    """The body poses of every 30th frame from ``phase``: (B, K, body dims)."""
    return motion[:, phase::FPS, BODY]


def vq_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    assert model.vq is not None
    poses = second_poses(batch["motion"], _randint(0, FPS - 1, generator))
    return model.vq.loss(poses, batch["mask"][..., BODY], generator)


def guide_inputs(model: A2P, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
    """The (B, N) code targets of a guide example and the (B, S, 30, 2*bands) audio of its
    seconds and the span - 1 before: second k is the 30 frames centred on its pose's frame."""
    assert model.vq is not None
    config = model.config
    lead = FPS * (config.guide_audio_span - 1) + GUIDE_REACH
    motion = batch["motion"]
    with torch.no_grad():
        codes = model.vq.encode(second_poses(motion, lead))[:, : config.guide_seconds]
    heard = model.audio_norm(batch["audio"])
    seconds = config.guide_seconds + config.guide_audio_span - 1
    chunks = heard[:, : seconds * FPS].reshape(len(motion), seconds, FPS, -1)
    return codes.reshape(len(motion), -1), chunks


def guide_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Next-code cross-entropy with label smoothing 0.1 (the reference's), teacher forcing."""
    assert model.guide is not None
    targets, chunks = guide_inputs(model, batch)
    keep = (torch.rand(len(targets), generator=generator) >= model.config.cond_drop).float().to(targets.device)
    memory = model.guide.audio_memory(chunks, keep)
    start = torch.full((len(targets), 1), model.guide.start_token, dtype=torch.long, device=targets.device)
    inputs = torch.cat([start, targets[:, :-1]], dim=1)
    logits = model.guide(inputs, memory, batch["speaker"])
    loss = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), targets.reshape(-1), label_smoothing=0.1)
    accuracy = (logits.argmax(-1) == targets).float().mean()
    return loss, {"accuracy": accuracy.detach()}


def body_inputs(
    model: A2P, batch: Batch, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """From a body example (``HISTORY`` frames, then the window): this step's window motion and
    audio, and its guide poses as the runtime has them: decoded from the VQ codes of the 1 fps
    poses (the history's as the decoder's context), at their frames relative to the window, known
    from a second before the window to ``GUIDE_REACH`` frames before its end, a tenth dropped."""
    assert model.vq is not None
    offset, size = crop(batch["motion"].shape[1] - HISTORY, model.config, generator)
    begin = HISTORY + offset
    motion, audio = batch["motion"][:, begin : begin + size], batch["audio"][:, begin : begin + size]
    phase = _randint(0, FPS - 1, generator)
    with torch.no_grad():
        guides = model.vq.decode(model.vq.encode(second_poses(batch["motion"][:, : begin + size], phase)))
    positions = torch.arange(phase, begin + size, FPS, dtype=torch.float32, device=motion.device) - begin
    near = (positions >= -FPS) & (positions <= size - GUIDE_REACH)
    guides, positions = guides[:, near], positions[near][None].expand(len(motion), -1)
    valid = (torch.rand(positions.shape, generator=generator) >= 0.1).float().to(motion.device)
    return motion, audio, batch["mask"], guides, positions, valid


def body_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    assert model.body is not None
    motion, audio, mask, guides, positions, valid = body_inputs(model, batch, generator)
    keep = keep_flags(len(motion), 2, model.config.cond_drop, generator).to(motion.device)
    memory = model.body.memory([model.audio_norm(audio)], keep, batch["speaker"], guides, positions, valid)
    return denoiser_loss(
        model.body,
        motion[..., BODY],
        mask[..., BODY],
        memory,
        model.config,
        model.config.body_velocity_weight,
        generator,
    )


@torch.no_grad()
def update_target(student: nn.Module, target: nn.Module, decay: float) -> None:
    for s, t in zip(student.parameters(), target.parameters()):
        t.mul_(decay).add_(s.detach(), alpha=1 - decay)


def consistency_loss(
    teacher: Denoiser,
    student: Denoiser,
    target_net: Denoiser,
    memories: tuple[Memory, Memory, Memory],
    x0: torch.Tensor,
    feature_mask: torch.Tensor,
    guidance_max: float,
    config: A2PConfig,
    generator: torch.Generator,
) -> torch.Tensor:
    """One consistency-distillation term (see the module doc). ``memories``: the teacher's
    (conditional rows, then unconditional), the target's and the student's."""
    teacher_memory, target_memory, student_memory = memories
    b, t, _ = x0.shape
    device = x0.device
    skip, points = config.distill_skip, config.diffusion_steps // config.distill_skip
    known = known_prefix(b, t, config, generator).to(device)
    n = torch.randint(1, points + 1, (b,), generator=generator).to(device)
    step, previous = n * skip - 1, (n - 1) * skip - 1
    scale = (1 + torch.rand(b, generator=generator) * (guidance_max - 1)).to(device)
    noise = torch.randn(x0.shape, generator=generator).to(device)
    abar = alpha_bar(config).to(device)
    x = noised(x0, noise, abar[step][:, None, None])
    with torch.no_grad():
        both = teacher.step(
            torch.cat([x, x]), torch.cat([step, step]), torch.cat([x0, x0]), torch.cat([known, known]), teacher_memory
        )
        cond, uncond = both[:b], both[b:]
        guess = uncond + scale[:, None, None] * (cond - uncond)
        guess = known * x0 + (1 - known) * guess
        a_prev = torch.where(previous >= 0, abar[previous.clamp(min=0)], torch.ones(b, device=device))[:, None, None]
        x_prev = ddim_step(x, guess, abar[step][:, None, None], a_prev)
        answer = target_net.step(x_prev, previous.clamp(min=0), x0, known, target_memory, scale)
        answer = torch.where((previous < 0)[:, None, None], guess, answer)
    prediction = student.step(x, step, x0, known, student_memory, scale)
    return masked_l2(prediction, answer, feature_mask * (1 - known))


def distill_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    config = model.config
    assert model.face is not None and model.body is not None and model.face_student is not None
    assert model.body_student is not None and model.face_target is not None and model.body_target is not None
    update_target(model.face_student, model.face_target, config.distill_ema)
    update_target(model.body_student, model.body_target, config.distill_ema)
    motion, audio, mask, guides, positions, valid = body_inputs(model, batch, generator)
    b = len(motion)
    speaker = batch["speaker"]
    keep = torch.ones(b, 2, device=motion.device)
    both_keep = torch.cat([keep, torch.zeros(b, 2, device=motion.device)])
    face_cond = face_conditions(model, audio)
    heard = face_cond[0]
    with torch.no_grad():
        teacher_face = model.face.memory([torch.cat([c, c]) for c in face_cond], both_keep, speaker.repeat(2))
        target_face = model.face_target.memory(face_cond, keep, speaker)
        teacher_body = model.body.memory(
            [torch.cat([heard, heard])],
            both_keep,
            speaker.repeat(2),
            guides.repeat(2, 1, 1),
            positions.repeat(2, 1),
            valid.repeat(2, 1),
        )
        target_body = model.body_target.memory([heard], keep, speaker, guides, positions, valid)
    student_face = model.face_student.memory(face_cond, keep, speaker)
    student_body = model.body_student.memory([heard], keep, speaker, guides, positions, valid)
    face = consistency_loss(
        model.face,
        model.face_student,
        model.face_target,
        (teacher_face, target_face, student_face),
        motion[..., FACE],
        mask[..., FACE],
        config.face_guidance_max,
        config,
        generator,
    )
    body = consistency_loss(
        model.body,
        model.body_student,
        model.body_target,
        (teacher_body, target_body, student_body),
        motion[..., BODY],
        mask[..., BODY],
        config.body_guidance_max,
        config,
        generator,
    )
    return face + body, {"face": face.detach(), "body": body.detach()}
