"""ProbTalk's networks: shapes, losses that fall on a tiny batch, the codebook's EMA and resets,
frozen earlier stages, and MaskGIT decoding in NumPy equal to the torch reference."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from convodrive.models.common import masked_l2
from convodrive.models.probtalk import ProbTalk
from convodrive.models.probtalk_blocks import sinusoid
from convodrive.models.probtalk_config import ProbTalkConfig
from convodrive.models.probtalk_pqvae import OverlapAdd, ProductQuantizer
from convodrive.models.probtalk_predictor import maskgit_sample
from convodrive.motion import representation as rep
from convodrive.neural.maskgit import draw_uniforms, remask_count
from convodrive.neural.maskgit import maskgit_sample as numpy_maskgit_sample
from tests.conftest import require

pytestmark = require("torch")

DIM, BANDS, SPEAKERS = 330, 80, 3


TINY = ProbTalkConfig(
    codes=16,
    code_dim=8,
    vq_channels=(32, 32, 32, 32),
    vq_layers=1,
    context_channels=(8, 8, 16, 16),
    audio_channels=16,
    width=32,
    heads=2,
    layers=2,
    feedforward=64,
    refiner_width=32,
    refiner_heads=2,
    refiner_layers=1,
    refiner_feedforward=64,
    speaker_dim=8,
    dropout=0.0,
    window=48,
    min_window=16,
)


def _batch(b: int = 4, t: int = 48, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    time = torch.linspace(0, 6, t)
    phase = torch.rand(b, 1, DIM, generator=g) * 6
    motion = torch.sin(time[None, :, None] + phase)  # smooth, learnable motion
    return {
        "motion": motion,
        "mask": torch.ones(b, 1, DIM),
        "audio": torch.randn(b, t, 2, BANDS, generator=g),
        "speaker": torch.arange(b) % SPEAKERS,
    }


def test_shapes_at_several_lengths() -> None:
    torch.manual_seed(0)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS).eval()
    for t in (16, 48, 184):
        x = _batch(2, t)
        codes = model.vq.encode(x["motion"])
        assert codes.shape == (2, t // 8, TINY.groups) and codes.max() < TINY.codes
        assert model.vq.decode(codes).shape == (2, t, DIM)
        known = torch.zeros(2, t, 1)
        known[:, :5] = 1
        tokens = codes.reshape(2, -1)
        logits = model.predictor(tokens, x["audio"], x["motion"], known, x["speaker"])
        assert logits.shape == (2, t // 8 * TINY.groups, TINY.codes)
        refined = model.refiner(model.vq.decode(codes), x["audio"], known, x["speaker"])
        assert refined.shape == (2, t, DIM)


def test_untrained_refiner_passes_motion_through_and_keeps_known_frames() -> None:
    torch.manual_seed(0)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS).eval()
    x = _batch(2)
    known = torch.zeros(2, 48, 1)
    known[:, :12] = 1
    assert torch.equal(model.refiner(x["motion"], x["audio"], known, x["speaker"]), x["motion"])
    with torch.no_grad():
        model.refiner.head.bias.fill_(0.5)
    out = model.refiner(x["motion"], x["audio"], known, x["speaker"])
    assert torch.equal(out[:, :12], x["motion"][:, :12])
    assert torch.allclose(out[:, 12:], x["motion"][:, 12:] + 0.5)


def _fit(model: ProbTalk, loss_fn, steps: int = 40, lr: float = 3e-3) -> tuple[float, float]:
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=lr)
    model.train()
    first = last = 0.0
    for step in range(steps):
        loss = loss_fn()
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = float(loss.detach()) if step == 0 else first
        last = float(loss.detach())
    return first, last


def test_each_stage_loss_falls_on_a_tiny_batch() -> None:
    torch.manual_seed(0)
    x = _batch()
    vq = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq")
    first, last = _fit(vq, lambda: vq.vq.loss(x["motion"], x["mask"])[0])
    assert last < 0.6 * first

    pred = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="predictor")
    pred.load_state_dict(vq.state_dict(), strict=False)
    codes = pred.vq.encode(x["motion"]).reshape(4, -1)
    known = torch.zeros(4, 48, 1)
    masked = codes.clone()
    masked[:, ::2] = TINY.mask_id

    def ce() -> torch.Tensor:
        logits = pred.predictor(masked, x["audio"], x["motion"], known, x["speaker"])
        return torch.nn.functional.cross_entropy(logits.flatten(0, 1), codes.flatten())

    first, last = _fit(pred, ce)
    assert last < 0.5 * first

    ref = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="refiner")
    coarse = x["motion"] + 0.3 * torch.randn_like(x["motion"])
    first, last = _fit(ref, lambda: (ref.refiner(coarse, x["audio"], known, x["speaker"]) - x["motion"]).abs().mean())
    assert last < 0.8 * first


def test_the_pq_vae_error_is_l1_or_its_square() -> None:
    """``vq_loss``: the paper's L1, or squared error (which follows a two-valued channel's mean
    where L1 settles on its median: a blink channel's median is an open eye)."""
    import dataclasses

    x = _batch()
    x["mask"][..., 7] = 0
    for kind in ("l1", "l2"):
        torch.manual_seed(0)
        model = ProbTalk(dataclasses.replace(TINY, vq_loss=kind), DIM, BANDS, SPEAKERS, stage="vq").eval()
        with torch.no_grad():
            _, figures = model.vq.loss(x["motion"], x["mask"])
            recon = model.vq(x["motion"] * x["mask"])[0]
        error = (recon - x["motion"])[..., torch.arange(DIM) != 7]
        expected = error.abs().mean() if kind == "l1" else error.square().mean()
        assert float(figures[kind]) == pytest.approx(float(expected), rel=1e-5)
    with pytest.raises(ValueError, match="vq_loss"):
        dataclasses.replace(TINY, vq_loss="huber").check()


