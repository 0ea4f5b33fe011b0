"""The losses of ``probtalk``'s three training stages and the batch helpers they share: each
part's weight in the error, the random crop, the known-frame masks, and the refiner's
distribution term."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F

from convodrive.eval.distribution import fd_g
from convodrive.models.common import MASKED_ERRORS, frechet_loss
from convodrive.models.probtalk import ProbTalk
from convodrive.models.probtalk_config import REFINER_GROUPS, ProbTalkConfig
from convodrive.motion import representation as rep
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.training.recipe import Batch
from convodrive.training.recipes.probtalk_teacher import taught_target

EYELIDS = ("eyeBlinkLeft", "eyeBlinkRight")
"""The ARKit channels ``eyelid_part`` weighs as a part of their own."""
SPINE_CHANNELS = rep.SPINE.stop - rep.SPINE.start
"""spine1..3's 6D blocks, the first channels of the upper body: ``spine_part`` weighs them as a part."""


def part_weights(config: ProbTalkConfig, device: torch.device | str = "cpu") -> torch.Tensor | None:
    """(D,) error weights under which each motion part of the layout (jaw, eyes, ARKit, head, upper
    body, hands; the eyelids with ``eyelid_part``, the spine with ``spine_part``) counts alike, whatever its number of
    channels; voice activity keeps one channel's weight. The mean weight is 1, so the loss keeps its
    scale. None when ``balance_parts`` is off. On ``device``, the batch's: a CPU tensor times a CUDA
    mask fails."""
    if not config.balance_parts:
        return None
    parts = [np.arange(part.start, part.stop) for name, part in rep.PARTS.items() if name != "vad"]
    own = []
    if config.eyelid_part:
        own.append(rep.PARTS["arkit"].start + np.array([ARKIT_NAMES.index(n) for n in EYELIDS]))
    if config.spine_part:
        own.append(REFINER_GROUPS["spine"])
    for columns in own:
        parts = [np.setdiff1d(p, columns) for p in parts] + [columns]
    weight = np.ones(rep.FEATURE_DIM)
    channels = sum(len(p) for p in parts)
    for columns in parts:
        weight[columns] = channels / len(parts) / len(columns)
    return torch.from_numpy(weight).float().to(device)


def reconstruction_fd(reconstruct: Callable[[torch.Tensor], torch.Tensor], batch: Batch) -> dict[str, float]:
    """FD_g of face and body for a batch's motion passed through ``reconstruct`` (the PQ-VAE's
    encode and decode), on the channels every window has.

    ``eval compare`` scores generated motion by these figures, and no predictor can do better
    than the PQ-VAE's own reconstruction: the vq stage already shows the best the later ones can reach."""
    motion, mask = batch["motion"], batch["mask"]
    recon = reconstruct(motion * mask)
    kept = mask.amin(dim=0).flatten().bool().cpu()
    out = {}
    for part in ("face", "body"):
        cols = torch.arange(rep.GROUPS[part].start, rep.GROUPS[part].stop)
        cols = cols[kept[cols]]
        if len(cols):
            real = motion[..., cols].flatten(0, 1).double().cpu().numpy()
            made = recon[..., cols].flatten(0, 1).double().cpu().numpy()
            out[f"recon_fd_g_{part}"] = fd_g([made], [real])
    return out


def crop(batch: Batch, config: ProbTalkConfig, generator: torch.Generator) -> Batch:
    """The batch cut to one random length (half the time the whole window), a multiple of a token."""
    frames = batch["motion"].shape[1]
    f = config.frames_per_token
    if float(torch.rand((), generator=generator)) < 0.5 or frames <= config.min_window:
        return batch
    lengths = list(range(config.min_window, frames + 1, f))
    length = lengths[int(torch.randint(len(lengths), (), generator=generator))]
    start = int(torch.randint(frames - length + 1, (), generator=generator))
    return {k: v[:, start : start + length] if k in ("motion", "audio") else v for k, v in batch.items()}


