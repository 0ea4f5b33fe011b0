"""Face and conversation-state channels of the canonical motion."""

from __future__ import annotations

import enum
import math

import numpy as np

ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
)
NUM_BLENDSHAPES = len(ARKIT_NAMES)
BLENDSHAPE_INDEX: dict[str, int] = {name: i for i, name in enumerate(ARKIT_NAMES)}

# How the skeleton's jaw and eye joints tie to the face channels (DESIGN: "kept consistent"):
# generators write both, and renderers or retargeters may read either.
JAW_OPEN_RAD = math.radians(28.0)
"""Jaw joint rotation about +X (chin down) at ``jawOpen`` = 1."""
EYE_LOOK_YAW_RAD = math.radians(30.0)
EYE_LOOK_PITCH_RAD = math.radians(25.0)
"""Eye joint yaw / pitch at which an ``eyeLook*`` channel reaches 1."""

VAD_NAMES: tuple[str, str] = ("self", "other")
"""Columns of a clip's voice-activity array: self (channel 0) and the partner (channel 1)."""
VAD_ON = 0.5
"""Voice activity above which a side counts as speaking (a learned model's is a soft value in [0, 1])."""


class ConversationState(enum.IntEnum):
    """Who is talking in a frame, from self's point of view."""

    SILENCE = 0
    SPEAKING = 1
    LISTENING = 2
    OVERLAP = 3

    @classmethod
    def from_activity(cls, self_active: bool, other_active: bool) -> ConversationState:
        if self_active and other_active:
            return cls.OVERLAP
        if self_active:
            return cls.SPEAKING
        if other_active:
            return cls.LISTENING
        return cls.SILENCE

    @classmethod
    def from_vad(cls, vad: np.ndarray, threshold: float = VAD_ON) -> np.ndarray:
        """(T,) int8 states from (T, 2) voice activity of self and the partner."""
        vad = np.asarray(vad)
        speaking, listening = vad[:, 0] > threshold, vad[:, 1] > threshold
        return np.select(
            [speaking & listening, speaking, listening], [cls.OVERLAP, cls.SPEAKING, cls.LISTENING], cls.SILENCE
        ).astype(np.int8)
