"""Behaviour figures of a motion clip against its conversation audio (``convodrive eval behaviour``).

Who is talking is measured from the audio itself, independently of the generator: a voice is
active where its frame RMS is within 30 dB of its loud speech (95th percentile) and 10 dB above
its noise floor (5th percentile), with gaps under 150 ms bridged, so the stop closures inside
words do not count as silence but pauses do.

Figures: lip sync (Pearson r of ``jawOpen`` with self's amplitude envelope), how often the mouth is
closed (``jawOpen`` < 0.05) while self is silent, split by whether the partner talks; mean head
angular speed while self speaks and while only the partner speaks, and their ratio; blink rates;
gaze toward the partner; arm motion.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.clip import MotionClip
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.skeleton import global_rotation
from convodrive.plumbing.errors import UserError

JAW_CLOSED = 0.05
_BRIDGE_FRAMES = 4


def frame_rms(voice: np.ndarray, num_frames: int, fps: float) -> np.ndarray:
    """RMS of each motion frame's samples (16 kHz), zero past the end of the audio."""
    edges = np.floor(np.arange(num_frames + 1) * 16000.0 / fps).astype(int)
    sq = np.concatenate([[0.0], np.cumsum(voice.astype(np.float64) ** 2)])
    edges = np.minimum(edges, len(voice))
    counts = np.maximum(edges[1:] - edges[:-1], 1)
    return np.sqrt((sq[edges[1:]] - sq[edges[:-1]]) / counts)


def voice_activity(rms: np.ndarray) -> np.ndarray:
    """Active frames of one voice: loud relative to its own speech, short gaps bridged."""
    db = 20 * np.log10(rms + 1e-10)
    loud = float(np.percentile(db, 95))
    floor = float(np.percentile(db, 5))
    if loud < -80.0 or loud - floor < 15.0:  # digital silence, or nothing stands out of the noise
        return np.zeros(len(rms), bool)
    threshold = max(loud - 30.0, floor + 10.0)
    active = db > threshold
    idx = np.flatnonzero(active)
    for a, b in zip(idx[:-1], idx[1:]):
        if 1 < b - a <= _BRIDGE_FRAMES + 1:
            active[a:b] = True
    return active


def envelope(rms: np.ndarray) -> np.ndarray:
    """Amplitude envelope: frame RMS smoothed over 100 ms."""
    return np.convolve(rms, np.array([0.25, 0.5, 0.25]), mode="same")


def head_angular_speed(clip: MotionClip) -> np.ndarray:
    """(T,) angular speed of the head's global orientation, degrees per second (0 for frame 0)."""
    glob = global_rotation(axis_angle_to_matrix(clip.pose), J["head"])
    rel = np.einsum("tji,tjk->tik", glob[:-1], glob[1:])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.concatenate([[0.0], np.arccos(cos)])) * clip.fps


def _mean(x: np.ndarray, mask: np.ndarray) -> float | None:
    return float(x[mask].mean()) if mask.any() else None


def _pearson(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) < 3 or a.std() < 1e-9 or b.std() < 1e-9:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def behaviour_figures(clip: MotionClip, audio: DyadicAudio) -> dict[str, Any]:
    """The figures as a JSON-ready dict. Raises UserError if clip and audio lengths disagree."""
    expected = int(round(audio.duration * clip.fps))
    if abs(expected - clip.num_frames) > 1:
        raise UserError(
            f"motion has {clip.num_frames} frames ({clip.duration:.2f} s) but the audio lasts {audio.duration:.2f} s "
            f"({expected} frames at {clip.fps:g} fps); they must belong together"
        )
    t = clip.num_frames
    rms_self, rms_other = frame_rms(audio.self_voice, t, clip.fps), frame_rms(audio.other_voice, t, clip.fps)
    self_on, other_on = voice_activity(rms_self), voice_activity(rms_other)
    env = envelope(rms_self)
    jaw = clip.face[:, B["jawOpen"]].astype(np.float64)
    silent = ~self_on
    closed = jaw < JAW_CLOSED
    speed = head_angular_speed(clip)
    only_partner = other_on & ~self_on
    speaking_speed = _mean(speed, self_on)
    listening_speed = _mean(speed, only_partner)
    minutes = lambda m: m.sum() / clip.fps / 60.0  # noqa: E731
    blink = clip.face[:, B["eyeBlinkLeft"]]
    blink_onsets = (blink[1:] >= 0.5) & (blink[:-1] < 0.5)
    blink_onsets = np.concatenate([[False], blink_onsets])
    gaze = np.degrees(np.linalg.norm(clip.pose[:, J["left_eye_smplhf"]], axis=1))
    arm_joints = [
        J[n] for n in ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
    ]
    arm_speed = np.concatenate(
        [[0.0], np.degrees(np.linalg.norm(np.diff(clip.pose[:, arm_joints], axis=0), axis=2).mean(axis=1)) * clip.fps]
    )

    def rate(mask: np.ndarray) -> float | None:
        return round(float(blink_onsets[mask].sum() / minutes(mask)), 2) if minutes(mask) > 0 else None

    def rnd(x: float | None, nd: int = 4) -> float | None:
        return None if x is None else round(x, nd)

    ratio = speaking_speed / listening_speed if speaking_speed is not None and listening_speed else None
    return {
        "frames": t,
        "fps": clip.fps,
        "duration_s": round(clip.duration, 3),
        "activity": {
            "self_speaking_frames": int(self_on.sum()),
            "only_partner_frames": int(only_partner.sum()),
            "overlap_frames": int((self_on & other_on).sum()),
            "both_silent_frames": int((~self_on & ~other_on).sum()),
        },
        "lip_sync": {
            "pearson_jaw_vs_self_envelope": rnd(_pearson(jaw, env)),
            "pearson_while_self_speaks": rnd(_pearson(jaw[self_on], env[self_on])),
            "jaw_closed_when_self_silent": rnd(_mean(closed.astype(float), silent)),
            "jaw_closed_when_only_partner_speaks": rnd(_mean(closed.astype(float), only_partner)),
            "jaw_closed_when_both_silent": rnd(_mean(closed.astype(float), silent & ~other_on)),
            "mean_jaw_open_self_speaking": rnd(_mean(jaw, self_on)),
        },
        "head": {
            "mean_angular_speed_self_speaking_deg_s": rnd(speaking_speed, 3),
            "mean_angular_speed_only_partner_deg_s": rnd(listening_speed, 3),
            "speaking_to_listening_ratio": rnd(ratio, 3),
        },
        "blinks_per_minute": {
            "self_speaking": rate(self_on),
            "only_partner": rate(only_partner),
            "both_silent": rate(~self_on & ~other_on),
        },
        "gaze": {
            "mean_eye_angle_self_speaking_deg": rnd(_mean(gaze, self_on), 3),
            "mean_eye_angle_only_partner_deg": rnd(_mean(gaze, only_partner), 3),
        },
        "arms": {
            "mean_speed_self_speaking_deg_s": rnd(_mean(arm_speed, self_on), 3),
            "mean_speed_only_partner_deg_s": rnd(_mean(arm_speed, only_partner), 3),
        },
    }
