"""Maps, filters, limits and IK: what the retargeter does to motion."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.clip import MotionClip
from convodrive.motion.rotations import euler_to_axis_angle
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.retargeting import Retargeter, RobotProfile, load_profile
from convodrive.retargeting.filters import CriticallyDampedFilter, OneEuroFilter

DT = 1.0 / 30


def random_clip(n: int, seed: int = 0, scale: float = 1.5) -> MotionClip:
    """Wild motion: random rotations everywhere and random face, far outside any joint's limits."""
    rng = np.random.default_rng(seed)
    clip = MotionClip.neutral(n)
    clip.pose[:] = rng.normal(0.0, scale, clip.pose.shape)
    clip.face[:] = rng.uniform(0.0, 1.0, clip.face.shape)
    return clip


def profile_of(joints: dict, smoothing: object = "none") -> RobotProfile:
    return RobotProfile.from_dict({"name": "t", "defaults": {"smoothing": smoothing}, "joints": joints}, "test.yaml")


def test_euler_split_recovers_head_yaw_pitch_roll():
    angles = np.array([0.4, -0.3, 0.2])
    clip = MotionClip.neutral(1)
    clip.pose[0, J["head"]] = euler_to_axis_angle(angles, "YXZ")
    joints = {
        n: {"source": {"rotation": "head", "euler": "YXZ", "axis": a}, "limits": [-1, 1]}
        for n, a in (("yaw", "Y"), ("pitch", 1), ("roll", "Z"))
    }
    values = Retargeter(profile_of(joints)).retarget_clip(clip)[0]
    np.testing.assert_allclose(values, angles, atol=1e-6)


def test_piecewise_map_sum_gain_offset_direction():
    joints = {
        "lid": {
            "sum": [{"blendshape": "eyeBlinkLeft", "weight": 0.5}, {"blendshape": "eyeBlinkRight", "weight": 0.5}],
            "limits": [0, 1],
        },
        "jaw": {
            "source": {"blendshape": "jawOpen", "map": [[0, 0], [0.5, 0.1], [1, 0.3]]},
            "limits": [-1, 1],
            "gain": 2.0,
            "offset": 0.05,
            "direction": -1,
        },
    }
    clip = MotionClip.neutral(1)
    clip.face[0, B["eyeBlinkLeft"]], clip.face[0, B["eyeBlinkRight"]], clip.face[0, B["jawOpen"]] = 1.0, 0.2, 0.75
    lid, jaw = Retargeter(profile_of(joints)).retarget_clip(clip)[0]
    assert lid == pytest.approx(0.6)
    assert jaw == pytest.approx(0.05 - 2.0 * 0.2)  # map(0.75) = 0.2, then direction, gain, offset


@pytest.mark.parametrize("name", ["servo_head", "convo_humanoid"])
def test_limits_hold_for_wild_motion(name):
    r = Retargeter(load_profile(name))
    spec = r.spec
    values = r.retarget_clip(random_clip(240))
    assert np.all(values >= spec.lower - 1e-9) and np.all(values <= spec.upper + 1e-9)
    speed = np.abs(np.diff(values, axis=0)) / DT
    assert np.all(speed <= spec.max_velocity + 1e-6)
    # Acceleration holds except where a position limit stops a joint short.
    acc = np.abs(np.diff(values, 2, axis=0)) / DT**2
    inside = np.all((values[1:-1] > spec.lower + 1e-6) & (values[1:-1] < spec.upper - 1e-6), axis=0)
    assert np.all(acc[:, inside] <= spec.max_acceleration[inside] * (1 + 1e-6) + 1e-6)


def test_streaming_matches_clip_and_reset_restarts():
    r = Retargeter(load_profile("servo_head"))
    clip = random_clip(60, seed=3, scale=0.3)
    whole = r.retarget_clip(clip)
    streamed = np.array([r(f) for f in clip.frames()])
    np.testing.assert_allclose(streamed, whole, atol=1e-9)
    r.reset()
    np.testing.assert_allclose(r(clip.frame(0)), whole[0], atol=1e-9)


