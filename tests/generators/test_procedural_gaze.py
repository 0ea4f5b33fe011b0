"""The gaze options: how often self looks away from the partner, and how far."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.eval.behaviour import GAZE_AT_PARTNER_DEG
from convodrive.generators.procedural import ProceduralGenerator
from convodrive.motion.skeleton import JOINT_INDEX as J
from tests.procedural_dialogues import make

pytestmark = [pytest.mark.espeak]


@pytest.fixture(scope="module")
def audio(tmp_path_factory):
    return make("alternating", tmp_path_factory.mktemp("gaze"))[1]


def gaze_figures(audio, **options: float) -> tuple[float, float]:
    """Share of frames looking away (eyes beyond the at-partner cone) and the mean angle of those
    frames, over four takes."""
    gen = ProceduralGenerator({**options, "phones": False})
    eye = np.concatenate(
        [
            np.degrees(np.linalg.norm(clip.pose[:, J["left_eye_smplhf"]], axis=1))
            for clip in gen.generate(audio, seed=3, num_samples=4)
        ]
    )
    away = eye > GAZE_AT_PARTNER_DEG
    return float(away.mean()), float(eye[away].mean()) if away.any() else 0.0


def test_aversion_sets_how_often_self_looks_away(audio):
    never, _ = gaze_figures(audio, gaze_aversion=0)
    default, _ = gaze_figures(audio)
    often, _ = gaze_figures(audio, gaze_aversion=2.5)
    assert never == 0.0  # only the small saccades around the partner's face
    assert default > 0.05
    assert often > 1.3 * default


def test_range_sets_how_far(audio):
    share_near, near = gaze_figures(audio, gaze_range=0.5)
    share_default, default = gaze_figures(audio)
    _, far = gaze_figures(audio, gaze_range=2)
    assert near < 0.75 * default and far > 1.5 * default
    assert share_near > 0  # the looks away still happen, only smaller
