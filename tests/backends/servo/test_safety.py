"""Property: whatever frames arrive, no command outside the configured limits reaches a servo."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from convodrive.backends.servo.safety import Ease, RawMap, Refused, SafetyGuard
from convodrive.motion.targets import TargetSpec

finite = st.floats(-3.0, 3.0, allow_nan=False)
wild = st.one_of(st.floats(-10.0, 10.0), st.just(float("nan")), st.just(float("inf")), st.just(-float("inf")))


@st.composite
def profiles(draw):  # type: ignore[no-untyped-def]
    n = draw(st.integers(1, 7))
    lower = np.array([draw(st.floats(-2.0, 0.5)) for _ in range(n)])
    upper = lower + np.array([draw(st.floats(0.01, 2.5)) for _ in range(n)])
    neutral = lower + (upper - lower) * np.array([draw(st.floats(0, 1)) for _ in range(n)])
    vmax = np.array([draw(st.sampled_from([np.inf, 0.5, 3.0, 20.0])) for _ in range(n)])
    amax = np.array([draw(st.sampled_from([np.inf, 5.0, 60.0, 800.0])) for _ in range(n)])
    spec = TargetSpec("p", tuple(f"j{i}" for i in range(n)), lower, upper, neutral, vmax, amax, ("rad",) * n)
    # Calibration: ticks (X-series, 1024-tick XL-320) or quarter-microseconds, either direction,
    # with a raw range that covers at least part of the joint range.
    scale = np.array([draw(st.sampled_from([651.9, -651.9, 195.6, -2400.0, 2400.0])) for _ in range(n)])
    zero = np.array([draw(st.floats(500, 3500)) for _ in range(n)])
    ends = np.sort(np.stack([zero + scale * lower, zero + scale * upper]), axis=0)
    inner = np.array([draw(st.floats(0.0, 0.45)) for _ in range(n)])
    low = np.floor(ends[0] + inner * (ends[1] - ends[0]))
    high = np.ceil(ends[1] - inner * (ends[1] - ends[0]) * np.array([draw(st.floats(0, 1)) for _ in range(n)]))
    return spec, RawMap(zero, scale, low, np.maximum(low, high))


@settings(max_examples=120, deadline=None)
@given(profile=profiles(), data=st.data())
def test_no_command_outside_limits(profile, data) -> None:  # type: ignore[no-untyped-def]
    spec, raw_map = profile
    guard = SafetyGuard(spec, raw_map)
    n = len(spec.names)
    guard.reset(data.draw(st.lists(finite, min_size=n, max_size=n)))
    for _ in range(data.draw(st.integers(1, 25))):
        frame = np.array(data.draw(st.lists(st.one_of(finite, wild), min_size=n, max_size=n)))
        dt = data.draw(st.sampled_from([1 / 30, 1 / 15, 0.1, 1e-3]))
        before = guard.last.copy()
        try:
            values = guard.check(frame)
        except Refused:
            assert not np.all(np.isfinite(frame)) or not spec.within_limits(frame, 1e-6)
            assert np.array_equal(guard.last, before)
            continue
        command = guard.limit(values, dt)
        raw = guard.to_raw(command)
        assert np.all(command >= spec.lower) and np.all(command <= spec.upper)
        assert np.all(raw >= raw_map.low) and np.all(raw <= raw_map.high)
        # What the servo is told, read back in joint units, is within the limits up to one raw unit.
        back = raw_map.to_joint(raw)
        assert np.all(back >= spec.lower - 1 / np.abs(raw_map.scale))
        assert np.all(back <= spec.upper + 1 / np.abs(raw_map.scale))
        step = np.abs(command - before)
        assert np.all(step <= spec.max_velocity * dt + 1e-9)


def test_in_limit_trajectory_passes_unchanged() -> None:
    n = 3
    spec = TargetSpec(
        "p", ("a", "b", "c"), -np.ones(n), np.ones(n), np.zeros(n), np.full(n, 5.0), np.full(n, 100.0), ("rad",) * n
    )
    guard = SafetyGuard(spec, RawMap(np.full(n, 2048.0), np.full(n, 651.9), np.zeros(n), np.full(n, 4095.0)))
    guard.reset(np.zeros(n))
    t = np.arange(60) / 30
    for row in 0.5 * np.sin(np.outer(t, [1.0, 2.0, 3.0])):
        assert np.array_equal(guard.limit(guard.check(row), 1 / 30), row)


def test_ease_starts_and_ends_at_rest() -> None:
    ease = Ease(np.zeros(1), np.ones(1), 1.0, t0=0.0)
    assert ease.at(0.0)[0] == 0.0 and ease.at(1.0)[0] == 1.0 and ease.at(2.0)[0] == 1.0
    assert ease.at(0.01)[0] < 0.001 and abs(ease.at(0.5)[0] - 0.5) < 1e-9
    assert ease.done(1.0) and not ease.done(0.9)
