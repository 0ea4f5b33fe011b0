"""Head, torso and arms: nods and tilts on pitch accents, speech-driven sway, beat gestures while
speaking; backchannel nods (``listener``), posture shifts, arm rest, breathing and the in-breath
before a turn (``posture``) at all times.

Speech-driven motion scales with self's speaking activity, so the body moves most while talking
(audio2photoreal's observation); while listening it stays attentive rather than frozen: nods,
slow head drift, posture shifts, breathing. Gestures blend between key poses (``poses``) through a
critically damped filter, which gives eased, natural transitions without overshoot.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.poses import ARM_JOINTS, KEY_POSES, LIBRARY, LIBRARY_RIGHT, rest_pose
from convodrive.generators.procedural.signals import FrameNoise, bump, one_pole, smoother
from convodrive.motion.skeleton import JOINT_INDEX as J
from convodrive.motion.skeleton import NUM_JOINTS

_P = len(KEY_POSES)
_GESTURE_CHOICE = np.cumsum([0.0, 0.45, 0.25, 0.15, 0.15])  # rest excluded: beat, palms, grip, point
_DRIFT_TAU = 1.2
_DRIFT_GAIN = math.sqrt(2.0 * 30.0 * _DRIFT_TAU)  # roughly unit-variance output of the drift filter


def yxz_axis_angle(angles: np.ndarray) -> np.ndarray:
    """(n, 3) intrinsic yaw (Y), pitch (X), roll (Z) to axis-angle, like ``euler_to_axis_angle(a,
    "YXZ")`` but in closed form: the quaternion product qy qx qz written out, about ten times faster
    on the few frames of a streaming step."""
    c, s = np.cos(0.5 * angles), np.sin(0.5 * angles)
    cy, cx, cz = c[:, 0], c[:, 1], c[:, 2]
    sy, sx, sz = s[:, 0], s[:, 1], s[:, 2]
    w = cy * cx * cz + sy * sx * sz
    v = np.stack([cz * cy * sx + cx * sy * sz, cz * cx * sy - cy * sx * sz, cy * cx * sz - cz * sy * sx], axis=1)
    flip = (w < 0)[:, None]  # the shorter way round: angle in [0, pi]
    w = np.abs(w)[:, None]
    v = np.where(flip, -v, v)
    norm = np.sqrt((v * v).sum(axis=1, keepdims=True))
    small = norm < 1e-9
    scale = np.where(small, 2.0 / np.maximum(w, 1e-12), 2.0 * np.arctan2(norm, w) / np.where(small, 1.0, norm))
    return v * scale


class BodySynth:
    def __init__(self, options: ProceduralOptions, seed: int) -> None:
        self.o = options
        self.rest = rest_pose()
        self.speaking = one_pole(0.35)
        self.listening = one_pole(0.6)
        self.loud = one_pole(0.12)
        self.nod = bump(0.14)  # self's accents and the listener's quick nods
        self.tilt = bump(0.22, 2)  # self's tilts on accents; the listener's slow nods
        self.beat_nod = bump(0.09)  # self's stresses; the listener's dips in time with the partner
        self.drift = smoother(_DRIFT_TAU, 5)
        self.follow = smoother(0.35, 5)  # the head following the eyes (2), the listener's attitude (3)
        # Both arms start in the rest pose (weight 1 on library pose 0), not eased in from a T-pose.
        self.arms = smoother(0.13, 2 * _P).settle(np.tile(np.eye(_P)[0], 2))
        self.flick = bump(0.09, 2)
        self.uniform = FrameNoise(seed, 21, dims=6)
        self.normal = FrameNoise(seed, 22, dims=5, kind="normal")
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 23])
        v = options.variability
        self.phase = rng.uniform(0, 2 * np.pi, 4)
        self.freq = np.array([2.2, 0.6, 1.3, 0.27]) * (1.0 + 0.15 * v * rng.uniform(-1, 1, 4))
        # Event state.
        self._since_stroke = 99
        self._hold = [-1, -1]
        self._pose = [0, 0]
        self._self_quiet = 99

    def step(
        self,
        first: int,
        s: dict[str, np.ndarray],
        o: dict[str, np.ndarray],
        gaze: np.ndarray,
        listener: dict[str, np.ndarray],
        posture: dict[str, np.ndarray],
    ) -> np.ndarray:
        """(n, 55, 3) axis-angle pose."""
        n = len(gaze)
        u = self.uniform.take(first, n)
        vad_self, vad_other = s["vad"], o["vad"]
        act = self.speaking(vad_self)
        listen = self.listening(vad_other * (1.0 - vad_self))
        loud = self.loud(s["env"] * vad_self)
        arm_targets, flicks = self._events(first, u, s)
        head, sway = self._head(first, u, s, o, gaze, listener, posture, act, listen, loud)
        pose = np.broadcast_to(self.rest, (n, NUM_JOINTS, 3)).copy()
        self._torso(pose, head, posture, listen, sway)
        self._arms(pose, posture["arms"], arm_targets, flicks)
        return pose

    def _head(
        self,
        first: int,
        u: np.ndarray,
        s: dict[str, np.ndarray],
        o: dict[str, np.ndarray],
        gaze: np.ndarray,
        listener: dict[str, np.ndarray],
        posture: dict[str, np.ndarray],
        act: np.ndarray,
        listen: np.ndarray,
        loud: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The head's (yaw, pitch, roll) in radians (n, 3), and the torso's sway (2, n)."""
        n = len(u)
        e, v = self.o.expressiveness, self.o.variability
        t = (first + np.arange(n)) / 30.0
        accent = s["accent"] * (1.0 + 0.5 * v * (u[:, 0] - 0.5))
        side = np.where(u[:, 1] < 0.5, -1.0, 1.0)
        # Nods: on self's accents and stresses, and the listener's backchannel nods; a listener's
        # head also dips a little in time with the speaker's syllables (interactional synchrony),
        # far below a nod.
        tilts = self.tilt(np.stack([accent * side, listener["nod_slow"]], axis=1))
        nod = (
            self.nod(accent * 6.0 + listener["nod"] * 5.5)
            + self.beat_nod(s["stress"] * 1.8 + o["nucleus"] * listen * 0.5)
            + tilts[:, 1] * 7.0
        )
        tilt = tilts[:, 0] * 3.0
        osc = np.sin(2 * np.pi * self.freq[:3] * t[:, None] + self.phase[:3])
        wobble = osc * np.array([2.0, 3.5, 1.6]) * loud[:, None]
        drift = self.drift(self.normal.take(first, n)) * _DRIFT_GAIN
        drift_amp = (0.9 + 1.8 * act)[:, None] * (0.4 + 0.6 * v)
        followed = self.follow(np.concatenate([gaze, np.radians(listener["attitude"])], axis=1))
        follow = np.degrees(followed[:, :2]) * 0.3
        attitude = np.degrees(followed[:, 2:]) * e
        body = posture["posture"]  # lean, side, twist, weight, head yaw, pitch, roll (degrees)
        inhale = posture["inhale"]

        pitch = e * (nod + wobble[:, 0] + drift_amp[:, 0] * drift[:, 0] * 0.8) + 2.0 * listen + follow[:, 1]
        yaw = e * (wobble[:, 1] + drift_amp[:, 0] * drift[:, 1] * 1.5) + follow[:, 0]
        roll = e * (tilt + wobble[:, 2] + drift_amp[:, 0] * drift[:, 2] * 0.7) + 2.5 * listen
        # Where the head rests moves with the posture and the listener's attitude; breathing in
        # before a turn lifts the chin.
        yaw = yaw + body[:, 4] + attitude[:, 0]
        pitch = pitch + body[:, 5] + attitude[:, 1] - 2.0 * inhale
        roll = roll + body[:, 6] + attitude[:, 2]
        head = np.radians(np.stack([yaw, pitch, roll], axis=1))
        return head, np.radians(e * drift_amp[:, 0] * drift[:, 3:5].T)

    def _torso(
        self, pose: np.ndarray, head: np.ndarray, posture: dict[str, np.ndarray], listen: np.ndarray, sway: np.ndarray
    ) -> None:
        """Neck, head, spine, pelvis and collars of ``pose``, in place."""
        n = len(head)
        body, inhale = posture["posture"], posture["inhale"]
        # Neck takes 40 % and head 60 % of the head's motion (intrinsic yaw, pitch, roll).
        # Posture: the weight on one hip (pelvis roll, the spine bending back over it), a lean,
        # a bend and a turn at the lower back; the in-breath before a turn leans in.
        rad = np.radians
        lower_back = rad(
            np.stack([body[:, 2], body[:, 0] + 0.5 * listen + 1.8 * inhale, body[:, 1] - 0.6 * body[:, 3]], axis=1)
        )
        # One conversion for the three joints: on a streaming step's few frames its cost is per call.
        pose[:, [J["neck"], J["head"], J["spine1"]]] = (
            yxz_axis_angle(np.concatenate([0.4 * head, 0.6 * head, lower_back])).reshape(3, n, 3).transpose(1, 0, 2)
        )
        pose[:, J["pelvis"], 2] = rad(body[:, 3])
        # Breathing lifts the chest and shoulders (a deeper breath before a turn); the torso sways
        # a little while talking.
        breath = posture["breath"] + 1.6 * inhale
        for name, gain in (("spine2", 0.35), ("spine3", 0.5)):
            pose[:, J[name], 0] = rad(-gain * breath + 0.5 * listen)
        pose[:, J["spine2"], 1] += 0.6 * sway[0]
        pose[:, J["spine2"], 2] = rad(-0.3 * body[:, 3])
        pose[:, J["spine3"], 2] += 0.4 * sway[1]
        pose[:, J["left_collar"], 2] = rad(0.7 * breath)
        pose[:, J["right_collar"], 2] = rad(-0.7 * breath)

    def _arms(self, pose: np.ndarray, rest_offset: np.ndarray, arm_targets: np.ndarray, flicks: np.ndarray) -> None:
        """The arms of ``pose``, in place: at rest as the posture has them (``rest_offset``, (n, 2, 18, 3));
        gestures leave from and return to that rest."""
        for a, arm in enumerate(("left", "right")):
            pose[:, ARM_JOINTS[arm]] += rest_offset[:, a]
        if not self.o.gestures:
            return
        w = self.arms(arm_targets)
        amount = min(self.o.expressiveness, 1.5)
        for a, (arm, lib) in enumerate((("left", LIBRARY), ("right", LIBRARY_RIGHT))):
            blend = np.einsum("np,pjd->njd", w[:, a * _P : (a + 1) * _P], lib)
            idx = ARM_JOINTS[arm]
            rest = w[:, a * _P, None, None]  # how much of the arm is at rest
            pose[:, idx] = lib[0] + amount * (blend - lib[0]) + rest * rest_offset[:, a]
        # The beat itself: a quick downward flick of the forearm on the stressed syllable.
        flick = self.flick(flicks) * np.radians(9.0) * amount
        pose[:, J["left_elbow"], 1] += flick[:, 0]
        pose[:, J["right_elbow"], 1] -= flick[:, 1]

    def _events(self, first: int, u: np.ndarray, s: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Arm key-pose targets (n, 2P) and beat impulses (n, 2)."""
        n = len(u)
        targets = np.zeros((n, 2 * _P))
        flicks = np.zeros((n, 2))
        v = self.o.variability
        uu = u.tolist()
        vs = s["vad"].tolist()
        stress = s["stress"].tolist()
        for j in range(n):
            k = first + j
            r = uu[j]
            sp = vs[j] > 0
            self._self_quiet = 0 if sp else self._self_quiet + 1
            # Gestures: a stroke on a stressed syllable, from a key pose, held briefly.
            self._since_stroke += 1
            if sp and stress[j] > 0 and self._since_stroke > 12 + int(10 * v * r[4]):
                pick = int(np.searchsorted(_GESTURE_CHOICE, r[5] * 0.999999, side="right"))
                arms = (1,) if r[1] < 0.5 else ((0,) if r[1] < 0.75 else (0, 1))
                for a in arms:
                    self._pose[a] = pick
                    self._hold[a] = k + 14 + int(20 * v * r[3])
                    flicks[j, a] = stress[j]
                self._since_stroke = 0
            for a in (0, 1):
                if self._hold[a] < k or self._self_quiet > 6:
                    self._pose[a] = 0
                targets[j, a * _P + self._pose[a]] = 1.0
        return targets, flicks
