"""Behaviour figures of a motion clip against its conversation audio (``convodrive eval behaviour``).

Who is talking comes from reference speech segments when the user has them (``segments``), and
otherwise from the audio itself, independently of the generator: a voice is active where its
frame RMS is within 30 dB of its loud speech (95th percentile) and 10 dB above its noise floor
(5th percentile), with gaps under 150 ms bridged, so the stop closures inside words do not count
as silence but pauses do. That detector hears a partner who leaks into self's microphone as self,
so recordings with bleed need reference segments for honest figures.

*Listening* frames are those where self is silent during the partner's turn: the partner speaks,
or paused less than a second ago. A *partner pause* starts where the partner's voice stops for at
least 150 ms (by the audio-level detector, within the reference segments when there are any).

Figures: lip sync (Pearson r of ``jawOpen`` with self's amplitude envelope), how often the mouth is
closed (``jawOpen`` < 0.05) while self is silent, split by whether the partner talks; the clip's
own voice activity against the reference; mean head angular speed while self speaks and while
listening, and their ratio; blink rates; nods (head pitch dips of at least 2 degrees that come back
within a second) per minute and their delay after partner pauses; smile share; posture shifts;
gaze toward the partner; arm motion.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy.signal import find_peaks

from convodrive.audio.source import DyadicAudio
from convodrive.eval.segments import Segments
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.channels import VAD_ON
from convodrive.motion.clip import MotionClip
from convodrive.motion.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.skeleton import global_rotation
from convodrive.plumbing.errors import UserError

JAW_CLOSED = 0.05
_BRIDGE_FRAMES = 4
NOD_MIN_DEG = 2.0
"""A nod: the head pitches down at least this far and back within about a second."""
NOD_WINDOW_S = 1.0
PAUSE_NOD_S = 0.6
"""A listening nod this soon after the start of a partner pause counts as timed to it."""
TURN_BRIDGE_S = 1.0
"""Partner pauses shorter than this stay inside the turn: self is still listening."""
SMILE = 0.2
"""Mean ``mouthSmile`` from which a frame counts as smiling."""
GAZE_AT_PARTNER_DEG = 5.0
POSTURE_WINDOW_S = 1.0
POSTURE_SHIFT_DEG = 1.0
"""A posture shift: the lower back's mean orientation moves this far from one second to the next."""


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
    return bridge(db > threshold, _BRIDGE_FRAMES)


def bridge(active: np.ndarray, gap: int) -> np.ndarray:
    """``active`` with inactive runs of at most ``gap`` frames between active frames filled."""
    out = active.copy()
    idx = np.flatnonzero(active)
    for a, b in zip(idx[:-1], idx[1:]):
        if 1 < b - a <= gap + 1:
            out[a:b] = True
    return out


def envelope(rms: np.ndarray) -> np.ndarray:
    """Amplitude envelope: frame RMS smoothed over 100 ms."""
    return np.convolve(rms, np.array([0.25, 0.5, 0.25]), mode="same")


def head_angular_speed(clip: MotionClip) -> np.ndarray:
    """(T,) angular speed of the head's global orientation, degrees per second (0 for frame 0)."""
    glob = global_rotation(axis_angle_to_matrix(clip.pose), J["head"])
    rel = np.einsum("tji,tjk->tik", glob[:-1], glob[1:])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.concatenate([[0.0], np.arccos(cos)])) * clip.fps


def head_pitch(clip: MotionClip) -> np.ndarray:
    """(T,) how far the head looks down, degrees (its forward axis below the horizontal)."""
    glob = global_rotation(axis_angle_to_matrix(clip.pose), J["head"])
    forward = glob[:, :, 2]  # the canonical body faces +Z
    return np.degrees(np.arcsin(np.clip(-forward[:, 1], -1.0, 1.0)))


def nod_frames(clip: MotionClip) -> np.ndarray:
    """Frames where a nod is deepest: head pitch peaks that stand ``NOD_MIN_DEG`` out of the
    surrounding second, so slow posture changes and breathing do not count."""
    window = int(round(NOD_WINDOW_S * clip.fps)) | 1
    peaks, _ = find_peaks(head_pitch(clip), prominence=NOD_MIN_DEG, wlen=window)
    return peaks


def pause_starts(partner_on: np.ndarray) -> np.ndarray:
    """First frames of the partner's silences (after bridging, each lasts at least 150 ms)."""
    return np.flatnonzero(~partner_on[1:] & partner_on[:-1]) + 1


def posture_shifts(clip: MotionClip) -> np.ndarray:
    """Frames where the lower back's orientation, averaged over one-second windows, moves at least
    ``POSTURE_SHIFT_DEG`` from one window to the next (one event per move, at its largest step).
    The lower back (``spine1``) shifts with the posture but hardly breathes, unlike the chest."""
    glob = global_rotation(axis_angle_to_matrix(clip.pose), J["spine1"])
    rotvec = np.degrees(matrix_to_axis_angle(glob))
    n = int(round(POSTURE_WINDOW_S * clip.fps))
    count = len(rotvec) // n
    if count < 2:
        return np.zeros(0, int)
    means = rotvec[: count * n].reshape(count, n, 3).mean(axis=1)
    steps = np.concatenate([[0.0], np.linalg.norm(np.diff(means, axis=0), axis=1), [0.0]])
    peaks, _ = find_peaks(steps, height=POSTURE_SHIFT_DEG, distance=2)
    return (peaks * n).astype(int)


