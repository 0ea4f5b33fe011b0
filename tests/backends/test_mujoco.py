"""The mujoco backend end to end: physics, tracking report, offscreen mp4 with the audio muxed."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.synth import speak
from convodrive.backends.base import Session
from convodrive.backends.mujoco_sim import MujocoBackend
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.targets import TargetFrame
from convodrive.retargeting import Retargeter, load_profile

pytestmark = [pytest.mark.mujoco, pytest.mark.ffmpeg]


def speech(path: Path) -> float:
    """A spoken sentence from espeak-ng; returns its duration."""
    voice = speak("Hello there, how are you today?")
    sf.write(path, voice, 16000)
    return len(voice) / 16000


def talking_clip(n: int) -> MotionClip:
    """Sinusoidal conversational motion: nods and turns, gestures, jaw, gaze, one blink."""
    t = np.arange(n) / 30.0
    clip = MotionClip.neutral(n)
    clip.pose[:, J["neck"], 1] = 0.25 * np.sin(2 * np.pi * 0.4 * t)
    clip.pose[:, J["neck"], 0] = 0.12 * np.sin(2 * np.pi * 0.9 * t)
    clip.pose[:, J["head"], 0] = 0.15 * np.sin(2 * np.pi * 0.7 * t + 1.0)
    clip.pose[:, J["head"], 2] = 0.08 * np.sin(2 * np.pi * 0.5 * t)
    clip.pose[:, J["left_shoulder"], 2] = -1.2 + 0.2 * np.sin(2 * np.pi * 0.6 * t)
    clip.pose[:, J["right_shoulder"], 2] = 1.2
    clip.pose[:, J["left_elbow"], 1] = -0.9 - 0.4 * np.sin(2 * np.pi * 0.8 * t)
    clip.pose[:, J["right_elbow"], 1] = 0.7
    clip.pose[:, J["jaw"], 0] = 0.12 + 0.12 * np.sin(2 * np.pi * 3.0 * t)
    clip.face[:, B["jawOpen"]] = clip.pose[:, J["jaw"], 0] / 0.3
    for eye in ("left_eye_smplhf", "right_eye_smplhf"):
        clip.pose[:, J[eye], 1] = 0.3 * np.sin(2 * np.pi * 0.3 * t)
    blink = (np.abs(t - t[n // 2]) < 0.1).astype(np.float32)
    clip.face[:, B["eyeBlinkLeft"]] = clip.face[:, B["eyeBlinkRight"]] = blink
    return clip


def drive(profile_name: str, clip: MotionClip, out_dir: Path, audio: Path | None = None, **options) -> MujocoBackend:
    profile = load_profile(profile_name)
    values = Retargeter(profile).retarget_clip(clip)
    backend = MujocoBackend({"model": str(profile.model_path), **profile.backend_options("mujoco"), **options})
    backend.open(profile.spec, Session(out_dir=out_dir, audio_path=audio, num_frames=len(values)))
    try:
        for i, row in enumerate(values):
            backend.send(TargetFrame(i, i / 30.0, row, (clip.frame(i),)))
    finally:
        backend.close()
    return backend


def ffprobe(path: Path) -> list[dict]:
    out = subprocess.run(
        [
            "ffprobe",
            "-v",
            "error",
            "-show_entries",
            "stream=codec_type,r_frame_rate,duration",
            "-of",
            "json",
            str(path),
        ],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(out)["streams"]


@pytest.mark.espeak
def test_humanoid_video_and_tracking(tmp_path):
    audio = tmp_path / "speech.wav"
    duration = speech(audio)
    clip = talking_clip(round(duration * 30))
    backend = drive("convo_humanoid", clip, tmp_path, audio)
    report = backend.report()
    assert report["video_error"] is None, report["video_error"]
    assert backend.outputs() == [tmp_path / "mujoco.mp4"]
    streams = {s["codec_type"]: s for s in ffprobe(tmp_path / "mujoco.mp4")}
    assert streams["video"]["r_frame_rate"] == "30/1"
    assert "audio" in streams
    assert abs(float(streams["video"]["duration"]) - duration) <= 1 / 30 + 1e-3
    assert report["frames"] == len(clip.pose) and report["refused_frames"] == 0
    neck_head = {k: v for k, v in report["tracking_deg"].items() if k.startswith(("neck", "head"))}
    assert len(neck_head) == 6 and all(v["rms"] <= 2.0 for v in neck_head.values()), neck_head
    # The joints really moved: the commanded neck swing is far larger than the tracking error.
    assert report["neck_head_rms_deg"] <= 2.0
    assert backend.data.qpos[backend.qadr[backend.spec.index["jaw"]]] != 0.0
    assert backend.health()["status"] == "ok"
    # Physics in lock step with the 30 fps clock: simulated time ends within one timestep of the clip.
    assert abs(report["sim_seconds"] - len(clip.pose) / 30.0) <= backend.model.opt.timestep


def test_rendering_failure_degrades_to_no_video(tmp_path, monkeypatch):
    import mujoco

    def broken(*args, **kwargs):
        raise RuntimeError("no GL context")

    monkeypatch.setattr(mujoco, "Renderer", broken)
    backend = drive("servo_head", talking_clip(15), tmp_path)
    report = backend.report()
    assert report["video"] is None and "no GL context" in report["video_error"]
    assert report["frames"] == 15 and backend.outputs() == []
    assert backend.health()["status"] == "degraded"
    assert not list(tmp_path.glob("*.mp4"))


def test_servo_twin_tracks_and_refuses_values_outside_limits(tmp_path):
    profile = load_profile("servo_head")
    backend = MujocoBackend({"video": False})
    backend.open(profile.spec, Session(out_dir=tmp_path))
    clip = talking_clip(30)
    values = Retargeter(profile).retarget_clip(clip)
    for i, row in enumerate(values):
        backend.send(TargetFrame(i, i / 30, row, (clip.frame(i),)))
    bad = profile.spec.upper + 0.5
    backend.send(TargetFrame(30, 1.0, bad, (clip.frame(0),)))
    backend.close()
    report = backend.report()
    assert report["refused_frames"] == 1 and report["frames"] == 30
    assert report["tracking_deg"]["neck_pan"]["rms"] < 2.0
    assert np.all(backend.data.ctrl[backend.act] <= profile.spec.upper + 1e-9)


@pytest.mark.gymnasium
def test_config_only_gymnasium_humanoid_bends_its_elbows(tmp_path):
    """Third-party MJCF, driven by a YAML file alone: elbows flex when the canonical elbows do."""
    import mujoco

    n = 45
    clip = MotionClip.neutral(n)
    bend = np.clip(np.arange(n) / 30.0 * 2.0 - 0.5, 0.0, 1.0) * 1.4  # straight, then flexing to 1.4 rad
    clip.pose[:, J["left_shoulder"], 2], clip.pose[:, J["right_shoulder"], 2] = -1.1, 1.1
    clip.pose[:, J["left_elbow"], 1], clip.pose[:, J["right_elbow"], 1] = -bend, bend
    profile = load_profile("gymnasium_humanoid")
    backend = MujocoBackend({"model": str(profile.model_path), **profile.backend_options("mujoco"), "video": False})
    values = Retargeter(profile).retarget_clip(clip)
    backend.open(profile.spec, Session(out_dir=tmp_path, num_frames=n))
    m, d = backend.model, backend.data
    reach = {}
    for i, row in enumerate(values):
        backend.send(TargetFrame(i, i / 30, row, (clip.frame(i),)))
        if i in (5, n - 1):
            for side in ("left", "right"):
                hand = d.geom(f"{side}_hand").xpos
                shoulder = d.body(f"{side}_upper_arm").xpos
                reach[side, i] = np.linalg.norm(hand - shoulder)
    backend.close()
    elbow = {s: backend.spec.index[f"{s}_elbow"] for s in ("left", "right")}
    for side in ("left", "right"):
        # Flexing the canonical elbow by 1.4 rad pulls the hand at least 7 cm toward the shoulder.
        assert reach[side, n - 1] < reach[side, 5] - 0.07, reach
        assert values[-1, elbow[side]] - values[5, elbow[side]] > 0.4
    assert backend.report()["refused_frames"] == 0
    assert "right_elbow" in backend.report()["added_actuators"]
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "root") == -1  # the free root was welded


@pytest.mark.espeak
def test_drive_cli_with_procedural_motion_meets_the_must_show(tmp_path):
    """`convodrive drive AUDIO --generator procedural --backend mujoco --config convo_humanoid.yaml`."""
    from convodrive.cli.main import main
    from convodrive.retargeting import load_profile

    audio = tmp_path / "speech.wav"
    duration = speech(audio)
    out = tmp_path / "out"
    config = load_profile("convo_humanoid").path
    code = main(
        [
            "drive",
            str(audio),
            "--generator",
            "procedural",
            "--backend",
            "mujoco",
            "--config",
            str(config),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    streams = {s["codec_type"]: s for s in ffprobe(out / "mujoco.mp4")}
    assert streams["video"]["r_frame_rate"] == "30/1" and "audio" in streams
    assert abs(float(streams["video"]["duration"]) - duration) <= 1 / 30 + 1e-3
    report = json.loads((out / "run_report.json").read_text())["backends"]["mujoco"]["report"]
    assert report["video_error"] is None
    neck_head = [v["rms"] for k, v in report["tracking_deg"].items() if k.startswith(("neck", "head"))]
    assert len(neck_head) == 6 and max(neck_head) <= 2.0
