"""The slow layer of the body: posture shifts, how the arms rest, breathing, and the in-breath.

People do not hold one pose through a conversation: every 10 to 30 s they shift their weight,
lean in or back, turn a little, rest their hands differently; more readily when a turn changes.
In between, a hand settles somewhere slightly different now and then. Each change draws a new
target and the body moves there along a minimum-jerk path (the smooth bell-shaped speed of human
reaching) in 1.5 s, computed in closed form from the change's start, which costs nothing while
the posture holds. Breathing runs all the time at the take's own rate; before self
speaks (the ``breath`` cue, which the look-ahead makes possible) the chest fills, the shoulders
rise a little and the body leans in.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.poses import LIBRARY, mirror, rest_variant
from convodrive.generators.procedural.signals import smoother

SHIFT_MIN_S, SHIFT_MAX_S = 10.0, 30.0
"""Time between posture shifts."""
HAND_MIN_S, HAND_MAX_S = 5.0, 15.0
"""Time between the small adjustments of one hand's rest."""
TURN_SHIFT_SHARE = 0.6
"""A turn change this far into the interval to the next shift brings the shift forward to it."""
POSTURE_FIELDS = ("lean", "side", "twist", "weight", "head_yaw", "head_pitch", "head_roll")
"""Degrees: lean forward (+) at the lower back, bend to the side, turn, pelvis roll (weight on one
hip), and where the head rests (yaw, pitch down, roll)."""
_RANGES = np.array([(-1.0, 3.5), (-2.5, 2.5), (-3.0, 3.0), (-1.8, 1.8), (-4.0, 4.0), (-1.5, 2.5), (-4.0, 4.0)])
_ARM_DIMS = 2 * 18 * 3
SHIFT_FRAMES = 45
"""How long a posture shift or a hand's adjustment takes (1.5 s)."""


class _Transitions:
    """Values that move from where they are to new targets along minimum-jerk paths, each
    dimension from the frame its latest change began: a pure function of the change events."""

    def __init__(self, start: np.ndarray, target: np.ndarray, frames: int) -> None:
        self.frames = frames
        self.source, self.target = start.astype(float), target.astype(float)
        self.began = np.zeros(len(start), int)

    def at(self, k: np.ndarray) -> np.ndarray:
        """(len(k), dims) values at frames ``k``."""
        u = np.clip((k[:, None] - self.began[None, :]) / self.frames, 0.0, 1.0)
        shape = u * u * u * (10.0 + u * (-15.0 + 6.0 * u))
        return self.source + (self.target - self.source) * shape

    def move(self, k: int, dims: slice, target: np.ndarray) -> None:
        """From frame ``k`` on, head for ``target`` in ``dims`` from wherever they are then."""
        now = self.at(np.array([k]))[0]
        self.source[dims], self.target[dims], self.began[dims] = now[dims], target, k


