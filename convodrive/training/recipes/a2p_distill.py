"""``a2p``'s distillation stage: both denoisers' students, by one of two methods
(``A2PConfig.distillation``), each student hearing the guidance scale as an input.

- ``guidance`` (Meng et al. 2023, their first stage): at a random step of the schedule, the student's
  x0 regresses onto the guided teacher's (conditional and unconditional pass combined). One pass
  of the student then does the teacher's two, and it is sampled by the teachers' own few-step
  solver (DPM-Solver++): the student inherits the solver's accuracy instead of learning a coarse
  trajectory.
- ``consistency`` (Song et al. 2023, as latent consistency models do): from a noisy point at grid
  step n, the guided teacher's DDIM step to grid step n-1, and the student's exponential moving
  average's answer there, as the target of the student's answer at step n; at the grid's first
  step the target is the teacher's x0 itself.
"""

from __future__ import annotations

import torch
from torch import nn

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import BODY, FACE, A2PConfig
from convodrive.models.a2p_denoiser import Denoiser, Memory
from convodrive.models.common import masked_l2
from convodrive.neural.diffusion import ddim_step, noised
from convodrive.training.recipe import Batch
from convodrive.training.recipes.a2p_losses import alpha_bar, body_inputs, face_conditions, known_prefix


@torch.no_grad()
def update_target(student: nn.Module, target: nn.Module, decay: float) -> None:
    for s, t in zip(student.parameters(), target.parameters()):
        t.mul_(decay).add_(s.detach(), alpha=1 - decay)


@torch.no_grad()
def guided_teacher(
    teacher: Denoiser,
    memory: Memory,
    x: torch.Tensor,
    step: torch.Tensor,
    x0: torch.Tensor,
    known: torch.Tensor,
    scale: torch.Tensor,
) -> torch.Tensor:
    """The teacher's guided x0 at (x, step): its conditional and unconditional rows (``memory``
    holds both, conditional first) in one batch, combined at ``scale`` (B,)."""
    b = len(x)
    both = teacher.step(
        torch.cat([x, x]), torch.cat([step, step]), torch.cat([x0, x0]), torch.cat([known, known]), memory
    )
    cond, uncond = both[:b], both[b:]
    return uncond + scale[:, None, None] * (cond - uncond)


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
        guess = guided_teacher(teacher, teacher_memory, x, step, x0, known, scale)
        guess = known * x0 + (1 - known) * guess
        a_prev = torch.where(previous >= 0, abar[previous.clamp(min=0)], torch.ones(b, device=device))[:, None, None]
        x_prev = ddim_step(x, guess, abar[step][:, None, None], a_prev)
        answer = target_net.step(x_prev, previous.clamp(min=0), x0, known, target_memory, scale)
        answer = torch.where((previous < 0)[:, None, None], guess, answer)
    prediction = student.step(x, step, x0, known, student_memory, scale)
    return masked_l2(prediction, answer, feature_mask * (1 - known))


def guided_regression_loss(
    teacher: Denoiser,
    student: Denoiser,
    memories: tuple[Memory, Memory],
    x0: torch.Tensor,
    feature_mask: torch.Tensor,
    guidance_max: float,
    config: A2PConfig,
    generator: torch.Generator,
) -> torch.Tensor:
    """One guidance-distillation term (see the module doc). ``memories``: the teacher's
    (conditional rows, then unconditional) and the student's."""
    teacher_memory, student_memory = memories
    b, t, _ = x0.shape
    device = x0.device
    known = known_prefix(b, t, config, generator).to(device)
    step = torch.randint(config.diffusion_steps, (b,), generator=generator).to(device)
    scale = (1 + torch.rand(b, generator=generator) * (guidance_max - 1)).to(device)
    noise = torch.randn(x0.shape, generator=generator).to(device)
    x = noised(x0, noise, alpha_bar(config).to(device)[step][:, None, None])
    guess = guided_teacher(teacher, teacher_memory, x, step, x0, known, scale)
    prediction = student.step(x, step, x0, known, student_memory, scale)
    return masked_l2(prediction, guess, feature_mask * (1 - known))


def distill_loss(model: A2P, batch: Batch, generator: torch.Generator) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    config = model.config
    assert model.face is not None and model.body is not None and model.face_student is not None
    assert model.body_student is not None and model.face_target is not None and model.body_target is not None
    consistency = config.distillation == "consistency"
    if consistency:
        update_target(model.face_student, model.face_target, config.distill_ema)
        update_target(model.body_student, model.body_target, config.distill_ema)
    motion, audio, mask, guides, positions, valid = body_inputs(model, batch, generator)
    b = len(motion)
    speaker = batch["speaker"]
    keep = torch.ones(b, 2, device=motion.device)
    face_keep = torch.cat([keep, torch.zeros(b, 2, device=motion.device)])
    # The guidance students learn the generator's DDIM default, guidance on the audio alone (the
    # unconditional pass keeps the guide poses); the consistency ones learned it on both.
    body_keep = face_keep.clone()
    if not consistency:
        body_keep[b:, 1] = 1.0
    face_cond = face_conditions(model, audio)
    heard = face_cond[0]
    with torch.no_grad():
        teacher_face = model.face.memory([torch.cat([c, c]) for c in face_cond], face_keep, speaker.repeat(2))
        teacher_body = model.body.memory(
            [torch.cat([heard, heard])],
            body_keep,
            speaker.repeat(2),
            guides.repeat(2, 1, 1),
            positions.repeat(2, 1),
            valid.repeat(2, 1),
        )
        targets = (
            {
                "face": model.face_target.memory(face_cond, keep, speaker),
                "body": model.body_target.memory([heard], keep, speaker, guides, positions, valid),
            }
            if consistency
            else {}
        )
    student_face = model.face_student.memory(face_cond, keep, speaker)
    student_body = model.body_student.memory([heard], keep, speaker, guides, positions, valid)
    parts = {
        "face": (model.face, model.face_student, model.face_target, FACE, config.face_guidance_max),
        "body": (model.body, model.body_student, model.body_target, BODY, config.body_guidance_max),
    }
    memories = {"face": (teacher_face, student_face), "body": (teacher_body, student_body)}
    terms = {}
    for name, (teacher, student, target, columns, guidance_max) in parts.items():
        x0, feature_mask = motion[..., columns], mask[..., columns]
        teacher_memory, student_memory = memories[name]
        if consistency:
            terms[name] = consistency_loss(
                teacher,
                student,
                target,
                (teacher_memory, targets[name], student_memory),
                x0,
                feature_mask,
                guidance_max,
                config,
                generator,
            )
        else:
            terms[name] = guided_regression_loss(
                teacher, student, (teacher_memory, student_memory), x0, feature_mask, guidance_max, config, generator
            )
    return terms["face"] + terms["body"], {k: v.detach() for k, v in terms.items()}