def test_the_refiner_error_is_l1_or_its_square() -> None:
    """``refiner_loss``: the paper's L1, or squared error, whose optimum is each channel's mean
    rather than its median, so a mouth shape held in a few frames of ten is not flattened away."""
    from convodrive.training.recipes.probtalk_losses import refiner_loss

    x = _batch()
    x["mask"][..., 7] = 0
    known = torch.zeros(4, 48, 1)
    for kind in ("l1", "l2"):
        torch.manual_seed(0)
        config = dataclasses.replace(TINY, refiner_loss=kind, refiner_noise=0.0)
        model = ProbTalk(config, DIM, BANDS, SPEAKERS, stage="refiner").eval()
        with torch.no_grad():
            _, figures = refiner_loss(model, x, known, torch.Generator().manual_seed(0))
            coarse = model.vq.decode(model.vq.encode(x["motion"] * x["mask"]))  # an untrained refiner passes it
        error = (coarse - x["motion"])[..., torch.arange(DIM) != 7]
        expected = error.abs().mean() if kind == "l1" else error.square().mean()
        assert set(figures) == {kind, "velocity", f"coarse_{kind}"}
        assert float(figures[kind]) == pytest.approx(float(expected), rel=1e-5)
        assert float(figures[f"coarse_{kind}"]) == pytest.approx(float(expected), rel=1e-5)
    with pytest.raises(ValueError, match="refiner_loss"):
        dataclasses.replace(TINY, refiner_loss="huber").check()


def test_the_frechet_loss_is_fd_g_and_its_gradient_restores_a_shrunken_spread() -> None:
    """``frechet_loss`` is the metric's own formula, also where two channels move as one (a blink's
    lids: a zero eigenvalue), and descending it gives motion regressed towards its mean its spread back."""
    from convodrive.eval.distribution import frechet_distance
    from convodrive.models.common import frechet_loss

    g = torch.Generator().manual_seed(0)
    real = torch.randn(600, 6, generator=g, dtype=torch.float64) @ torch.randn(6, 6, generator=g, dtype=torch.float64)
    real[:, 1] = real[:, 0]
    made = (0.3 * real + 0.05 * torch.randn(600, 6, generator=g, dtype=torch.float64)).requires_grad_(True)
    expected = frechet_distance(made.detach().numpy(), real.numpy())
    assert float(frechet_loss(made, real)) == pytest.approx(expected, abs=2 * 6 * 1e-6**0.5)  # its eps's bias
    optimizer = torch.optim.Adam([made], lr=0.05)
    for _ in range(100):
        optimizer.zero_grad()
        frechet_loss(made, real).backward()
        optimizer.step()
    assert torch.isfinite(made).all()
    assert frechet_distance(made.detach().numpy(), real.numpy()) < 0.1 * expected
    assert float(made.detach().std(0).mean()) > 0.8 * float(real.std(0).mean())


def test_the_refiner_fd_term_adds_the_weighted_distance_of_each_group_on_its_own() -> None:
    """``refiner_fd`` adds its weight times ``group_frechet`` of each group it names, and each group's
    distance looks at that group only: a change to the body leaves the face's as it was."""
    from convodrive.training.recipes.probtalk_losses import group_frechet, refiner_loss

    x = _batch()
    known = torch.zeros(4, 48, 1)
    known[:, :8] = 1.0
    totals = {}
    for weight, groups in ((0.0, ("face", "body")), (0.5, ("face", "body")), (0.5, ("face",))):
        torch.manual_seed(0)
        config = dataclasses.replace(TINY, refiner_noise=0.0, refiner_fd=weight, refiner_fd_groups=groups)
        model = ProbTalk(config, DIM, BANDS, SPEAKERS, stage="refiner").eval()
        with torch.no_grad():
            totals[weight, groups], figures = refiner_loss(model, x, known, torch.Generator().manual_seed(0))
    assert set(figures) == {"l1", "velocity", "coarse_l1", "face_fd"}
    both = float(totals[0.5, ("face", "body")] - totals[0.0, ("face", "body")])
    face = float(totals[0.5, ("face",)] - totals[0.0, ("face", "body")])
    assert face == pytest.approx(0.5 * float(figures["face_fd"]), rel=1e-4)
    assert both > face > 0
    made = x["motion"] + 0.1 * torch.randn(x["motion"].shape, generator=torch.Generator().manual_seed(1))
    moved = made.clone()
    moved[..., rep.GROUPS["body"]] += 1.0
    for group, changes in (("face", False), ("body", True)):
        before = float(group_frechet(made, x["motion"], x["mask"], known, group))
        after = float(group_frechet(moved, x["motion"], x["mask"], known, group))
        assert before > 0
        assert (after > before + 0.5) if changes else after == pytest.approx(before, rel=1e-6)
    with pytest.raises(ValueError, match="refiner_fd_groups"):
        dataclasses.replace(TINY, refiner_fd_groups=("hands",)).check()