def test_one_euro_reduces_jitter_but_follows_moves():
    rng = np.random.default_rng(1)
    noisy = 0.3 + rng.normal(0, 0.02, 300)
    f = OneEuroFilter(min_cutoff=1.0, beta=0.5)
    out = np.array([f(np.array([x]), DT)[0] for x in noisy])
    assert np.std(np.diff(out[30:])) < 0.25 * np.std(np.diff(noisy[30:]))
    step = np.r_[np.zeros(30), np.ones(60)]
    f.reset()
    out = np.array([f(np.array([x]), DT)[0] for x in step])
    assert out[-1] == pytest.approx(1.0, abs=0.02)


def test_critically_damped_never_overshoots():
    f = CriticallyDampedFilter(time_constant=0.05)
    out = np.array([f(np.array([x]), DT)[0] for x in np.r_[0.0, np.ones(60)]])
    assert np.all(np.diff(out) >= -1e-12) and out.max() <= 1.0 + 1e-12 and out[-1] > 0.999


def test_velocity_limit_slews_a_step():
    joints = {"j": {"source": {"blendshape": "jawOpen"}, "limits": [0, 1], "max_velocity": 1.5}}
    clip = MotionClip.neutral(30)
    clip.face[1:, B["jawOpen"]] = 1.0
    values = Retargeter(profile_of(joints)).retarget_clip(clip)[:, 0]
    np.testing.assert_allclose(np.diff(values)[:10], 1.5 * DT, rtol=1e-9)
    assert values[-1] == pytest.approx(1.0)


@pytest.mark.mujoco
@pytest.mark.gymnasium
def test_ik_reaches_hand_targets_on_gymnasium_humanoid():
    r = Retargeter(load_profile("gymnasium_humanoid"))
    clip = MotionClip.neutral(10)
    clip.pose[:, J["left_shoulder"], 2], clip.pose[:, J["right_shoulder"], 2] = -1.0, 1.0
    clip.pose[:, J["left_elbow"], 1], clip.pose[:, J["right_elbow"], 1] = -1.2, 1.2
    for i in range(len(clip.pose)):
        r.raw(clip.pose[i : i + 1], clip.translation[i : i + 1], clip.face[i : i + 1])
    elbows, hands = r.ik.last_errors[[0, 2]], r.ik.last_errors[[1, 3]]
    assert np.all(hands < 0.03), hands  # hands (cost 1.0) reach their targets
    assert np.all(elbows < 0.1), elbows  # elbows (cost 0.5) come close: the arm proportions differ
    untouched = r.retarget_clip(MotionClip.neutral(3))
    assert not np.allclose(untouched[-1], r.raw(clip.pose[:1], clip.translation[:1], clip.face[:1])[0], atol=0.1)


@pytest.mark.mujoco
def test_ik_head_task_agrees_with_the_exact_axis_map():
    """IK on the humanoid's neck, aimed at the canonical head's pose, finds the axis map's answer."""
    base = load_profile("convo_humanoid")
    neck = ("neck_yaw", "neck_pitch", "neck_roll")
    data = {
        "name": "ik_head",
        "model": str(base.model_path),
        "defaults": {"smoothing": "none"},
        "joints": {n: {"limits": [-0.8, 0.8]} for n in neck},
        "ik": {
            "joints": list(neck),
            "root": {"canonical": "spine3", "body": "torso"},
            "iterations": 8,
            "tasks": [
                {
                    "frame": "head",
                    "canonical": "head",
                    "anchor": {"canonical": "neck", "body": "neck"},
                    "position_cost": 1.0,
                    "orientation_cost": 1.0,
                }
            ],
        },
    }
    r = Retargeter(RobotProfile.from_dict(data, "ik_head.yaml"))
    target = np.array([0.4, 0.25, -0.15])  # yaw, pitch, roll
    clip = MotionClip.neutral(1)
    clip.pose[0, J["neck"]] = euler_to_axis_angle(target, "YXZ")
    for _ in range(3):
        values = r.raw(clip.pose, clip.translation, clip.face)[0]
    np.testing.assert_allclose(values, target, atol=0.02)
    assert r.ik.last_errors[0] < 0.005
