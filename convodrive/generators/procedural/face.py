"""The face: visemes to ARKit mouth channels and jaw, blinks, gaze and saccades, brows, smiles.

The mouth is driven by self's loudness (how far it opens) and the viseme (which shape): neighbouring
visemes blend through a critically damped filter (coarticulation, easing in and out), and both
fall to zero with self's voice, so the mouth is closed and relaxed whenever self is silent, also
while the partner talks; only the in-breath before a turn parts the lips a little. While
listening, the listener's events (``listener``) add smiles, blinks at the partner's pauses and
glances away. Eye rotations and ``eyeLook*`` channels come from one gaze angle pair, and the jaw
joint from ``jawOpen``, so the skeleton and the blendshapes always agree.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive.audio.visemes import NUM_VISEMES, VISEME_INDEX
from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.signals import AttackRelease, Filter, FrameNoise, bump, one_pole, smoother
from convodrive.motion.channels import BLENDSHAPE_INDEX as B
from convodrive.motion.channels import EYE_LOOK_PITCH_RAD as EYE_PITCH_MAX
from convodrive.motion.channels import EYE_LOOK_YAW_RAD as EYE_YAW_MAX
from convodrive.motion.channels import JAW_OPEN_RAD as JAW_MAX_RAD
from convodrive.motion.channels import NUM_BLENDSHAPES

# Viseme -> (jaw factor, {ARKit channel: weight}); L/R pairs are written once without the side.
_VISEME_SHAPES: dict[str, tuple[float, dict[str, float]]] = {
    "sil": (0.3, {}),
    "PP": (0.1, {"mouthClose": 0.6, "mouthPress": 0.4}),
    "FF": (0.25, {"mouthRollLower": 0.5, "mouthUpperUp": 0.3}),
    "TH": (0.35, {"tongueOut": 0.3, "mouthStretch": 0.1}),
    "DD": (0.45, {"mouthStretch": 0.15}),
    "kk": (0.5, {"mouthStretch": 0.1}),
    "CH": (0.35, {"mouthFunnel": 0.5, "mouthPucker": 0.2}),
    "SS": (0.2, {"mouthStretch": 0.35, "mouthSmile": 0.15}),
    "nn": (0.35, {"mouthStretch": 0.1}),
    "RR": (0.35, {"mouthPucker": 0.4, "mouthFunnel": 0.3}),
    "aa": (1.0, {"mouthLowerDown": 0.3}),
    "E": (0.65, {"mouthStretch": 0.35, "mouthSmile": 0.15, "mouthUpperUp": 0.2}),
    "ih": (0.45, {"mouthStretch": 0.4, "mouthSmile": 0.2}),
    "oh": (0.75, {"mouthFunnel": 0.5, "mouthPucker": 0.2}),
    "ou": (0.4, {"mouthPucker": 0.7, "mouthFunnel": 0.3}),
}


def _tables() -> tuple[np.ndarray, np.ndarray]:
    jaw = np.zeros(NUM_VISEMES)
    shapes = np.zeros((NUM_VISEMES, NUM_BLENDSHAPES))
    for name, (factor, channels) in _VISEME_SHAPES.items():
        v = VISEME_INDEX[name]
        jaw[v] = factor
        for ch, w in channels.items():
            for full in (ch,) if ch in B else (ch + "Left", ch + "Right"):
                shapes[v, B[full]] = w
    return jaw, shapes


VISEME_JAW, VISEME_SHAPES = _tables()
_BLINK = [0.35, 0.85, 1.0, 0.8, 0.5, 0.25, 0.08]
"""Eyelid closure over seven frames: a fast close and a slower reopening (about 230 ms)."""
BLINKS_PER_MINUTE = {"speaking": 21.0, "listening": 12.0, "silent": 14.0}
"""Spontaneous blinks: people blink more while talking (about 20-26 a minute) than while listening
attentively (about 10-20, with the listener's blinks at the partner's pauses on top of these),
and extra blinks mark the start of their own turn."""
INHALE_JAW = 0.035
"""How far the in-breath before a turn parts the lips: visibly, yet below a closed mouth's 0.05."""
_TURN_BLINK = 0.75
"""Chance of a blink just after self starts a turn (within 60-200 ms of the onset)."""
_END_BLINK = 0.25
"""Chance of a blink as self's turn ends."""