def test_by_voice_the_distance_sees_a_mouth_that_moves_in_silence_instead_of_in_speech() -> None:
    """Pooled over all frames, a face that moves while self is silent and rests while self speaks has
    the true face's distribution; ``by_voice`` compares speech with speech and silence with silence."""
    from convodrive.training.recipes.probtalk_losses import group_frechet

    g = torch.Generator().manual_seed(0)
    frames, block = 96, 16
    speaking = (torch.arange(frames) // block) % 2 == 0
    face = rep.GROUPS["face"]
    real = torch.zeros(2, frames, DIM)
    real[..., rep.PARTS["vad"].start] = torch.where(speaking, 1.0, -1.0)
    moving = torch.randn(2, frames // 2, face.stop - face.start, generator=g).cumsum(dim=1) * 0.3
    real[:, speaking, face] = moving
    real[:, ~speaking, face] = -1.0
    swapped = real.clone()
    swapped[:, ~speaking, face], swapped[:, speaking, face] = real[:, speaking, face], real[:, ~speaking, face]
    mask, known = torch.ones(2, 1, DIM), torch.zeros(2, frames, 1)
    pooled = float(group_frechet(swapped, real, mask, known, "face"))
    apart = float(group_frechet(swapped, real, mask, known, "face", by_voice=True))
    same = float(group_frechet(real, real, mask, known, "face", by_voice=True))  # frechet_loss's eps bias
    assert apart > 10 * max(pooled, same)


def test_the_shut_mouth_error_counts_only_a_jaw_opened_past_the_truth_in_free_silent_frames() -> None:
    """``refiner_shut``: a jaw ajar where self is silent costs its excess; the same opening while self
    speaks, in known frames, or a jaw shut tighter than the truth, costs nothing."""
    from convodrive.training.recipes.probtalk_losses import JAW_OPEN, refiner_loss, shut_mouth_error

    frames = 40
    real = torch.zeros(2, frames, DIM)
    speaking = torch.arange(frames) >= 20
    real[..., rep.PARTS["vad"].start] = torch.where(speaking, 1.0, -1.0)
    mask, known = torch.ones(2, 1, DIM), torch.zeros(2, frames, 1)
    known[:, :5] = 1.0
    made = real.clone()
    made[:, :5, JAW_OPEN] = 3.0  # known frames: copied from the truth at run time, not the refiner's
    made[:, 20:, JAW_OPEN] = 3.0  # open while self speaks
    made[:, 5:10, JAW_OPEN] = -2.0  # shut tighter than the truth
    assert float(shut_mouth_error(made, real, mask, known)) == 0.0
    made[:, 10:20, JAW_OPEN] = 0.6  # ajar in half of the 15 free silent frames
    assert float(shut_mouth_error(made, real, mask, known)) == pytest.approx(0.6 * 10 / 15)
    no_jaw = mask.clone()
    no_jaw[..., JAW_OPEN] = 0.0
    assert float(shut_mouth_error(made, real, no_jaw, known)) == 0.0

    x, context = _batch(), torch.zeros(4, 48, 1)
    totals = {}
    for weight in (0.0, 2.0):
        torch.manual_seed(0)
        model = ProbTalk(dataclasses.replace(TINY, refiner_noise=0.0, refiner_shut=weight), DIM, BANDS, SPEAKERS).eval()
        with torch.no_grad():
            totals[weight], figures = refiner_loss(model, x, context, torch.Generator().manual_seed(0))
    assert float(figures["shut"]) > 0
    assert float(totals[2.0] - totals[0.0]) == pytest.approx(2 * float(figures["shut"]), rel=1e-4)


def test_the_acceleration_term_adds_the_weighted_second_difference_error() -> None:
    """``acceleration_weight``: the PQ-VAE's loss gains the weighted error of the second difference,
    which penalises frame-to-frame shiver that the velocity term lets through; 0 leaves it out."""
    x = _batch()
    totals = {}
    for weight in (0.0, 2.0):
        torch.manual_seed(0)
        config = dataclasses.replace(TINY, vq_loss="l2", acceleration_weight=weight)
        model = ProbTalk(config, DIM, BANDS, SPEAKERS, stage="vq").eval()
        with torch.no_grad():
            totals[weight], figures = model.vq.loss(x["motion"], x["mask"], torch.Generator().manual_seed(0))
            recon = model.vq(x["motion"] * x["mask"], torch.Generator().manual_seed(0))[0]
        assert ("acceleration" in figures) == bool(weight)
    expected = (recon.diff(n=2, dim=1) - x["motion"].diff(n=2, dim=1)).square().mean()
    assert float(figures["acceleration"]) == pytest.approx(float(expected), rel=1e-5)
    assert float(totals[2.0] - totals[0.0]) == pytest.approx(2 * float(expected), rel=1e-4)


def test_eyelid_part_weighs_the_two_lids_as_much_as_a_whole_part() -> None:
    """``eyelid_part``: the two blink channels carry as much of the error as the head's 12 channels
    or the rest of ARKit's 50, so that a PQ-VAE cannot leave blinks out for free."""
    import dataclasses

    from convodrive.motion.channels import ARKIT_NAMES
    from convodrive.training.recipes.probtalk_losses import EYELIDS, part_weights

    plain = part_weights(dataclasses.replace(TINY, balance_parts=True))
    weight = part_weights(dataclasses.replace(TINY, balance_parts=True, eyelid_part=True))
    assert plain is not None and weight is not None
    assert float(weight.mean()) == pytest.approx(1.0)
    arkit = rep.PARTS["arkit"]
    lids = [arkit.start + ARKIT_NAMES.index(n) for n in EYELIDS]
    rest = [c for c in range(arkit.start, arkit.stop) if c not in lids]
    lid_total, rest_total = float(weight[lids].sum()), float(weight[rest].sum())
    assert lid_total == pytest.approx(rest_total) == pytest.approx(float(weight[rep.PARTS["head"]].sum()))
    assert lid_total > 10 * float(plain[lids].sum()), "without it the lids weigh 2/52 of ARKit's share"


def test_spine_part_weighs_the_three_spine_joints_as_much_as_a_whole_part() -> None:
    """``spine_part``: spine1..3's 18 channels carry as much of the error as the head or the rest of
    the upper body, with the eyelids a part too when both are on."""
    import dataclasses

    from convodrive.training.recipes.probtalk_losses import SPINE_CHANNELS, part_weights

    assert SPINE_CHANNELS == 18
    weight = part_weights(dataclasses.replace(TINY, balance_parts=True, spine_part=True, eyelid_part=True))
    plain = part_weights(dataclasses.replace(TINY, balance_parts=True))
    assert weight is not None and plain is not None
    assert float(weight.mean()) == pytest.approx(1.0)
    upper = rep.PARTS["upper"]
    spine = list(range(upper.start, upper.start + 18))
    rest = list(range(upper.start + 18, upper.stop))
    head = float(weight[rep.PARTS["head"]].sum())
    assert float(weight[spine].sum()) == pytest.approx(head) == pytest.approx(float(weight[rest].sum()))
    assert float(weight[spine].sum()) > 2.5 * float(plain[spine].sum()), (
        "without it the spine weighs 18/66 of the upper body's share"
    )


def test_balanced_parts_weigh_a_small_part_as_much_as_a_large_one() -> None:
    """``balance_parts``: the same error confined to the head's 12 channels or to the hands' 180
    costs the PQ-VAE alike (channel-alike, the hands' costs 15 times more), and the loss keeps
    its scale (a mean weight of 1)."""
    import dataclasses

    from convodrive.training.recipes.probtalk_losses import part_weights

    assert part_weights(TINY) is None
    balanced = dataclasses.replace(TINY, balance_parts=True)
    weight = part_weights(balanced)
    assert weight is not None and weight.shape == (DIM,)
    assert float(weight.mean()) == pytest.approx(1.0)
    totals = {name: float(weight[part].sum()) for name, part in rep.PARTS.items()}
    assert totals["vad"] == pytest.approx(2.0)
    motion_totals = [v for name, v in totals.items() if name != "vad"]
    assert max(motion_totals) == pytest.approx(min(motion_totals))

    torch.manual_seed(0)
    model = ProbTalk(balanced, DIM, BANDS, SPEAKERS, stage="vq").eval()
    motion, mask = _batch()["motion"], torch.ones(4, 1, DIM)
    with torch.no_grad():
        recon = model.vq(motion)[0]

    def error_of(part: slice, w: torch.Tensor | None) -> float:
        # the motion moved away from its reconstruction by 1 on one part's channels only
        target = recon.clone()
        target[..., part] += 1.0
        return float(masked_l2(recon, target, mask if w is None else mask * w))

    head, hands = rep.PARTS["head"], rep.PARTS["hands"]
    assert error_of(head, weight) == pytest.approx(error_of(hands, weight), rel=1e-5)
    assert error_of(hands, None) == pytest.approx(15 * error_of(head, None), rel=1e-5)
    only_head = torch.zeros(DIM)
    only_head[head] = 1.0
    with torch.no_grad():
        _, figures = model.vq.loss(motion, mask, weight=only_head)
    assert float(figures["l1"]) == pytest.approx(float((recon - motion)[..., head].abs().mean()), rel=1e-5)


def _low_rank_motion(b: int, seed: int, t: int = 48) -> torch.Tensor:
    """Windows of three smooth signals (random phase and speed) spread over every channel by one
    fixed mixing: motion a few codes can describe, as a body's joints move together."""
    g = torch.Generator().manual_seed(seed)
    mixing = torch.randn(3, DIM, generator=torch.Generator().manual_seed(99)) / math.sqrt(3)
    time = torch.linspace(0, 1, t)[None, :, None]
    speed = 2 + 4 * torch.rand(b, 1, 3, generator=g)
    phase = 2 * math.pi * torch.rand(b, 1, 3, generator=g)
    return torch.sin(2 * math.pi * speed * time + phase) @ mixing


def test_the_pq_vae_encodes_unseen_motion_through_its_codes() -> None:
    """Held-out windows come back closer than the mean motion would, and other codes decode to
    other motion. (With each frame normalised over its channels, the decoder learnt to ignore its
    codes and every window decoded to the mean.)"""
    torch.manual_seed(0)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq")
    seeds = iter(range(1000))
    _fit(model, lambda: model.vq.loss(_low_rank_motion(8, next(seeds)), torch.ones(8, 1, DIM))[0], steps=150)
    model.eval()
    unseen = _low_rank_motion(16, seed=5000)
    with torch.no_grad():
        codes = model.vq.encode(unseen)
        decoded = model.vq.decode(codes)
        other = model.vq.decode(torch.randint(TINY.codes, codes.shape, generator=torch.Generator().manual_seed(0)))
    error = float((decoded - unseen).abs().mean())
    mean_error = float((unseen - unseen.mean(dim=(0, 1))).abs().mean())
    assert error < 0.9 * mean_error, (error, mean_error)  # 1.0 when codes are ignored
    assert float((other - decoded).abs().mean()) > 0.3 * mean_error


def test_the_vq_stage_reports_the_fd_g_its_reconstruction_allows() -> None:
    """The vq stage's validation scores its reconstruction as ``eval compare`` scores generated
    motion: 0 when it gives the motion back, the motion's own spread when it gives a constant, and
    channels a corpus lacks are left out."""
    from convodrive.training.recipes.probtalk_losses import reconstruction_fd

    batch = _batch(8)
    face = rep.GROUPS["face"]
    missing = face.start + 3
    batch["mask"][..., missing] = 0
    batch["motion"][..., missing] = 100.0 * torch.randn(8, 48)  # what a missing channel holds does not count

    def flat(motion: torch.Tensor) -> torch.Tensor:
        return motion.mean(dim=(0, 1), keepdim=True).expand_as(motion)

    perfect = reconstruction_fd(lambda motion: motion, batch)
    constant = reconstruction_fd(flat, batch)
    assert set(perfect) == {"recon_fd_g_face", "recon_fd_g_body"}
    assert max(perfect.values()) < 1e-6
    kept = [c for c in range(face.start, face.stop) if c != missing]
    spread = float(batch["motion"][..., kept].flatten(0, 1).double().var(dim=0).sum())
    assert constant["recon_fd_g_face"] == pytest.approx(spread, rel=0.01)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq").eval()
    with torch.no_grad():
        untrained = reconstruction_fd(lambda motion: model.vq(motion)[0], batch)
    assert all(math.isfinite(v) and v > 0.1 for v in untrained.values())


def test_codebooks_follow_the_latents_and_no_code_stays_dead() -> None:
    torch.manual_seed(0)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq").train()
    q = model.vq.quantizer
    x = _batch(8)
    g = torch.Generator().manual_seed(1)
    model.vq(x["motion"], g)  # first step: every code is dead and takes a latent of the batch
    latents = q.split(model.vq.encoder(x["motion"])).detach().reshape(-1, TINY.groups, TINY.code_dim)
    for group in range(TINY.groups):
        dist = torch.cdist(q.codebooks[group], latents[:, group], compute_mode="donot_use_mm_for_euclid_dist")
        assert float(dist.min(dim=1).values.max()) < 1e-5  # each code is one of the batch's latents
    assert bool((q.usage > 0).all())
    before = q.codebooks.clone()
    model.vq(x["motion"], g)
    assert not torch.equal(before, q.codebooks)  # EMA moved them
    model.eval()
    frozen = q.codebooks.clone()
    model.vq(x["motion"], g)
    assert torch.equal(frozen, q.codebooks)  # no updates in eval mode


def test_later_stages_freeze_the_earlier_ones() -> None:
    torch.manual_seed(0)
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="refiner").train()
    assert not model.vq.training and not model.predictor.training and model.refiner.training
    assert not any(p.requires_grad for p in model.vq.parameters())
    assert not any(p.requires_grad for p in model.predictor.parameters())
    assert model.vq.quantizer.updating is False
    names = set(model.state_dict())
    assert any(n.startswith("refiner.") for n in names) and not any(n.startswith("frozen") for n in names)
    assert ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq").predictor is None


def test_2d_positions_add_a_time_and_a_group_encoding() -> None:
    model = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="predictor")
    pos = model.predictor.positions(12, torch.device("cpu"))
    w = TINY.width
    assert torch.allclose(pos[6], sinusoid(torch.tensor(1), w) + sinusoid(torch.tensor(2), w))  # t=1, g=2
    flat = ProbTalk(TINY.__class__(**{**TINY.__dict__, "position": "1d"}), DIM, BANDS, SPEAKERS, stage="predictor")
    assert torch.allclose(flat.predictor.positions(12, torch.device("cpu"))[6], sinusoid(torch.tensor(6), w))


