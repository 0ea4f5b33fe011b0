"""Beat consistency (BC, ProbTalk): do the motion's beats fall on the audio's onsets?

Audio beats are speech onsets: peaks of the positive spectral flux of a log-mel spectrogram (the
quantity librosa's onset detector picks peaks of). Motion beats are local minima of the arms'
angular speed (ProbTalk: minima of the angular velocity of the arm bones), kept where the arms
moved enough around them to be a gesture stroke, not rest. The score is the mean over audio onsets
of exp(-d^2 / (2 sigma^2)), d the time to the nearest motion beat, sigma = 0.1 s.
"""

from __future__ import annotations

import numpy as np

from convodrive.motion.clip import MotionClip
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX, global_rotation

SIGMA_S = 0.1
ARM_JOINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
_RATE = 16_000
_N_FFT, _HOP, _BANDS = 1024, 256, 40
_MIN_STROKE_DEG_S = 5.0
"""A speed minimum counts as a beat only if the arms reach this speed within 0.3 s around it."""


def _mel_matrix() -> np.ndarray:
    mel = lambda hz: 2595.0 * np.log10(1.0 + hz / 700.0)  # noqa: E731
    edges_hz = 700.0 * (10 ** (np.linspace(mel(60.0), mel(7600.0), _BANDS + 2) / 2595.0) - 1.0)
    bins = np.fft.rfftfreq(_N_FFT, 1.0 / _RATE)
    lower, centre, upper = edges_hz[:-2, None], edges_hz[1:-1, None], edges_hz[2:, None]
    return np.maximum(0.0, np.minimum((bins - lower) / (centre - lower), (upper - bins) / (upper - centre)))


def audio_onsets(samples: np.ndarray) -> np.ndarray:
    """Onset times (s) of 16 kHz audio, from peaks of the log-mel spectral flux."""
    x = np.asarray(samples, np.float64)
    if len(x) < _N_FFT:
        return np.zeros(0)
    frames = np.lib.stride_tricks.sliding_window_view(x, _N_FFT)[::_HOP] * np.hanning(_N_FFT)
    power = np.abs(np.fft.rfft(frames, axis=1)) ** 2
    logmel = 10.0 * np.log10(power @ _mel_matrix().T + 1e-10)
    flux = np.concatenate([[0.0], np.maximum(np.diff(logmel, axis=0), 0.0).mean(axis=1)])
    loud = logmel.max(axis=1) > logmel.max() - 60.0
    if flux.max() <= 0:
        return np.zeros(0)
    flux = flux / flux.max()
    peaks = []
    last = -1e9
    for i in range(1, len(flux) - 1):
        lo, hi = max(0, i - 3), min(len(flux), i + 4)
        local_mean = flux[max(0, i - 10) : i + 11].mean()
        if flux[i] == flux[lo:hi].max() and flux[i] > local_mean + 0.07 and loud[i] and i - last >= 3:
            peaks.append(i)
            last = i
    return (np.array(peaks) * _HOP + _N_FFT / 2) / _RATE


def arm_speed(clip: MotionClip) -> np.ndarray:
    """(T,) mean angular speed (deg/s) of the arms' global orientations (0 for frame 0)."""
    mats = axis_angle_to_matrix(clip.pose)
    speeds = []
    for name in ARM_JOINTS:
        glob = global_rotation(mats, JOINT_INDEX[name])
        rel = np.einsum("tji,tjk->tik", glob[:-1], glob[1:])
        cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        speeds.append(np.degrees(np.arccos(cos)) * clip.fps)
    return np.concatenate([[0.0], np.mean(speeds, axis=0)]) if clip.num_frames > 1 else np.zeros(clip.num_frames)


def motion_beats(clip: MotionClip) -> np.ndarray:
    """Beat times (s): local minima of the smoothed arm speed inside strokes."""
    speed = np.convolve(arm_speed(clip), np.ones(3) / 3.0, mode="same")
    reach = int(round(0.3 * clip.fps))
    beats = []
    for i in range(1, len(speed) - 1):
        if speed[i] < speed[i - 1] and speed[i] <= speed[i + 1]:
            around = speed[max(0, i - reach) : i + reach + 1]
            if around.max() >= _MIN_STROKE_DEG_S and around.max() > 1.5 * speed[i]:
                beats.append(i)
    return np.array(beats, np.float64) / clip.fps


def beat_consistency(onsets: np.ndarray, beats: np.ndarray, sigma: float = SIGMA_S) -> float | None:
    """Mean over audio onsets of exp(-d^2/(2 sigma^2)); None without onsets, 0 without beats."""
    onsets, beats = np.asarray(onsets, np.float64), np.asarray(beats, np.float64)
    if len(onsets) == 0:
        return None
    if len(beats) == 0:
        return 0.0
    d = np.abs(onsets[:, None] - beats[None, :]).min(axis=1)
    return float(np.exp(-(d**2) / (2 * sigma**2)).mean())
