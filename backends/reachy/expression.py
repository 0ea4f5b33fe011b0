"""The conversation's part of Reachy Mini's motion: where the body turns and how the antennas feel.

The profile maps the face and the head (brows and jaw move the antennas); this adds what follows
from who is talking, frame by frame from the motion's voice activity and conversation state:

- attention: the body turns toward the partner while the partner speaks and back toward its
  home yaw while self holds the turn (a first-order follow, so the turn is a glance, not a snap);
- perk: when the partner starts talking the antennas rise toward upright, then settle;
- droop: after a second of silence (nobody talking: self thinking, or waiting) they sink slowly,
  and come back as soon as anyone speaks;
- listening: while the partner speaks the head sways slowly on three incommensurate periods, the
  way an engaged listener's head keeps moving, easing in with the partner's voice and out quickly
  after it, so silence stays calm; it also tilts (roll) a few degrees as the body turns toward the
  partner, and holds the tilt as the body holds its turn. The generator's listener nods are small on
  this robot (a few degrees of pitch); without this the head moved only about 1.2 times as fast
  while the partner spoke as in silence.
"""

from __future__ import annotations

import dataclasses
import math

from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionFrame

ATTENTION_TAU_S = 0.6
PERK_TAU_S = 0.8
PERK_RAD = 0.6
"""How far a perk brings the antennas toward upright (from their own pose)."""
DROOP_AFTER_S = 1.0
DROOP_RISE_S = 2.5
DROOP_RAD = 0.8
QUIET_BEFORE_ONSET_S = 0.4
"""The partner must have been quiet this long for their voice to count as a start."""
VOICE = 0.5
LISTEN_TAU_S = (0.4, 0.2)
"""The sway eases in with the partner's voice and out after it (s)."""
LISTEN_TILT_DEG = 5.0
LISTEN_SWAY = ((4.0, 0.41), (3.0, 0.59), (4.0, 0.27))
"""(Amplitude in degrees, frequency in Hz) of the listening sway of roll, pitch and yaw: some 18
deg/s in all, a fraction of what Reachy Mini's own speech wobbler does (pitch 4.5 deg at 2.2 Hz,
yaw 7.5 deg at 0.6 Hz, roll 2.25 deg at 1.3 Hz)."""
LISTEN_ANTENNAS = (0.15, 0.7)
"""(Amplitude in rad, frequency in Hz) of the antennas' listening sway, both alike."""


@dataclasses.dataclass(frozen=True)
class Part:
    """What the conversation adds to one frame's command (radians)."""

    body: float
    antennas: float
    """Antenna magnitude to add: + droops, - perks."""
    head: tuple[float, float, float]
    """Head roll, pitch and yaw."""


class Expression:
    """Stateful: feed it every frame in order with the frame's time step."""

    def __init__(self, partner_yaw: float, home_yaw: float = 0.0, listening: float = 1.0) -> None:
        self.partner_yaw = partner_yaw
        self.home_yaw = home_yaw
        self.listening_gain = listening
        self.reset()

    def reset(self) -> None:
        self.attention = 0.0
        self.perk = 0.0
        self.droop = 0.0
        self.listening = 0.0
        self._t = 0.0
        self._partner_quiet_s = math.inf
        self._silent_s = 0.0

    def step(self, motion: MotionFrame, dt: float) -> Part:
        """Advance one frame."""
        state = ConversationState(int(motion.state))
        partner = float(motion.vad[1]) >= VOICE or state in (ConversationState.LISTENING, ConversationState.OVERLAP)
        speaking = float(motion.vad[0]) >= VOICE or state in (ConversationState.SPEAKING, ConversationState.OVERLAP)
        if partner and self._partner_quiet_s >= QUIET_BEFORE_ONSET_S:
            self.perk = 1.0
        self._partner_quiet_s = 0.0 if partner else self._partner_quiet_s + dt
        self._silent_s = 0.0 if partner or speaking else self._silent_s + dt

        goal = 1.0 if partner else (0.0 if speaking else self.attention)
        self.attention += (goal - self.attention) * (1.0 - math.exp(-dt / ATTENTION_TAU_S))
        self.perk *= math.exp(-dt / PERK_TAU_S)
        droop_goal = min(1.0, max(0.0, (self._silent_s - DROOP_AFTER_S) / DROOP_RISE_S))
        rate = dt / DROOP_RISE_S if droop_goal > self.droop else dt / 0.3  # sinks slowly, recovers fast
        self.droop += max(-rate, min(rate, droop_goal - self.droop))
        body = self.home_yaw + self.attention * (self.partner_yaw - self.home_yaw)
        head, sway = self._listen(partner, dt)
        return Part(body, DROOP_RAD * self.droop - PERK_RAD * self.perk + sway, head)

    def _listen(self, partner: bool, dt: float) -> tuple[tuple[float, float, float], float]:
        """The head's roll, pitch and yaw and the antennas' magnitude while listening: the sway
        follows the partner's voice, the tilt (roll) the attention."""
        self._t += dt
        tau = LISTEN_TAU_S[0] if partner else LISTEN_TAU_S[1]
        self.listening += (float(partner) - self.listening) * (1.0 - math.exp(-dt / tau))
        level = self.listening_gain * self.listening
        roll, pitch, yaw = (math.radians(level * a) * math.sin(2 * math.pi * f * self._t) for a, f in LISTEN_SWAY)
        tilt = math.radians(self.listening_gain * self.attention * LISTEN_TILT_DEG)
        antennas = level * LISTEN_ANTENNAS[0] * math.sin(2 * math.pi * LISTEN_ANTENNAS[1] * self._t)
        return (roll + tilt, pitch, yaw), antennas