def _fake_logits(codes: int):
    """Logits that depend on the tokens already decided, like a real predictor's."""
    weights = np.random.default_rng(5).standard_normal((codes + 1, codes)) * 2.0

    def fn(tokens: np.ndarray) -> np.ndarray:
        context = weights[tokens].mean(axis=1, keepdims=True)
        position = np.sin(np.arange(tokens.shape[1])[None, :, None] * np.arange(1, codes + 1) * 0.37)
        return (context + 3.0 * position).astype(np.float32)

    return fn


@pytest.mark.parametrize("iterations", [1, 2, 8, 16])
def test_numpy_maskgit_equals_the_torch_reference(iterations: int) -> None:
    codes, length = 16, 24
    fn = _fake_logits(codes)
    rngs = [np.random.default_rng([7, k]) for k in range(3)]
    got = numpy_maskgit_sample(fn, length, codes, iterations, rngs, temperature=0.8)
    uniforms = torch.from_numpy(draw_uniforms([np.random.default_rng([7, k]) for k in range(3)], iterations, length))
    want = maskgit_sample(
        lambda t: torch.from_numpy(fn(t.numpy())), 3, length, TINY.__class__(codes=codes), iterations, uniforms, 0.8
    )
    assert np.array_equal(got, want.numpy())
    assert got.min() >= 0 and got.max() < codes  # every token decided
    alone = numpy_maskgit_sample(fn, length, codes, iterations, [np.random.default_rng([7, 1])], temperature=0.8)
    assert np.array_equal(alone[0], got[1])  # a take does not depend on the takes beside it


