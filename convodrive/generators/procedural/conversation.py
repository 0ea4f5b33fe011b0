"""What the conversation's events (``generators.events``) change in the procedural motion.

- **Planning** (thinking, a tool call, before the first played sample): people avert their gaze
  while they plan what to say, so the eyes go up and to one side (the side drawn per episode) and
  the head, which follows the eyes, tilts a little; the mouth stays shut.
- **Interrupted, paused**: nothing queued will be heard, so the mouth shuts within two frames and
  self's voice counts as silence from the event on (``self_silent``): no lips on audio that will
  never play, and a running beat gesture ends as it does when a turn ends.
- **Idle** for ``IDLE_RELAX`` seconds: the body relaxes into slower, deeper breathing and slow
  glances around the room.

A generator without events is left exactly as it was (``active`` is False until the first event),
so offline generation equals streaming.
"""

from __future__ import annotations

import math

import numpy as np

from convodrive.generators.events import AgentState, EventLog
from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.signals import AttackRelease, FrameNoise, smoother
from convodrive.motion.channels import ARKIT_NAMES, EYE_LOOK_PITCH_RAD, EYE_LOOK_YAW_RAD
from convodrive.motion.rotations import axis_angle_to_quat, quat_multiply, quat_to_axis_angle
from convodrive.motion.skeleton import JOINT_INDEX as J

MOUTH = np.array(
    [
        i
        for i, n in enumerate(ARKIT_NAMES)
        if (n.startswith(("mouth", "jaw", "tongue")) or n == "cheekPuff") and not n.startswith("mouthSmile")
    ]
)
"""Channels that move with speech: shut with the mouth (smiles stay)."""
AVERT_YAW = 0.32
AVERT_PITCH = -0.16
"""Where planning eyes go (radians; negative pitch looks up), before ``gaze_range``."""
THINK_TILT = math.radians(5.0)
"""The head's roll toward the averted side while planning."""
IDLE_RELAX = 5.0
"""Seconds idle before the body relaxes."""
GLANCE_SECONDS = 4.0
BREATH_HZ = 0.2


class ConversationOverlay:
    """Per take: turns the conversation state at each frame into gaze, head, mouth and breath."""

    def __init__(self, options: ProceduralOptions, seed: int, log: EventLog) -> None:
        self.o = options
        self.log = log
        self.seed = seed
        self.shut = AttackRelease(0.02, 0.06)
        self.away = smoother(0.1, 3)
        self.glance = smoother(0.6, 2)
        self.relax = smoother(1.0)
        self.noise = FrameNoise(seed, 71, 2)

    @property
    def active(self) -> bool:
        return len(self.log) > 0

    def states(self, first: int, n: int) -> list[AgentState]:
        return self.log.states([(first + j) / 30.0 for j in range(n)])

    def self_silent(self, start: int, samples: int, rate: int) -> np.ndarray | None:
        """A mask over ``samples`` samples from ``start`` that are shut (interrupted, paused,
        planning): self's voice there is never heard. None when nothing is shut."""
        if not self.active or not samples:
            return None
        step = max(rate // 100, 1)
        times = [(start + i) / rate for i in range(0, samples, step)]
        shut = np.array([s.mouth_shut for s in self.log.states(times)])
        if not shut.any():
            return None
        return np.repeat(shut, step)[:samples]

    def gaze(self, first: int, states: list[AgentState], eyes: np.ndarray) -> np.ndarray:
        """Eyes (n, 2) yaw/pitch moved to where planning and idle glances take them."""
        n = len(states)
        t = (first + np.arange(n)) / 30.0
        planning = np.array([s.planning for s in states], float)
        side = np.array([_side(s.thinking_since or s.tool_since, self.seed) for s in states])
        r = self.o.gaze_range
        away = self.away(np.stack([planning * side * AVERT_YAW * r, planning * AVERT_PITCH * r, planning * side], 1))
        idle = np.array([min(max(s.idle_for(x) - IDLE_RELAX, 0.0) / 2.0, 1.0) for s, x in zip(states, t)])
        relax = self.relax(idle)
        block = np.floor(t / GLANCE_SECONDS).astype(int)
        targets = np.array([self.noise.take(int(b * GLANCE_SECONDS * 30), 1)[0] for b in block]) - 0.5
        glance = self.glance(targets * np.array([0.5, 0.15]) * r) * relax[:, None]
        self._tilt = away[:, 2] * THINK_TILT
        self._relax = relax
        self._t = t
        moved = eyes + away[:, :2] + glance
        limit = np.array([EYE_LOOK_YAW_RAD, EYE_LOOK_PITCH_RAD])
        return np.clip(moved, -limit, limit)

    def body(self, states: list[AgentState], pose: np.ndarray, face: np.ndarray) -> None:
        """Shut the mouth, tilt the head, breathe: in place on ``pose`` (n, 55, 3), ``face``."""
        shut = self.shut(np.array([s.mouth_shut for s in states], float))
        keep = (1.0 - shut)[:, None]
        face[:, MOUTH] *= keep
        pose[:, J["jaw"]] *= keep
        extra = np.zeros((len(states), 3))
        extra[:, 2] = self._tilt
        breath = self._relax * np.sin(2 * np.pi * BREATH_HZ * self._t)
        extra[:, 1] = math.radians(1.5) * breath
        q = quat_multiply(axis_angle_to_quat(pose[:, J["head"]]), axis_angle_to_quat(extra))
        pose[:, J["head"]] = quat_to_axis_angle(q)
        for name, gain in (("spine2", 2.0), ("spine3", 2.5)):
            pose[:, J[name], 0] -= math.radians(gain) * breath


def _side(since: float | None, seed: int) -> float:
    """Which way one planning episode looks: drawn from its start time and the take's seed."""
    if since is None:
        return 1.0
    return 1.0 if (int(round(since * 30)) * 2654435761 + seed * 40503) % 2 else -1.0