class FaceSynth:
    def __init__(self, options: ProceduralOptions, seed: int) -> None:
        self.o = options
        self.coart = smoother(0.035, NUM_VISEMES)
        self.jaw = AttackRelease(0.025, 0.012)
        self.blink = Filter(_BLINK, [1.0])
        self.brow = bump(0.16)
        self.smile = one_pole(0.35)
        self.eyes = smoother(0.02, 2)
        self.rand = FrameNoise(seed, 11, dims=6)
        self.gaze_rand = FrameNoise(seed, 12)  # whether a turn start looks away (gaze_aversion < 1)
        # Event state, carried between batches.
        self._since_blink = 99
        self._blink_phase = 0.0  # accumulated fraction of the mean inter-blink interval
        self._blink_due = 1.0  # phase at which the next spontaneous blink fires
        self._turn_blink_at = -1  # frame of a pending turn-start blink
        self._self_quiet = 99  # frames since self's voice was last active
        self._prev_self = False
        self._gaze = (0.0, 0.0)  # current gaze target (yaw, pitch) radians, 0 = at the partner
        self._avert_until = -1
        self._listener_glance = False  # the current aversion is a listener's glance (it may last)
        self._next_saccade = 0

    def step(
        self,
        first: int,
        s: dict[str, np.ndarray],
        o: dict[str, np.ndarray],
        visemes: np.ndarray,
        listener: dict[str, np.ndarray],
        inhale: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Face channels (n, 52), jaw angle (n,), and gaze (n, 2) yaw/pitch in radians."""
        n = len(visemes)
        face = np.zeros((n, NUM_BLENDSHAPES))
        vad_self = s["vad"]
        # Mouth: loudness sets the opening, the coarticulated viseme the shape.
        vis = self.coart(visemes)
        # Only frames that carry self's own voice open the mouth: not the quiet edges of a turn
        # (which the voice activity's hangover still counts), not the partner's voice in self's
        # microphone.
        drive = np.clip((s["env"] - 0.22) / 0.55, 0.0, 1.0) * vad_self * s["sounding"] * (1.0 - s["bleed"])
        drive = self.jaw(drive)
        jaw_factor = 0.5 + 0.5 * (vis @ VISEME_JAW)
        jaw_open = np.clip(0.8 * drive * jaw_factor + INHALE_JAW * inhale * (1.0 - drive), 0.0, 1.0)
        face += np.clip(drive * 1.3, 0.0, 1.0)[:, None] * (vis @ VISEME_SHAPES)
        face[:, B["jawOpen"]] = jaw_open
        for ch in ("mouthLowerDownLeft", "mouthLowerDownRight"):
            face[:, B[ch]] += 0.12 * inhale * (1.0 - drive)

        r = self.rand.take(first, n)
        blinks, gaze = self._events(first, r, self.gaze_rand.take(first, n)[:, 0], vad_self, o["vad"], listener)
        lids = np.clip(self.blink(blinks), 0.0, 1.0)
        face[:, B["eyeBlinkLeft"]] = lids
        face[:, B["eyeBlinkRight"]] = lids

        # Brows rise on self's pitch accents (and a little on the partner's while listening).
        e = self.o.expressiveness
        accents = s["accent"] + 0.3 * o["accent"] * (1 - vad_self)
        brow = np.clip(self.brow(accents * (0.6 + 0.4 * self.o.variability * r[:, 5])) * 0.7 * e, 0.0, 1.0)
        face[:, B["browInnerUp"]] = brow
        face[:, B["browOuterUpLeft"]] = 0.8 * brow
        face[:, B["browOuterUpRight"]] = 0.8 * brow

        # Smiles on one's own laughter-like bursts, and the listener's (at the partner's laughter,
        # at lively phrases).
        smile = np.clip(self.smile(np.maximum(s["laugh"], listener["smile"])) * min(1.0, 0.5 + 0.5 * e), 0.0, 1.0)
        for ch, w in (
            ("mouthSmileLeft", 0.7),
            ("mouthSmileRight", 0.7),
            ("cheekSquintLeft", 0.4),
            ("cheekSquintRight", 0.4),
            ("eyeSquintLeft", 0.3),
            ("eyeSquintRight", 0.3),
        ):
            face[:, B[ch]] = np.clip(face[:, B[ch]] + w * smile, 0.0, 1.0)

        eyes = self.eyes(gaze)
        face = gaze_channels(face, eyes)
        yaw, pitch = eyes[:, 0], eyes[:, 1]
        eyes = np.stack(
            [np.clip(yaw, -EYE_YAW_MAX, EYE_YAW_MAX), np.clip(pitch, -EYE_PITCH_MAX, EYE_PITCH_MAX)], axis=1
        )
        return np.clip(face, 0.0, 1.0), jaw_open * JAW_MAX_RAD, eyes

    def _events(
        self,
        first: int,
        r: np.ndarray,
        r_avert: np.ndarray,
        vad_self: np.ndarray,
        vad_other: np.ndarray,
        listener: dict[str, np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Blink impulses and the gaze target, frame by frame (light scalar work only)."""
        n = len(vad_self)
        blinks = np.zeros(n)
        gaze = np.empty((n, 2))
        v = self.o.variability
        aversion, reach = self.o.gaze_aversion, self.o.gaze_range
        u = r.tolist()
        avert_at_onset = (r_avert < aversion).tolist()
        vs, vo = vad_self.tolist(), vad_other.tolist()
        asked_blink, glance = listener["blink"].tolist(), listener["glance_frames"].tolist()
        glance_yaw, glance_pitch = listener["glance_yaw"].tolist(), listener["glance_pitch"].tolist()
        for j in range(n):
            k = first + j
            sp, ls = vs[j] > 0, vo[j] > 0
            self_onset = sp and not self._prev_self and self._self_quiet > 15
            self_end = self._prev_self and not sp
            # Blinks: a renewal process whose rate depends on who talks (fairly regular intervals,
            # jittered by the variability), plus blinks at turn boundaries.
            state = "speaking" if sp else ("listening" if ls else "silent")
            self._blink_phase += BLINKS_PER_MINUTE[state] / 60.0 / 30.0
            self._since_blink += 1
            if self_onset and u[j][0] < _TURN_BLINK:
                self._turn_blink_at = k + 2 + int(4 * u[j][0] / _TURN_BLINK)
            # The listener's blink at a partner's pause comes early rather than on top: only once
            # 60 % of the interval to the next spontaneous blink has passed.
            early = asked_blink[j] > 0 and self._blink_phase >= 0.6 * self._blink_due
            turn = k == self._turn_blink_at or (self_end and u[j][0] < _END_BLINK) or early
            if self._since_blink > 9 and (turn or self._blink_phase >= self._blink_due):
                blinks[j] = 1.0
                self._since_blink = 0
                self._blink_phase = 0.0
                self._blink_due = 1.0 + min(0.9, 0.45 * v) * (2.0 * u[j][1] - 1.0)
            if k >= self._turn_blink_at:
                self._turn_blink_at = -1
            # Gaze: at the partner while listening; averted when taking the turn; saccades.
            yaw, pitch = self._gaze
            if self_onset and avert_at_onset[j]:
                side = 1.0 if u[j][1] < 0.5 else -1.0
                yaw = side * math.radians(9.0 + 7.0 * v * u[j][2]) * reach
                pitch = math.radians(-5.0 if u[j][3] < 0.4 else 4.0) * reach
                self._avert_until = k + int(18 + 24 * u[j][4])
                self._next_saccade = self._avert_until
            elif glance[j] > 0 and not sp:  # the listener glances away
                yaw, pitch = glance_yaw[j] * reach, glance_pitch[j] * reach
                self._avert_until = k + int(glance[j])
                self._next_saccade = self._avert_until
                self._listener_glance = True
            elif k == self._avert_until or (not sp and self._avert_until > k and not self._listener_glance):
                yaw, pitch = 0.0, 0.0
                self._avert_until = -1
                self._listener_glance = False
            elif k >= self._next_saccade:
                if sp and u[j][3] < 0.12 * aversion:  # an occasional look away mid-turn
                    yaw = math.radians((6.0 + 6.0 * v * u[j][2]) * (1 if u[j][1] < 0.5 else -1)) * reach
                    pitch = math.radians(3.0 * (u[j][4] - 0.5)) * reach
                    self._avert_until = k + int(12 + 15 * u[j][4])
                    self._next_saccade = self._avert_until
                else:  # a micro-saccade around the partner's face
                    spread = math.radians(1.5 + 1.5 * v) * (1.0 if sp else 0.6)
                    yaw = spread * (2 * u[j][2] - 1)
                    pitch = 0.6 * spread * (2 * u[j][4] - 1)
                    self._next_saccade = k + int((10 if sp else 20) + 30 * u[j][1])
            self._gaze = (yaw, pitch)
            gaze[j] = self._gaze
            self._self_quiet = 0 if sp else self._self_quiet + 1
            self._prev_self = sp
        return blinks, gaze


def gaze_channels(face: np.ndarray, eyes: np.ndarray) -> np.ndarray:
    """Write the ``eyeLook*`` channels of ``face`` (n, 52) from gaze (n, 2) yaw/pitch in radians,
    so the blendshapes and the eye joints agree; returns ``face``."""
    yaw, pitch = eyes[:, 0], eyes[:, 1]
    left = np.clip(yaw / EYE_YAW_MAX, 0.0, 1.0)  # looking toward the character's left (+X)
    right = np.clip(-yaw / EYE_YAW_MAX, 0.0, 1.0)
    face[:, B["eyeLookOutLeft"]] = left
    face[:, B["eyeLookInRight"]] = left
    face[:, B["eyeLookInLeft"]] = right
    face[:, B["eyeLookOutRight"]] = right
    face[:, B["eyeLookUpLeft"]] = face[:, B["eyeLookUpRight"]] = np.clip(-pitch / EYE_PITCH_MAX, 0.0, 1.0)
    face[:, B["eyeLookDownLeft"]] = face[:, B["eyeLookDownRight"]] = np.clip(pitch / EYE_PITCH_MAX, 0.0, 1.0)
    return face
