"""How self responds while the partner talks: backchannel nods, smiles, blinks and glances.

Listeners nod mostly when the speaker pauses, more surely after a falling (statement-final) pitch
and the longer they have not nodded, and now and then on a stressed syllable; they smile when the
speaker laughs or sounds animated; they blink at the speaker's pauses; they look at the speaker
most of the time and glance away now and then, less often than speakers do. Each take draws its
own listener: how often it nods, how it nods (single, double, slow), when it glances away. The
face and body render these events (``face``, ``body``); the decisions live here.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from convodrive.generators.procedural.cues import CueBatch
from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.signals import FrameNoise

LISTEN_AFTER_FRAMES = 30
"""Self still counts as listening this long (1 s) after the partner's voice, if self is silent."""
NOD_GAP_FRAMES = 36
"""At least 1.2 s between the starts of two backchannel nods."""
STRESS_NOD_GAP_FRAMES = 180
"""A nod on a stressed syllable only after 6 s without one..."""
STRESS_NOD_TURN_FRAMES = 60
"""... and 2 s into the partner's turn."""
DOUBLE_NOD_FRAMES = 9
"""The second nod of a double nod follows the first by 300 ms."""
ATTITUDE_MIN_FRAMES, ATTITUDE_MAX_FRAMES = 90, 240
"""The head settles a new way at a partner's pause at least 3 s after the last time, at the
latest after 8 s of listening."""