def _mean(x: np.ndarray, mask: np.ndarray) -> float | None:
    return float(x[mask].mean()) if mask.any() else None


def _pearson(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) < 3 or a.std() < 1e-9 or b.std() < 1e-9:
        return None
    return float(np.corrcoef(a, b)[0, 1])


@dataclasses.dataclass(frozen=True)
class _Turns:
    """Who is talking, per frame, and the clip's rate: the masks every figure is taken over."""

    fps: float
    self_on: np.ndarray
    other_on: np.ndarray
    partner_sounding: np.ndarray
    """The partner's voice heard in the audio (within the reference segments when there are any)."""
    only_partner: np.ndarray
    listening: np.ndarray

    def per_minute(self, events: np.ndarray, mask: np.ndarray) -> float | None:
        minutes = mask.sum() / self.fps / 60.0
        return round(float(events[mask].sum() / minutes), 2) if minutes > 0 else None


def _rnd(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(x, nd)


def _share(flags: np.ndarray, mask: np.ndarray) -> float | None:
    return _rnd(_mean(flags.astype(float), mask))


def behaviour_figures(clip: MotionClip, audio: DyadicAudio, reference: Segments | None = None) -> dict[str, Any]:
    """The figures as a JSON-ready dict. ``reference``: who really spoke when, if known.
    Raises UserError if clip and audio lengths disagree."""
    expected = int(round(audio.duration * clip.fps))
    if abs(expected - clip.num_frames) > 1:
        raise UserError(
            f"motion has {clip.num_frames} frames ({clip.duration:.2f} s) but the audio lasts {audio.duration:.2f} s "
            f"({expected} frames at {clip.fps:g} fps); they must belong together"
        )
    t = clip.num_frames
    rms_self = frame_rms(audio.self_voice, t, clip.fps)
    turns = _turns(clip, rms_self, frame_rms(audio.other_voice, t, clip.fps), reference)
    self_on, other_on, only_partner = turns.self_on, turns.other_on, turns.only_partner
    vad_self, vad_other = clip.vad[:, 0] > VAD_ON, clip.vad[:, 1] > VAD_ON
    return {
        "frames": t,
        "fps": clip.fps,
        "duration_s": round(clip.duration, 3),
        "activity": {
            "source": f"reference segments {reference.source}" if reference is not None else "audio levels",
            "self_speaking_frames": int(self_on.sum()),
            "only_partner_frames": int(only_partner.sum()),
            "listening_frames": int(turns.listening.sum()),
            "overlap_frames": int((self_on & other_on).sum()),
            "both_silent_frames": int((~self_on & ~other_on).sum()),
        },
        "voice_activity": {
            "self_on_when_only_partner_speaks": _share(vad_self, only_partner),
            "self_on_when_self_speaks": _share(vad_self, self_on),
            "partner_on_when_only_self_speaks": _share(vad_other, self_on & ~other_on),
        },
        "lip_sync": _lip_sync(clip, envelope(rms_self), turns),
        "head": _head(clip, turns),
        "blinks_per_minute": _blinks(clip, turns),
        "nods": _nods(clip, turns),
        "smiles": _smiles(clip, turns),
        "posture": _posture(clip, turns),
        "gaze": _gaze(clip, turns),
        "arms": _arms(clip, turns),
    }


def _turns(clip: MotionClip, rms_self: np.ndarray, rms_other: np.ndarray, reference: Segments | None) -> _Turns:
    heard_self, heard_other = voice_activity(rms_self), voice_activity(rms_other)
    if reference is not None:
        self_on, other_on = reference.masks(clip.num_frames, clip.fps)
        partner_sounding = other_on & heard_other
    else:
        self_on, other_on = heard_self, heard_other
        partner_sounding = heard_other
    listening = _partner_turn(other_on, clip.fps) & ~self_on
    return _Turns(clip.fps, self_on, other_on, partner_sounding, other_on & ~self_on, listening)


def _lip_sync(clip: MotionClip, env: np.ndarray, turns: _Turns) -> dict[str, Any]:
    jaw = clip.face[:, B["jawOpen"]].astype(np.float64)
    self_on = turns.self_on
    silent = ~self_on
    closed = jaw < JAW_CLOSED
    return {
        "pearson_jaw_vs_self_envelope": _rnd(_pearson(jaw, env)),
        "pearson_while_self_speaks": _rnd(_pearson(jaw[self_on], env[self_on])),
        "jaw_closed_when_self_silent": _rnd(_mean(closed.astype(float), silent)),
        "jaw_closed_when_only_partner_speaks": _rnd(_mean(closed.astype(float), turns.only_partner)),
        "jaw_closed_when_both_silent": _rnd(_mean(closed.astype(float), silent & ~turns.other_on)),
        "mean_jaw_open_self_speaking": _rnd(_mean(jaw, self_on)),
    }


def _head(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    speed = head_angular_speed(clip)
    speaking_speed = _mean(speed, turns.self_on)
    listening_speed = _mean(speed, turns.listening)
    ratio = speaking_speed / listening_speed if speaking_speed is not None and listening_speed else None
    return {
        "mean_angular_speed_self_speaking_deg_s": _rnd(speaking_speed, 3),
        "mean_angular_speed_listening_deg_s": _rnd(listening_speed, 3),
        "mean_angular_speed_only_partner_deg_s": _rnd(_mean(speed, turns.only_partner), 3),
        "speaking_to_listening_ratio": _rnd(ratio, 3),
    }


def _blinks(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    blink = clip.face[:, B["eyeBlinkLeft"]]
    onsets = np.concatenate([[False], (blink[1:] >= 0.5) & (blink[:-1] < 0.5)])
    return {
        "self_speaking": turns.per_minute(onsets, turns.self_on),
        "listening": turns.per_minute(onsets, turns.listening),
        "only_partner": turns.per_minute(onsets, turns.only_partner),
        "both_silent": turns.per_minute(onsets, ~turns.self_on & ~turns.other_on),
    }


def _nods(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    fps, listening = turns.fps, turns.listening
    nods = np.zeros(clip.num_frames, bool)
    nods[nod_frames(clip)] = True
    pauses = pause_starts(turns.partner_sounding)
    listening_pauses = pauses[listening[pauses]]
    listening_nods = np.flatnonzero(nods & listening)
    delays = [_delay_after(k, pauses) for k in listening_nods]
    known = [d / fps for d in delays if d is not None]
    timed = [d for d in known if d <= PAUSE_NOD_S]
    answered = [
        p for p in listening_pauses if np.any((listening_nods >= p) & (listening_nods <= p + PAUSE_NOD_S * fps))
    ]
    return {
        "per_minute_self_speaking": turns.per_minute(nods, turns.self_on),
        "per_minute_listening": turns.per_minute(nods, listening),
        "listening_nods": len(listening_nods),
        "listening_share_within_600ms_after_partner_pause": _rnd(len(timed) / len(delays)) if delays else None,
        "median_delay_after_partner_pause_s": _rnd(float(np.median(known)), 3) if known else None,
        "partner_pauses_while_listening": len(listening_pauses),
        "partner_pauses_answered_by_nod": _rnd(len(answered) / len(listening_pauses))
        if len(listening_pauses)
        else None,
    }


def _smiles(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    smiling = clip.face[:, [B["mouthSmileLeft"], B["mouthSmileRight"]]].mean(axis=1) >= SMILE
    return {"share_self_speaking": _share(smiling, turns.self_on), "share_listening": _share(smiling, turns.listening)}


def _posture(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    shifts = np.zeros(clip.num_frames, bool)
    shifts[posture_shifts(clip)] = True
    return {
        "shifts_per_minute": turns.per_minute(shifts, np.ones(clip.num_frames, bool)),
        "shifts_per_minute_listening": turns.per_minute(shifts, turns.listening),
    }


def _gaze(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    gaze = np.degrees(np.linalg.norm(clip.pose[:, J["left_eye_smplhf"]], axis=1))
    return {
        "mean_eye_angle_self_speaking_deg": _rnd(_mean(gaze, turns.self_on), 3),
        "mean_eye_angle_listening_deg": _rnd(_mean(gaze, turns.listening), 3),
        "mean_eye_angle_only_partner_deg": _rnd(_mean(gaze, turns.only_partner), 3),
        "at_partner_share_self_speaking": _share(gaze < GAZE_AT_PARTNER_DEG, turns.self_on),
        "at_partner_share_listening": _share(gaze < GAZE_AT_PARTNER_DEG, turns.listening),
    }


def _arms(clip: MotionClip, turns: _Turns) -> dict[str, Any]:
    joints = [
        J[n] for n in ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
    ]
    speed = np.concatenate(
        [[0.0], np.degrees(np.linalg.norm(np.diff(clip.pose[:, joints], axis=0), axis=2).mean(axis=1)) * turns.fps]
    )
    return {
        "mean_speed_self_speaking_deg_s": _rnd(_mean(speed, turns.self_on), 3),
        "mean_speed_listening_deg_s": _rnd(_mean(speed, turns.listening), 3),
        "mean_speed_only_partner_deg_s": _rnd(_mean(speed, turns.only_partner), 3),
    }


def _partner_turn(other_on: np.ndarray, fps: float) -> np.ndarray:
    """The partner's turn: the frames at most ``TURN_BRIDGE_S`` after the partner's voice, so its
    short pauses stay inside, and so does the second after it ends (where a listener's response
    to the end of the turn falls)."""
    span = int(round(TURN_BRIDGE_S * fps)) + 1
    return np.convolve(other_on.astype(float), np.ones(span), mode="full")[: len(other_on)] > 0.5


def _delay_after(frame: int, pauses: np.ndarray) -> int | None:
    """Frames from the latest partner pause start at or before ``frame`` (None if there is none)."""
    before = pauses[pauses <= frame]
    return int(frame - before[-1]) if len(before) else None
