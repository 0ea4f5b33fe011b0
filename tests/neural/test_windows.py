"""Window plans, the easing of a window's start onto the motion it continues, and the low-pass of its new frames."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.neural.windows import WindowPlan, ease_in, smooth_new_frames


def test_a_plan_covers_the_stream_in_hops_after_its_context() -> None:
    plan = WindowPlan(150, 30)
    assert plan.hop == 120 and plan.start(0) == -30 and plan.start(2) == 210
    assert plan.windows_for(241) == 3 and plan.lookahead_frames == 119
    with pytest.raises(ValueError, match="context < window"):
        WindowPlan(30, 30)


def test_ease_in_continues_the_context_and_fades_out() -> None:
    rng = np.random.default_rng(0)
    context = np.cumsum(rng.standard_normal((2, 10, 5)), axis=1).astype(np.float32)
    motion = rng.standard_normal((2, 40, 5)).astype(np.float32) + 5.0  # a window that jumps away
    motion[:, :10] = context
    out = ease_in(motion, context, 12)
    np.testing.assert_allclose(out[:, 10], 2 * context[:, -1] - context[:, -2], atol=1e-5)  # the context's velocity
    np.testing.assert_array_equal(out[:, :10], context)  # known frames kept
    np.testing.assert_array_equal(out[:, 22:], motion[:, 22:])  # the model's own motion after the blend
    offsets = (out - motion)[:, 10:22]
    assert np.all(np.abs(offsets[:, 1:]) <= np.abs(offsets[:, :-1]) + 1e-6)  # fading
    np.testing.assert_array_equal(ease_in(motion, context, 0), motion)


def test_smoothing_calms_a_shiver_but_keeps_the_gesture_the_context_and_the_other_channels() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(60, dtype=np.float32)
    gesture = np.sin(2 * np.pi * t / 45)[None, :, None]  # a 1.5 s swing, as the corpus gestures
    shiver = 0.1 * rng.standard_normal((2, 60, 4)).astype(np.float32)
    motion = np.concatenate([gesture + shiver, shiver], axis=2)  # (2, 60, 8): smooth the first 4
    out = smooth_new_frames(motion, keep=10, sigma=1.5, channels=slice(0, 4))
    np.testing.assert_array_equal(out[:, :10], motion[:, :10])  # the context is already out
    np.testing.assert_array_equal(out[..., 4:], motion[..., 4:])  # other channels untouched
    acceleration = lambda x: np.abs(np.diff(x[:, 10:, :4], 2, axis=1)).mean()  # noqa: E731
    assert acceleration(out) < acceleration(motion) / 4
    assert np.abs(out[:, 15:50, :4] - gesture[:, 15:50]).max() < 0.15  # the swing itself stays
    np.testing.assert_array_equal(smooth_new_frames(motion, 10, 0.0), motion)
