"""The canonical motion: skeleton, face channels, frames and clips, rotation conversions, clip I/O."""

from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX, NUM_BLENDSHAPES, ConversationState
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS, REST_OFFSETS

__all__ = [
    "ARKIT_NAMES",
    "BLENDSHAPE_INDEX",
    "NUM_BLENDSHAPES",
    "ConversationState",
    "MotionClip",
    "MotionFrame",
    "JOINT_INDEX",
    "JOINT_NAMES",
    "NUM_JOINTS",
    "PARENTS",
    "REST_OFFSETS",
]