def context_masks(batch: int, frames: int, config: ProbTalkConfig, generator: torch.Generator) -> torch.Tensor:
    """(B, frames, 1) known-frame masks: a quarter none, a quarter a block of ``context_frames`` at a
    random place (the reference's), half a prefix (the previous window's frames: ``context_frames``
    or a random length)."""
    kind = torch.rand(batch, generator=generator)
    t = torch.arange(frames)
    masks = torch.zeros(batch, frames, 1)
    block = max(1, min(config.context_frames, frames - 1))
    for b in range(batch):
        if kind[b] < 0.25:
            continue
        if kind[b] < 0.5:
            start = int(torch.randint(frames - block + 1, (), generator=generator))
            masks[b, :, 0] = ((t >= start) & (t < start + block)).float()
        else:
            upper = max(2, frames - config.frames_per_token)
            random_length = int(torch.randint(1, upper, (), generator=generator))
            length = block if kind[b] < 0.75 else random_length
            masks[b, :length, 0] = 1.0
    return masks


def predictor_loss(
    model: ProbTalk, batch: Batch, known: torch.Tensor, generator: torch.Generator
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """MaskGIT's objective: mask a cosine-distributed fraction of each window's codes, predict them."""
    assert model.predictor is not None
    config = model.config
    motion = batch["motion"] * batch["mask"]
    with torch.no_grad():
        target = model.vq.encode(motion).flatten(1)  # (B, N)
    b, n = target.shape
    ratio = torch.cos(torch.rand(b, generator=generator) * (math.pi / 2))
    count = torch.ceil(ratio * n).clamp(min=1).long().to(target.device)
    rank = torch.rand(b, n, generator=generator).argsort(dim=1).argsort(dim=1).to(target.device)
    masked = rank < count[:, None]
    tokens = torch.where(masked, torch.full_like(target, config.mask_id), target)
    audio = model.audio_norm(batch["audio"])
    logits = model.predictor(tokens, audio, motion, known, batch["speaker"])
    loss = F.cross_entropy(logits[masked], target[masked])
    accuracy = (logits[masked].argmax(-1) == target[masked]).float().mean()
    return loss, {"accuracy": accuracy.detach()}


def refiner_loss(
    model: ProbTalk, batch: Batch, known: torch.Tensor, generator: torch.Generator
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Error (``refiner_loss``: L1, the reference's, or squared) of the refined unknown frames against
    the truth, and of velocities everywhere (so the seam with the known frames counts), refining
    noisy VQ reconstructions (the reference's recipe); with ``refiner_teacher``, the target of its
    groups is that folder's refiner's output (``taught_target``); with ``refiner_fd``, plus the distance in distribution of
    each of ``refiner_fd_groups`` (``group_frechet``); with ``refiner_shut``, plus the jaw's
    opening past the truth in self's silence (``shut_mouth_error``)."""
    assert model.refiner is not None
    config = model.config
    motion, mask = batch["motion"], batch["mask"]
    with torch.no_grad():
        coarse = model.vq.decode(model.vq.encode(motion * mask))
        coarse = coarse + config.refiner_noise * torch.randn(coarse.shape, generator=generator).to(coarse.device)
    combined = known * motion + (1 - known) * coarse
    refined = model.refiner(combined, model.audio_norm(batch["audio"]), known, batch["speaker"])
    target = motion
    if config.refiner_teacher:
        groups = config.refiner_teacher_groups
        target = taught_target(
            config.refiner_teacher, groups, combined, batch["audio"], known, batch["speaker"], motion
        )
    shown, scored = refined, refined
    if config.refiner_shown:
        shown, scored = shown_motion(refined, target, model.shown_low, model.shown_high)
    weight = part_weights(config, mask.device)
    counted = mask if weight is None else mask * weight
    free = counted * (1 - known)
    name = config.refiner_loss
    error = MASKED_ERRORS[name]
    rec = error(scored, target, free)
    vel = error(scored.diff(dim=1), target.diff(dim=1), counted)
    coarse = error(combined, motion, free)
    loss, figures = (
        rec + config.velocity_weight * vel,
        {name: rec.detach(), "velocity": vel.detach(), f"coarse_{name}": coarse},
    )
    speakers = batch["speaker"] if config.refiner_fd_by_speaker else None
    for group in config.refiner_fd_groups if config.refiner_fd > 0 else ():
        distance = group_frechet(shown, motion, mask, known, group, config.refiner_fd_by_voice, speakers)
        loss = loss + config.refiner_fd * distance
        figures[f"{group}_fd"] = distance.detach()
    if config.refiner_shut > 0:
        ajar = shut_mouth_error(shown, motion, mask, known)
        loss = loss + config.refiner_shut * ajar
        figures["shut"] = ajar.detach()
    return loss, figures


def shown_motion(
    refined: torch.Tensor, target: torch.Tensor, low: torch.Tensor, high: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The refined motion as the run shows it (clipped to ``low``..``high``), and as its error
    reads it: clipped where the target sits at a bound, so that going past rest costs nothing
    when the truth rests, and unclipped elsewhere, so that a shape held under rest while the
    truth moves still has a gradient."""
    shown = torch.maximum(torch.minimum(refined, high), low)
    at_bound = (target <= low + 1e-3) | (target >= high - 1e-3)
    return shown, torch.where(at_bound, shown, refined)


def self_speaks(motion: torch.Tensor) -> torch.Tensor:
    """(B, T) frames where self speaks: normalised voice activity above 0, its mean. The one
    split of speech from silence that ``group_frechet`` and ``shut_mouth_error`` share."""
    return motion[..., rep.PARTS["vad"].start] > 0


JAW_OPEN = rep.PARTS["arkit"].start + ARKIT_NAMES.index("jawOpen")
"""The feature column of ARKit's ``jawOpen``, the channel ``eval`` reads the mouth's opening from."""


def shut_mouth_error(
    refined: torch.Tensor, motion: torch.Tensor, mask: torch.Tensor, known: torch.Tensor
) -> torch.Tensor:
    """Mean of how far the refined ``jawOpen`` rises above the true one over the free frames where
    self is silent (voice activity below its mean, 0 normalised), in normalised units; 0 when there
    are none or the windows lack the channel. One-sided: a jaw shut tighter than the truth in
    silence is the squared or L1 error's business, not this term's."""
    silent = ~self_speaks(motion) & (known[..., 0] == 0) & (mask[..., JAW_OPEN] > 0)
    excess = (refined[..., JAW_OPEN] - motion[..., JAW_OPEN]).clamp(min=0)
    return (excess * silent).sum() / silent.sum().clamp(min=1)


def group_frechet(
    refined: torch.Tensor,
    motion: torch.Tensor,
    mask: torch.Tensor,
    known: torch.Tensor,
    group: str,
    by_voice: bool = False,
    speakers: torch.Tensor | None = None,
) -> torch.Tensor:
    """FD_g + FD_k of one group (``REFINER_GROUPS``; ``face`` and ``body`` as ``eval compare`` scores them) over the
    batch's refined frames against the true ones: the frames (and frame pairs, for the velocities)
    no known context fixes, the group's channels every window has. The velocities are divided by
    the true ones' RMS over the group: normalised poses have about unit spread, their
    frame-to-frame steps a tenth of it, and would barely count (divided per channel, the channels
    that rest through a batch would count thousands of times over). ``by_voice``: the sum of the
    distances over the frames where self speaks and over those where self is silent (self's voice
    activity above or below its mean, 0 normalised), so that spread missing while speaking is not
    made up with a mouth that moves in silence. ``speakers`` (B,): the poses are taken relative to
    their speaker's true mean over the batch, made and true alike, so the distance asks for each
    style's own level and the spread within it, not the styles' pooled spread."""
    columns = torch.from_numpy(REFINER_GROUPS[group]).to(mask.device)
    columns = columns[mask.amin(dim=0).flatten()[columns] > 0]
    made, real = refined[..., columns], motion[..., columns]
    made_moves, real_moves = made.diff(dim=1), real.diff(dim=1)
    free = known[..., 0] == 0
    if speakers is not None:
        made, real = relative_to_speaker(made, real, speakers, free)
    spread = real_moves.square().mean().sqrt().clamp(min=1e-3).detach()  # velocities in their own units
    subsets = [free]
    if by_voice:
        speaking = self_speaks(motion)
        subsets = [free & speaking, free & ~speaking]
    distance = refined.new_zeros(())
    for rows in subsets:
        pairs = rows[:, 1:] & rows[:, :-1]
        if int(pairs.sum()) < 2:
            continue
        distance = distance + frechet_loss(made[rows], real[rows])
        distance = distance + frechet_loss(made_moves[pairs] / spread, real_moves[pairs] / spread)
    return distance


def relative_to_speaker(
    made: torch.Tensor, real: torch.Tensor, speakers: torch.Tensor, free: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``made`` and ``real`` (B, T, C) less the mean of ``real`` over the ``free`` (B, T) frames of
    the windows of each one's speaker (B,)."""
    offset = torch.zeros_like(real[:, :1])
    for speaker in speakers.unique():
        windows = speakers == speaker
        rows = free[windows]
        if int(rows.sum()):
            offset[windows] = real[windows][rows].mean(0).detach()
    return made - offset, real - offset
