"""The losses of ``a2p``'s training stages (lip, face, vq, guide, body) and the batch helpers they share.

Examples are cut each step to one random length, with a known prefix of random length, and each
condition dropped now and then (the ``a2p`` recipe's module doc says why).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import BODY, FACE, FPS, MOUTH_COLUMNS, VAD, A2PConfig
from convodrive.models.a2p_denoiser import Denoiser, Memory
from convodrive.models.a2p_guide import CausalConvs
from convodrive.models.common import masked_l2
from convodrive.neural.diffusion import cosine_schedule, noised
from convodrive.training.recipe import Batch

HISTORY = FPS * (CausalConvs.receptive_field() - 1)
"""Frames before a body window whose 1 fps poses the VQ decoder's receptive field reaches."""
GUIDE_REACH = 15
"""A guide pose is known once the audio half a second past it has been heard."""


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
