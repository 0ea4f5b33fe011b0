"""The reachy_mini backend against Reachy Mini's real daemon, in its mockup and MuJoCo simulations."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.backends.reachy.conftest import Daemon
from tests.conftest import require, run_cli

pytestmark = require("reachy")

from convodrive.backends.base import Session  # noqa: E402
from convodrive.backends.reachy import pose as rp  # noqa: E402
from convodrive.backends.reachy.expression import Expression, Part  # noqa: E402
from convodrive.backends.reachy_mini import ReachyMiniBackend  # noqa: E402
from convodrive.motion.channels import ConversationState  # noqa: E402
from convodrive.motion.clip import MotionFrame  # noqa: E402
from convodrive.motion.targets import TargetFrame  # noqa: E402
from convodrive.retargeting import load_profile  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
SPEC = load_profile("reachy_mini").spec
LIMITS = rp.Limits()


def test_limits_clamp_every_axis_and_keep_yaw_relative_to_body() -> None:
    wild = np.array([0.05, -0.05, -0.08, 1.2, -1.5, 4.0, 3.1, -4.0, 4.0])
    out = LIMITS.clamp(wild)
    assert LIMITS.within(out) and not LIMITS.within(wild)
    assert out[rp.Z] == pytest.approx(-0.025) and abs(out[rp.X]) == pytest.approx(0.015)
    assert out[rp.ROLL] == pytest.approx(math.radians(40)) and out[rp.PITCH] == pytest.approx(-math.radians(40))
    assert out[rp.BODY] == pytest.approx(math.radians(155))
    assert out[rp.YAW] == pytest.approx(math.radians(175))  # never across the +-180 wrap
    turned = LIMITS.clamp(np.array([0, 0, 0, 0, 0, -2.5, -0.5, 0, 0]))
    assert turned[rp.YAW] - turned[rp.BODY] == pytest.approx(-math.radians(60))
    assert list(out[rp.ANTENNAS]) == [-3.0, 3.0]
    head = np.array([0.004, -0.002, 0.01, 0.3, -0.2, 0.5, 0.0, 0.0, 0.0])
    assert np.allclose(rp.head_from_matrix(rp.head_matrix(head)), head[:6])


def test_listening_sways_the_head_only_while_the_partner_speaks() -> None:
    """The sway follows the partner's voice (none in silence, none with listening=0); the tilt
    follows the attention and is held through the silence after the partner."""

    def frame(state: ConversationState) -> MotionFrame:
        motion = MotionFrame.neutral()
        motion.state = state
        return motion

    def path(expression: Expression, state: ConversationState, seconds: float) -> tuple[float, Part]:
        parts = [expression.step(frame(state), 1 / 30) for _ in range(int(seconds * 30))]
        head = np.array([p.head for p in parts])
        return float(np.abs(np.diff(head, axis=0)).sum()), parts[-1]

    lively, quiet = Expression(0.3), Expression(0.3, listening=0.0)
    silent_path, _ = path(lively, ConversationState.SILENCE, 3)
    listening_path, listening = path(lively, ConversationState.LISTENING, 4)
    after_path, after = path(lively, ConversationState.SILENCE, 3)
    quiet_path, _ = path(quiet, ConversationState.LISTENING, 4)
    assert silent_path == 0.0 and quiet_path == 0.0
    assert math.degrees(listening_path) / 4 > 10.0  # deg/s of sway, summed over the axes
    assert after_path / 3 < 0.25 * listening_path / 4  # it stops quickly after the partner does
    assert math.degrees(after.head[0]) == pytest.approx(5.0, abs=0.3)  # the tilt, held by the attention


def _open(daemon: Daemon, **options: object) -> ReachyMiniBackend:
    backend = ReachyMiniBackend({"host": daemon.host, "port": daemon.port, "ease_s": 0.3, **options})
    backend.open(SPEC, Session(out_dir=Path("."), offline=False))
    return backend


@pytest.mark.parametrize("client", ["websocket", pytest.param("sdk", marks=pytest.mark.reachy_sdk)])
def test_unreachable_frames_are_clamped_and_the_head_follows(reachy_mockup: Daemon, client: str) -> None:
    """Frames far outside the limits: the daemon would drop them; clamped, the head goes there.
    Alike through the daemon's protocol spoken directly and through the official SDK client."""
    backend = _open(reachy_mockup, client=client)
    try:
        wild = SPEC.neutral.copy()
        wild[SPEC.index["head_pitch"]] = 3.0  # far past what the IK reaches
        wild[SPEC.index["head_z"]] = -0.2
        for i in range(20):
            backend.send(TargetFrame(i, i / 30, wild, ()))
            backend._hurry.wait(1 / 30)
        back = backend.link.latest()
    finally:
        backend.close()
    report = backend.report()
    assert back[rp.PITCH] == pytest.approx(math.radians(40), abs=math.radians(1.5))
    assert back[rp.Z] == pytest.approx(-0.025, abs=0.0015)
    assert report["clamped_frames"] == 20 and report["commands_outside_limits"] == 0
    # A 40 deg jump may leave one read-back in between (the daemon's FK converges over a tick or
    # two), never a run of them: a dropped pose would leave the head at neutral.
    assert report["readbacks_off_command"] <= 2 and report["eased_to_neutral"]
    assert report["client"] == client and report["follow"]["lag_ms"] is not None, report
    assert report["status"] == "ok", report