def test_maskgit_follows_the_cosine_schedule() -> None:
    codes, length, iterations = 16, 40, 8
    masked_seen: list[int] = []
    fn = _fake_logits(codes)

    def spy(tokens: np.ndarray) -> np.ndarray:
        masked_seen.append(int((tokens == codes).sum()))
        return fn(tokens)

    numpy_maskgit_sample(spy, length, codes, iterations, [np.random.default_rng(0)])
    expected = [length] + [remask_count(length, t, iterations) for t in range(iterations - 1)]
    assert masked_seen == expected
    assert expected[1] == math.floor(length * math.cos(math.pi / 16))
    assert remask_count(length, iterations - 1, iterations) == 0


def test_low_temperature_takes_the_most_likely_codes() -> None:
    codes, length = 16, 24
    fn = _fake_logits(codes)
    cold = numpy_maskgit_sample(fn, length, codes, 1, [np.random.default_rng(0)], temperature=1e-4)
    assert np.array_equal(cold[0], fn(np.full((1, length), codes)).argmax(-1)[0])
    varied = {tuple(numpy_maskgit_sample(fn, length, codes, 4, [np.random.default_rng(s)])[0]) for s in range(4)}
    assert len(varied) == 4


def test_each_take_may_have_its_own_temperature() -> None:
    codes, length = 16, 24
    fn = _fake_logits(codes)
    rngs = lambda: [np.random.default_rng([3, k]) for k in range(2)]  # noqa: E731
    mixed = numpy_maskgit_sample(fn, length, codes, 4, rngs(), temperature=np.array([0.5, 2.0]))
    for k, temperature in enumerate((0.5, 2.0)):
        alone = numpy_maskgit_sample(fn, length, codes, 4, [rngs()[k]], temperature=temperature)
        assert np.array_equal(mixed[k], alone[0])
    with pytest.raises(ValueError, match="one per take"):
        numpy_maskgit_sample(fn, length, codes, 4, rngs(), temperature=np.array([1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="temperature > 0"):
        numpy_maskgit_sample(fn, length, codes, 4, rngs(), temperature=np.array([1.0, 0.0]))


def test_codes_in_use_stay_put_and_a_replaced_code_is_not_replaced_again_at_once() -> None:
    """Latents from 6 clusters, 16 codes a book: 10 codes go unchosen, yet after the first steps
    no code is replaced again (a fixed threshold of one latent a step replaced them every step)."""
    torch.manual_seed(0)
    q = ProbTalk(TINY, DIM, BANDS, SPEAKERS, stage="vq").train().vq.quantizer
    g = torch.Generator().manual_seed(2)
    centres = torch.nn.functional.normalize(torch.randn(6, TINY.groups * TINY.code_dim), dim=-1)
    books = []
    for _ in range(60):
        pick = torch.randint(6, (4 * 5,), generator=g)
        latent = centres[pick] + 0.01 * torch.randn(20, TINY.groups * TINY.code_dim, generator=g)
        q(latent.reshape(4, 5, -1).transpose(1, 2), g)
        books.append(q.codebooks.clone())
    moved = [float((books[i] - books[i - 1]).norm(dim=-1).max()) for i in range(40, 60)]
    assert max(moved) < 0.05, moved  # no code jumps to a new latent late in training


def test_the_linear_path_lets_the_pq_vae_autoencoder_fit_what_its_stacks_alone_miss() -> None:
    """Motion that mixes 8 smooth signals into every channel: in the same steps the conv stacks alone
    (the reference's) leave much more of it unexplained by the encoder's continuous latent than with
    ``vq_skip``'s linear path beside them (on the corpus the small preset's stacks alone kept about
    half the motion's variance, where a linear map of each token's frames kept all of it)."""

    def unexplained(skip: bool) -> float:
        torch.manual_seed(0)
        config = dataclasses.replace(TINY, vq_skip=skip, vq_sphere=False)
        model = ProbTalk(config, DIM, BANDS, SPEAKERS, stage="vq")
        data = torch.Generator().manual_seed(100)
        mixing = torch.randn(8, DIM, generator=data) / math.sqrt(8)
        time = torch.linspace(0, 1, 48)[None, :, None]
        speed, phase = 1 + 3 * torch.rand(16, 1, 8, generator=data), 6 * torch.rand(16, 1, 8, generator=data)
        motion = torch.sin(2 * math.pi * speed * time + phase) @ mixing  # 0.22 unexplained alone, 0.002 with the path
        vq = model.vq
        optimizer = torch.optim.Adam(vq.parameters(), lr=3e-3)
        for _ in range(150):
            loss = F.mse_loss(vq.decoder(vq.encoder(motion)), motion)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        with torch.no_grad():
            decoded = vq.eval().decoder(vq.encoder(motion))
        return float((decoded - motion).square().mean() / motion.var())

    stacks, linear = unexplained(False), unexplained(True)
    assert linear < 0.5 * stacks, (stacks, linear)


@pytest.mark.parametrize("sphere", [True, False])
def test_off_the_sphere_the_codes_keep_the_latents_length(sphere: bool) -> None:
    """Latents along one direction at two lengths: on the sphere (``vq_sphere``) they are one point
    and take the same code (its value: the batch drew several copies of it); off it they take codes
    as far apart as they are (the length of a slice is
    most of the motion's amplitude)."""
    quantizer = ProductQuantizer(dataclasses.replace(TINY, vq_sphere=sphere)).train()
    direction = torch.randn(1, TINY.groups * TINY.code_dim, 1, generator=torch.Generator().manual_seed(0))
    latents = torch.cat([direction * (1 + 2 * (i % 2)) for i in range(8)], dim=2)  # lengths 1, 3, 1, 3, ...
    quantised, codes, _ = quantizer(latents, torch.Generator().manual_seed(1))  # the first step draws codes from these
    short, long = quantised[0, :, 0], quantised[0, :, 1]
    if sphere:
        assert torch.allclose(short, long, atol=1e-6)
    else:
        assert not torch.equal(codes[0, 0], codes[0, 1])
        assert torch.allclose(long.norm(), 3 * short.norm(), rtol=1e-4)


def test_overlap_add_decodes_independent_tokens_without_steps_at_their_borders() -> None:
    """Tokens drawn independently (as MaskGIT samples codes) decode to motion whose frame-to-frame
    change is as large at a token border as inside a token; a plain transposed conv of the same
    size steps at every border. And the windows sum to one: a kernel constant over its frames
    decodes a constant latent to a constant."""
    torch.manual_seed(0)
    hop, latent = 8, torch.randn(4, 16, 40)  # 40 independent tokens
    overlap = OverlapAdd(16, 6, hop)
    with torch.no_grad():  # smooth kernels, as training makes them, that do not end at zero
        shape = 1 + 0.5 * torch.sin(torch.arange(2 * hop) / 3 + torch.randn(16, 6, 1))
        overlap.conv.weight.copy_(torch.randn(16, 6, 1) * shape)
    plain = torch.nn.ConvTranspose1d(16, 6, 2 * hop, hop, hop // 2)
    plain.load_state_dict(overlap.conv.state_dict())

    def border_over_inside(net: torch.nn.Module) -> float:
        with torch.no_grad():
            speed = net(latent).diff(dim=-1).abs().mean(dim=(0, 1))[hop:-hop]  # away from the ends
        by_phase = torch.stack([speed[p::hop].mean() for p in range(hop)])
        return float(by_phase.max() / by_phase.median())

    assert border_over_inside(overlap) < 2 < 4 < border_over_inside(plain)  # 1.4 and 7.5
    with torch.no_grad():
        overlap.conv.weight.copy_(torch.randn(16, 6, 1).expand(16, 6, 2 * hop))
        steady = overlap(torch.randn(1, 16, 1).expand(1, 16, 10))[..., hop:-hop]
    assert torch.allclose(steady, steady[..., :1].expand_as(steady), atol=1e-4)


class _Fixed(torch.nn.Module):
    """A refiner that answers with given motion, whatever it is asked."""

    def __init__(self, motion: torch.Tensor) -> None:
        super().__init__()
        self.motion = motion

    def forward(self, *_: torch.Tensor) -> torch.Tensor:
        return self.motion


def test_with_refiner_shown_the_losses_read_the_face_as_the_run_shows_it() -> None:
    """``refiner_shown``: the shapes the run clips to [0, 1] are clipped in the losses too, so a
    shape pushed past rest while the truth rests costs nothing (it shows rest), a shape ajar while
    the truth rests costs its opening, and one held past rest while the truth moves still costs
    (and has a gradient): the error of every other channel is as before."""
    from convodrive.training.recipe import DataSpec
    from convodrive.training.recipes.probtalk import ProbTalkRecipe
    from convodrive.training.recipes.probtalk_losses import refiner_loss

    rng = np.random.default_rng(0)
    mean, std = rng.uniform(0.05, 0.2, DIM).astype(np.float32), rng.uniform(0.1, 0.3, DIM).astype(np.float32)
    spec = DataSpec(
        {"corpus": {"audio_features": {"bands": BANDS}}, "speakers": ["a", "b", "c"]},
        {"mean": mean, "std": std, "audio_mean": np.zeros(BANDS, np.float32), "audio_std": np.ones(BANDS, np.float32)},
    )
    config = dataclasses.replace(TINY, refiner_noise=0.0, refiner_loss="l2", refiner_fd=0.1, refiner_shown=True)
    model = ProbTalkRecipe().build_model(config, spec, "refiner").eval()  # as a new or a resumed run builds it
    assert isinstance(model, ProbTalk)
    raw = rng.normal(0.3, 0.6, (2, 16, DIM)).astype(np.float32)  # arkit values beyond both of [0, 1]
    shown = rep.encode(rep.decode(raw[0] * std + mean).pose, rep.decode(raw[0] * std + mean).face, np.zeros((16, 2)))
    low, high = model.shown_low.numpy(), model.shown_high.numpy()
    arkit = rep.PARTS["arkit"]
    assert np.allclose(np.clip(raw[0], low, high)[:, arkit], ((shown - mean) / std)[:, arkit], atol=1e-5)
    assert np.isinf(low[: arkit.start]).all() and np.isinf(high[arkit.stop :]).all()

    rest, shape = float(low[arkit.start + 5]), arkit.start + 5
    truth = torch.zeros(1, 16, DIM)
    truth[..., shape] = rest
    truth[:, 8:, shape] = rest + 2.0  # the truth moves in the last eight frames
    x = {"motion": truth, "mask": torch.ones(1, 1, DIM), "audio": torch.zeros(1, 16, 2, BANDS),
         "speaker": torch.zeros(1, dtype=torch.long)}  # fmt: skip
    known = torch.zeros(1, 16, 1)

    def error(offset_resting: float, offset_moving: float, shown: bool) -> float:
        made = truth.clone()
        made[:, :8, shape] += offset_resting
        made[:, 8:, shape] += offset_moving
        model.config = dataclasses.replace(model.config, refiner_shown=shown)
        model.refiner = _Fixed(made)
        figures = refiner_loss(model, x, known, torch.Generator().manual_seed(0))[1]
        return float(figures["l2"]), float(figures["face_fd"])

    assert error(-1.0, 0.0, shown=True)[0] == 0.0 < error(-1.0, 0.0, shown=False)[0]  # past rest: shows rest
    assert error(-1.0, 0.0, shown=True)[1] == pytest.approx(error(0.0, 0.0, shown=True)[1], abs=1e-6)  # its spread too
    assert error(-1.0, 0.0, shown=False)[1] > error(0.0, 0.0, shown=False)[1] + 0.1
    assert error(0.5, 0.0, shown=True) == pytest.approx(error(0.5, 0.0, shown=False))  # ajar: costs alike
    held_under = error(0.0, -2.5, shown=True)[0]  # held under rest while the truth moves
    assert held_under > 0 and held_under == pytest.approx(error(0.0, -2.5, shown=False)[0])
