"""Retargeting: canonical motion to a target's joint space, declared per robot in YAML.

``load_profile("servo_head")`` reads config/robots/servo_head.yaml (or any path);
``Retargeter(profile)`` turns ``MotionFrame``s into joint values in ``profile.spec.names`` order.
"""

from convodrive.retargeting.profile import RobotProfile, load_profile
from convodrive.retargeting.retargeter import Retargeter

__all__ = ["RobotProfile", "Retargeter", "load_profile"]
