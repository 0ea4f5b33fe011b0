"""convodrive: conversation audio to embodied motion, sent 30 times a second to any body.

The canonical motion types (``convodrive.motion``) are the contract every part speaks; see
docs/ARCHITECTURE.md in the project for its folders and which part may import which.
"""

__version__ = "0.1.0"

FPS = 30
"""The canonical motion rate. Every frame, clip, and backend speaks 30 frames per second."""