class PostureSynth:
    """Posture, arm rest and breathing of one take. ``step`` returns per-frame arrays:
    ``posture`` (n, 7) degrees in ``POSTURE_FIELDS`` order, ``arms`` (n, 2, 18, 3) axis-angle
    offsets of each arm's rest pose from the library's, ``breath`` (n,) the breathing cycle
    (-1..1, +1 full), ``inhale`` (n,) the in-breath before a turn (0..1)."""

    def __init__(self, options: ProceduralOptions, seed: int) -> None:
        self.o = options
        self._rng_seed = int(seed) & 0xFFFFFFFF
        rng = np.random.default_rng([self._rng_seed, 42])
        v = options.variability
        self.breath_hz = 0.26 * (1.0 + 0.15 * v * rng.uniform(-1, 1))
        self.breath_phase = rng.uniform(0, 2 * math.pi)
        self._shifts = 0
        self._hand_moves = [0, 0]
        # Every take starts upright with the library's rest (a robot's neutral pose) and settles
        # into its own first posture over the first second or two.
        first = np.concatenate([self._draw_body(0), self._draw_arm(0, 0), self._draw_arm(1, 0)])
        self.moves = _Transitions(np.zeros_like(first), first, SHIFT_FRAMES)
        self._last_shift = 0
        self._next_shift = self._interval(43, 0, SHIFT_MIN_S, SHIFT_MAX_S)
        self._next_hand = [self._interval(46, side, HAND_MIN_S, HAND_MAX_S) for side in (0, 1)]
        self._self_quiet = 99
        self._prev_self = False
        self._prev_other = False
        self.inhale = smoother(0.09)

    def step(self, first: int, vad_self: np.ndarray, vad_other: np.ndarray, breath_cue: np.ndarray) -> dict:
        n = len(vad_self)
        vs, vo = vad_self.tolist(), vad_other.tolist()
        body = slice(0, len(POSTURE_FIELDS))
        frames = first + np.arange(n)
        parts, done = [], 0  # the frames before a change follow the paths as they were
        for j in range(n):
            k = first + j
            sp, ls = vs[j] > 0, vo[j] > 0
            turn = (sp and not self._prev_self and self._self_quiet > 15) or (self._prev_other and not ls and not sp)
            self._self_quiet = 0 if sp else self._self_quiet + 1
            self._prev_self, self._prev_other = sp, ls
            due = k >= self._next_shift
            ready = k - self._last_shift >= TURN_SHIFT_SHARE * (self._next_shift - self._last_shift)
            if (due or (turn and ready) or k >= min(self._next_hand)) and j > done:
                parts.append(self.moves.at(frames[done:j]))
                done = j
            if due or (turn and ready):
                self._shifts += 1
                self.moves.move(k, body, self._draw_body(self._shifts))
                self._last_shift = k
                self._next_shift = k + self._interval(43, self._shifts, SHIFT_MIN_S, SHIFT_MAX_S)
                self._next_hand = [k, k]  # a new posture rests both hands anew
            for side in (0, 1):
                if k >= self._next_hand[side]:
                    self._hand_moves[side] += 1
                    count = self._hand_moves[side]
                    at = len(POSTURE_FIELDS) + side * _ARM_DIMS // 2
                    self.moves.move(k, slice(at, at + _ARM_DIMS // 2), self._draw_arm(side, count))
                    self._next_hand[side] = k + self._interval(46 + side, count, HAND_MIN_S, HAND_MAX_S)
        parts.append(self.moves.at(frames[done:]))
        smooth = np.concatenate(parts)
        t = frames / 30.0
        return {
            "posture": smooth[:, : len(POSTURE_FIELDS)],
            "arms": smooth[:, len(POSTURE_FIELDS) :].reshape(n, 2, 18, 3),
            "breath": np.sin(2 * math.pi * self.breath_hz * t + self.breath_phase),
            "inhale": np.clip(self.inhale(breath_cue), 0.0, 1.0),
        }

    def _interval(self, stream: int, index: int, low_s: float, high_s: float) -> int:
        rng = np.random.default_rng([self._rng_seed, stream, index])
        return int(30 * rng.uniform(low_s, high_s))

    @property
    def _amount(self) -> float:
        return min(1.0, 0.4 + 0.6 * self.o.variability)

    def _draw_body(self, index: int) -> np.ndarray:
        """Posture number ``index`` of this take: the body's angles in ``POSTURE_FIELDS`` order."""
        rng = np.random.default_rng([self._rng_seed, 44, index])
        lo, hi = _RANGES[:, 0], _RANGES[:, 1]
        mid = 0.5 * (lo + hi)
        return mid + self._amount * (rng.uniform(lo, hi) - mid)

    def _draw_arm(self, side: int, index: int) -> np.ndarray:
        """Rest number ``index`` of one arm (0 left, 1 right): offsets from the library's rest."""
        u = np.random.default_rng([self._rng_seed, 45, side, index]).uniform(-1, 1, 6) * self._amount
        left = rest_variant((7 * u[0], 5 * u[1], 6 * u[2]), 14 * u[3], 10 * u[4], 1.0 + 0.3 * u[5])
        arm = left - LIBRARY[0] if side == 0 else mirror(left) - mirror(LIBRARY[0])
        return arm.ravel()