class ListenerSynth:
    """Listening events of one take, frame by frame. ``step`` returns per-frame arrays:

    - ``nod`` and ``nod_slow``: impulses (their size) that start a quick or a slow nod;
    - ``smile``: the smile level the face should hold (0..1);
    - ``blink``: 1 where the listener blinks at the partner's pause;
    - ``glance_yaw``, ``glance_pitch`` (radians) and ``glance_frames``: a look away starting there;
    - ``attitude`` (n, 3): how the listener holds the head (yaw, pitch down, roll; degrees), a
      new way every few seconds, often as the partner pauses.
    """

    def __init__(self, options: ProceduralOptions, seed: int) -> None:
        self.o = options
        self.noise = FrameNoise(seed, 31, dims=12)
        self._seed = int(seed) & 0xFFFFFFFF
        rng = np.random.default_rng([self._seed, 32])
        v = options.variability
        # This take's listener: how readily it nods and how it glances away.
        self.nod_readiness = float(np.clip(1.0 + 0.25 * v * rng.uniform(-1, 1), 0.5, 1.5))
        self.double_share = float(np.clip(0.2 + 0.15 * v * rng.uniform(-1, 1), 0.0, 0.6))
        self.slow_share = float(np.clip(0.15 + 0.1 * v * rng.uniform(-1, 1), 0.0, 0.5))
        self.glance_down_share = float(np.clip(0.6 + 0.2 * v * rng.uniform(-1, 1), 0.2, 0.9))
        self._since_partner = 999
        self._turn_run = 0  # frames since the partner's turn began
        self._since_nod = 999
        self._since_glance = 0
        self._glance_due = self._glance_interval(150 + int(rng.integers(0, 200)))
        self._pending: list[tuple[int, str, float]] = []  # (frame, kind, size)
        self._smile_until = -1
        self._smile_level = 0.0
        self._prev_laugh = 0.0
        self._pitches: deque[float] = deque(maxlen=30)  # the partner's recent voiced pitch, semitones
        self._attitude = np.zeros(3)
        self._attitudes = 0
        self._since_attitude = 0

    def step(self, batch: CueBatch, s: dict[str, np.ndarray], o: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        n, first = len(batch), batch.first
        out = {k: np.zeros(n) for k in ("nod", "nod_slow", "smile", "blink", "glance_yaw", "glance_pitch")}
        out["glance_frames"] = np.zeros(n)
        out["attitude"] = np.zeros((n, 3))
        u = self.noise.take(first, n).tolist()
        v = self.o.variability
        pause, fall = batch.cues["pause"].tolist(), batch.cues["fall"].tolist()
        vs, vo, sounding = s["vad"].tolist(), o["vad"].tolist(), o["sounding"].tolist()
        stress, laugh = o["stress"].tolist(), o["laugh"].tolist()
        pitch, voiced = o["pitch_st"].tolist(), o["voiced"].tolist()
        for j in range(n):
            k = first + j
            r = u[j]
            self._since_partner = 0 if vo[j] > 0 else self._since_partner + 1
            self._turn_run = self._turn_run + 1 if self._since_partner <= LISTEN_AFTER_FRAMES else 0
            self._since_nod += 1
            self._since_glance += 1
            if voiced[j] > 0:
                self._pitches.append(pitch[j])
            listening = vs[j] <= 0 and self._since_partner <= LISTEN_AFTER_FRAMES
            self._since_attitude += 1
            if listening and (self._since_attitude > ATTITUDE_MAX_FRAMES or (pause[j] > 0 and r[4] > 0.5)):
                if self._since_attitude > ATTITUDE_MIN_FRAMES:
                    self._new_attitude()
            if listening and pause[j] > 0:
                self._on_pause(k, r, fall[j], v)
            elif (
                listening
                and stress[j] > 0.5
                and sounding[j] > 0
                and self._since_nod > STRESS_NOD_GAP_FRAMES
                and self._turn_run > STRESS_NOD_TURN_FRAMES
            ):
                if r[0] < 0.08 * self.nod_readiness:
                    self._pending.append((k + 1, "nod", 0.45 + 0.2 * r[1]))
                    self._since_nod = 0
            # Laughter invites a smile, held a second or three.
            if laugh[j] > 0.5 >= self._prev_laugh and r[8] < 0.85:
                self._smile(k, 0.5 + 0.3 * r[9], 45 + int(45 * r[10]))
            self._prev_laugh = laugh[j]
            if listening and self._since_glance >= self._glance_due:
                self._glance(out, j, r, v)
            elif not listening:
                self._since_glance = min(self._since_glance, self._glance_due // 2)
            self._emit(out, j, k)
            out["smile"][j] = self._smile_level if k < self._smile_until else 0.0
            out["attitude"][j] = self._attitude
        return out

    def _new_attitude(self) -> None:
        """Settle the head a new way: turned, tipped and tilted a few degrees."""
        self._attitudes += 1
        rng = np.random.default_rng([self._seed, 33, self._attitudes])
        amount = min(1.0, 0.4 + 0.6 * self.o.variability)
        self._attitude = amount * rng.uniform([-4.0, -1.5, -4.5], [4.0, 3.0, 4.5])
        self._since_attitude = 0

    def _on_pause(self, k: int, r: list[float], fall: float, v: float) -> None:
        """The partner paused after a phrase: perhaps a nod, a blink, a smile."""
        if self._since_nod >= NOD_GAP_FRAMES:
            waited = min(1.0, self._since_nod / 240.0)  # after 8 s without a nod, nod at the next pause
            chance = min(0.95, (0.2 + 0.25 * fall + 0.45 * waited) * self.nod_readiness)
            if r[0] < chance:
                start = k + 2 + int(5 * r[1] * (0.5 + 0.5 * v))  # 70 to 230 ms after the pause begins
                size = 0.7 + 0.3 * r[2]
                kind = r[3]
                if kind < self.slow_share:
                    self._pending.append((start, "nod_slow", size))
                elif kind < self.slow_share + self.double_share:
                    self._pending += [(start, "nod", 0.65 * size), (start + DOUBLE_NOD_FRAMES, "nod", 0.55 * size)]
                else:
                    self._pending.append((start, "nod", size))
                self._since_nod = 0
        if r[4] < 0.4:
            self._pending.append((k + 2 + int(4 * r[5]), "blink", 1.0))
        # An animated phrase (a wide pitch range) or, rarely, any phrase earns a small smile.
        lively = len(self._pitches) >= 10 and max(self._pitches) - min(self._pitches) > 5.0
        if r[6] < (0.35 if lively else 0.1):
            self._smile(k, 0.35 + 0.2 * r[7], 30 + int(45 * r[11]))

    def _smile(self, k: int, level: float, frames: int) -> None:
        if k >= self._smile_until or level > self._smile_level:
            self._smile_level = level
        self._smile_until = max(self._smile_until, k + frames)

    def _glance(self, out: dict[str, np.ndarray], j: int, r: list[float], v: float) -> None:
        """A listener's look away: short, mostly down, sometimes to a side."""
        side = 1.0 if r[1] < 0.5 else -1.0
        if r[2] < self.glance_down_share:
            yaw, pitch = side * math.radians(2.0 + 3.0 * r[3]), math.radians(5.0 + 4.0 * r[4])
        else:
            yaw, pitch = side * math.radians(6.0 + 5.0 * r[3]), math.radians(1.0 * (r[4] - 0.3))
        out["glance_yaw"][j], out["glance_pitch"][j] = yaw, pitch
        out["glance_frames"][j] = 12 + int(18 * r[5])
        self._since_glance = 0
        self._glance_due = self._glance_interval(150 + 240 * r[6] * (0.5 + 0.5 * v))  # every 5 to 13 s

    def _glance_interval(self, frames: float) -> int:
        """Frames to the next glance: the default interval, shortened as ``gaze_aversion`` grows."""
        aversion = self.o.gaze_aversion
        return int(frames / aversion) if aversion > 0 else 1 << 62  # 0: never

    def _emit(self, out: dict[str, np.ndarray], j: int, k: int) -> None:
        keep = []
        for frame, kind, size in self._pending:
            if frame == k:
                out[kind][j] = max(out[kind][j], size)
            elif frame > k:
                keep.append((frame, kind, size))
        self._pending = keep
