"""probtalk's refiner and the spine, which the PQ-VAE's codes leave near its mean: the column
groups its losses name (``REFINER_GROUPS``), and the distance term that asks each speaking style
for its own posture (``refiner_fd_by_speaker``)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from convodrive.models.probtalk_config import REFINER_GROUPS
from convodrive.motion import representation as rep
from tests.conftest import require
from tests.models.test_probtalk import DIM, TINY, _batch

pytestmark = require("torch")


def test_the_spine_is_the_upper_body_s_first_three_joints_and_the_groups_split_the_body() -> None:
    upper = rep.feature_names()[rep.SPINE.start : rep.SPINE.stop]
    assert {name.split(".")[1] for name in upper} == {"spine1", "spine2", "spine3"}
    assert rep.SPINE.start == rep.PARTS["upper"].start
    body = set(REFINER_GROUPS["body"])
    spine, rest = set(REFINER_GROUPS["spine"]), set(REFINER_GROUPS["body_but_spine"])
    assert spine | rest == body and not spine & rest
    assert set(REFINER_GROUPS["face"]) == set(range(rep.GROUPS["face"].start, rep.GROUPS["face"].stop))
    with pytest.raises(ValueError, match="refiner_teacher_groups"):
        dataclasses.replace(TINY, refiner_teacher_groups=("arms",)).check()


def test_by_speaker_the_distance_asks_each_style_for_its_own_posture() -> None:
    """Two styles lean apart. A spine that gives each style the other's lean matches the pooled
    batch exactly, and only the distance taken by speaker sees it."""
    from convodrive.training.recipes.probtalk_losses import group_frechet

    g = torch.Generator().manual_seed(3)
    spine = REFINER_GROUPS["spine"]
    speakers = torch.tensor([0, 1] * 8)
    truth = _batch(16)["motion"]
    lean = torch.where(speakers == 0, 1.0, -1.0)[:, None, None]
    sway = torch.sin(torch.linspace(0, 3, 48)[None, :, None] + torch.rand(16, 1, len(spine), generator=g) * 6)
    truth[..., spine] = lean + 0.3 * sway
    swapped = truth.clone()
    swapped[..., spine] = truth[..., spine].roll(1, dims=0)  # each window gets the other style's
    near = truth + 0.1  # each style's own posture, a little off
    mask, known = torch.ones(16, 1, DIM), torch.zeros(16, 48, 1)

    def distance(made: torch.Tensor, by: torch.Tensor | None) -> float:
        return float(group_frechet(made, truth, mask, known, "spine", speakers=by))

    assert distance(swapped, None) < 0.5 * distance(near, None)  # the same rows, pooled
    assert distance(swapped, speakers) > 20 * distance(near, speakers)
    assert distance(near, speakers) == pytest.approx(distance(near, None), rel=0.5)


def test_the_refiner_loss_weighs_the_spine_s_distance_by_speaker_when_asked() -> None:
    """``refiner_fd_groups`` with ``spine`` adds the spine's distance to the refiner's loss, taken
    by speaker with ``refiner_fd_by_speaker`` (the same batch scores otherwise)."""
    from convodrive.models.probtalk import ProbTalk
    from convodrive.training.recipes.probtalk_losses import refiner_loss
    from tests.models.test_probtalk import BANDS, SPEAKERS

    x = _batch()
    x["speaker"] = torch.tensor([0, 1, 0, 1])
    x["motion"][..., REFINER_GROUPS["spine"]] += torch.tensor([1.0, -1.0, 1.0, -1.0])[:, None, None]
    known = torch.zeros(4, 48, 1)
    figures = {}
    for by_speaker in (False, True):
        torch.manual_seed(0)
        config = dataclasses.replace(
            TINY,
            refiner_noise=0.0,
            refiner_fd=0.1,
            refiner_fd_groups=("face", "spine"),
            refiner_fd_by_speaker=by_speaker,
        )
        model = ProbTalk(config, DIM, BANDS, SPEAKERS, stage="refiner").eval()
        with torch.no_grad():
            figures[by_speaker] = refiner_loss(model, x, known, torch.Generator().manual_seed(0))[1]
    assert {"face_fd", "spine_fd"} <= set(figures[True])
    assert float(figures[True]["spine_fd"]) != pytest.approx(float(figures[False]["spine_fd"]), rel=0.05)