@pytest.mark.slow
def test_drive_dialogue_into_the_mockup(reachy_mockup: Daemon, tmp_path: Path) -> None:
    """The must-show run: 30 commands a second, all within limits, the head following, livelier
    while the partner speaks than in silence, and a calm neutral at the end."""
    out = tmp_path / "out"
    result = run_cli(
        "drive", str(ROOT / "samples" / "dialogue.wav"), "--backend", "reachy_mini", "--out", str(out),
        "-B", f"reachy_mini.port={reachy_mockup.port}",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    report = json.loads((out / "run_report.json").read_text())["backends"]["reachy_mini"]["report"]
    print(
        json.dumps({k: report[k] for k in ("commands_per_s", "follow", "liveliness", "neutral_error", "set_target_ms")})
    )
    assert report["status"] == "ok", report.get("reason")
    assert report["commands_per_s"] == pytest.approx(30.0, abs=0.5)
    assert report["commands"] >= 24.9 * 30 and report["unsent"] == 0 and report["disconnects"] == 0
    assert report["commands_outside_limits"] == 0 and report["readbacks_off_command"] == 0
    follow = report["follow"]
    assert 0 < follow["lag_ms"] <= 150 and follow["head_rms_deg"] <= 1.5 and follow["position_rms_mm"] <= 1.5
    # Livelier while the partner speaks, as the daemon read the robot back (not only as commanded).
    for live in (report["liveliness"]["readback"], report["liveliness"]["commanded"]):
        assert live["listening"]["seconds"] >= 5 and live["silence"]["seconds"] >= 0.5, live
        assert live["listening"]["head_deg_s"] >= 1.5 * live["silence"]["head_deg_s"], live
        assert live["listening"]["antennas_rad_s"] >= 1.5 * live["silence"]["antennas_rad_s"], live
    assert report["eased_to_neutral"] and report["neutral_error"]["head_deg"] <= 1.5


@pytest.mark.slow
def test_physical_sim_reaches_the_clamped_limits(reachy_mujoco: Daemon) -> None:
    """In MuJoCo (PD actuators, the real joint ranges) the clamped extremes are reached, not dropped:
    the backend's limits lie inside what the robot does."""
    backend = _open(reachy_mujoco)
    corners = []
    try:
        # One axis at a time: pitch 40 deg with z -25 mm together is beyond the sim's joints (26 deg).
        for pitch, roll, z in ((3.0, 0.0, 0.0), (-3.0, 0.0, 0.0), (0.0, 3.0, 0.0), (0.0, 0.0, -0.2)):
            wild = SPEC.neutral.copy()
            wild[SPEC.index["head_pitch"]], wild[SPEC.index["head_roll"]] = pitch, roll
            wild[SPEC.index["head_z"]] = z
            for i in range(30):  # one second held: the PD actuators lag some 150-200 ms
                backend.send(TargetFrame(i, i / 30, wild, ()))
                backend._hurry.wait(1 / 30)
            corners.append(backend.link.latest())
    finally:
        backend.close()
    report = backend.report()
    # A dropped pose would leave the head where it was (the other extreme or neutral); reached, the
    # PD actuators under gravity and load settle a few degrees short of it (35-38 deg for 40).
    reached = (corners[0][rp.PITCH], -corners[1][rp.PITCH], corners[2][rp.ROLL])
    assert all(math.radians(30) <= v <= math.radians(44) for v in reached), np.degrees(reached)
    assert corners[3][rp.Z] == pytest.approx(-0.025, abs=0.002)
    assert report["commands_outside_limits"] == 0 and report["eased_to_neutral"]
    assert 0 < report["follow"]["lag_ms"] <= 400
