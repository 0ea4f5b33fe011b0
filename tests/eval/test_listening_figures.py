"""The behaviour eval's listening figures on clips made by hand, where the answer is known: nods
and their delay after partner pauses, posture shifts, smiles, blinks, gaze."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.source import DyadicAudio
from convodrive.eval.behaviour import behaviour_figures, head_pitch, nod_frames, posture_shifts
from convodrive.eval.segments import Segments
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX as J

FPS = 30


def nod(pitch_deg: np.ndarray, at: int, depth: float, frames: int = 12) -> None:
    """A down-and-up head nod of ``depth`` degrees peaking at frame ``at``."""
    shape = np.sin(np.linspace(0, np.pi, frames))
    pitch_deg[at - frames // 2 : at - frames // 2 + frames] += depth * shape


def clip_with_head_pitch(pitch_deg: np.ndarray) -> MotionClip:
    clip = MotionClip.neutral(len(pitch_deg))
    clip.pose[:, J["head"], 0] = np.radians(pitch_deg)  # +X rotation tips the face down
    return clip


def test_nods_are_found_and_slow_motion_is_not():
    t = np.arange(20 * FPS) / FPS
    pitch = 3.0 * np.sin(2 * np.pi * 0.1 * t) + 0.6 * np.sin(2 * np.pi * 0.27 * t)  # posture sway, breathing
    for at in (90, 200, 330, 500):
        nod(pitch, at, 4.0)
    nod(pitch, 420, 1.0)  # too small to see
    clip = clip_with_head_pitch(pitch)
    assert np.allclose(head_pitch(clip), pitch, atol=1e-3)
    assert list(nod_frames(clip)) == pytest.approx([90, 200, 330, 500], abs=1)


def test_nod_timing_after_partner_pauses_and_listening_rates():
    """The partner talks from 1 s to 19 s with pauses starting at 5, 10 and 15 s; self is silent.
    Nods 0.3 s after the first two pauses, one 1.5 s after the third, one in mid-speech."""
    n = 20 * FPS
    rng = np.random.default_rng(0)
    partner = np.zeros(n * 16000 // FPS, np.float32)
    for start, end in ((1.0, 5.0), (5.5, 10.0), (10.5, 15.0), (15.5, 19.0)):
        partner[int(start * 16000) : int(end * 16000)] = 0.2 * rng.standard_normal(int((end - start) * 16000))
    audio = DyadicAudio(np.full_like(partner, 1e-4), partner)
    pitch = np.zeros(n)
    for at_s in (5.3, 10.3, 16.5, 3.0):
        nod(pitch, int(at_s * FPS), 5.0)
    clip = clip_with_head_pitch(pitch)
    blink_at = np.arange(60, n, 120)  # every 4 s: 15 a minute
    for k in blink_at:
        clip.face[k : k + 4, B["eyeBlinkLeft"]] = 1.0
    clip.face[300:390, [B["mouthSmileLeft"], B["mouthSmileRight"]]] = 0.5  # 3 s of smiling
    reference = Segments((), ((1.0, 19.0),))
    f = behaviour_figures(clip, audio, reference)
    nods = f["nods"]
    assert nods["listening_nods"] == 4
    assert nods["listening_share_within_600ms_after_partner_pause"] == 0.5
    assert nods["median_delay_after_partner_pause_s"] == pytest.approx(0.3, abs=0.05)  # 0.3, 0.3, 1.5 (3 s: none)
    assert nods["partner_pauses_while_listening"] == 4  # the last one is the turn's end
    assert nods["partner_pauses_answered_by_nod"] == 0.5
    listening_minutes = f["activity"]["listening_frames"] / FPS / 60
    assert nods["per_minute_listening"] == pytest.approx(4 / listening_minutes, rel=0.01)
    assert f["blinks_per_minute"]["listening"] == pytest.approx(15, abs=1.5)
    assert f["smiles"]["share_listening"] == pytest.approx(90 / f["activity"]["listening_frames"], abs=0.01)
    assert f["gaze"]["at_partner_share_listening"] == 1.0


def test_posture_shifts_are_counted_once_each():
    n = 60 * FPS
    lean = np.zeros(n)
    for at_s, to_deg in ((10, 3.0), (25, -1.0), (45, 2.0)):
        k = at_s * FPS
        ramp = np.clip((np.arange(n) - k) / 45.0, 0, 1)  # a 1.5 s shift
        lean = lean + (to_deg - (lean[k] if k < n else 0)) * ramp
    clip = MotionClip.neutral(n)
    t = np.arange(n) / FPS
    clip.pose[:, J["spine1"], 0] = np.radians(lean)
    clip.pose[:, J["spine3"], 0] = np.radians(1.2 * np.sin(2 * np.pi * 0.25 * t))  # breathing moves the chest
    shifts = posture_shifts(clip) / FPS
    assert len(shifts) == 3 and np.allclose(shifts, [10.5, 25.5, 45.5], atol=1.01)


def test_a_soft_voice_activity_counts_as_speaking_only_above_one_half():
    """A learned model's voice activity is a regressed value in [0, 1]: 0.1 while the partner talks
    is silence, not a self that talks over its partner."""
    n = 6 * FPS
    partner = np.zeros(n * 16000 // FPS, np.float32)
    partner[16000 : 5 * 16000] = 0.2 * np.random.default_rng(0).standard_normal(4 * 16000)
    audio = DyadicAudio(np.full_like(partner, 1e-4), partner)
    clip = MotionClip.neutral(n)
    clip.vad[:, 0] = 0.1
    clip.vad[: FPS // 2, 0] = 0.9  # half a second of talking before the partner starts
    f = behaviour_figures(clip, audio, Segments((), ((1.0, 5.0),)))
    assert f["voice_activity"]["self_on_when_only_partner_speaks"] == 0.0
