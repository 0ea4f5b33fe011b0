"""Backend ``osc``: the face, the joints and who is talking as Open Sound Control, one bundle a frame.

For Unity (extOSC, OscJack), VRChat-style rigs and TouchDesigner: one address per ARKit channel
(``face_path``, a float in [0, 1]) and per joint (``joint_path``, its local rotation as a
quaternion x, y, z, w, or as yaw, pitch, roll in degrees), plus ``{prefix}/vad`` (self, partner)
and ``{prefix}/state`` (an int: 0 silence, 1 speaking, 2 listening, 3 overlap). Every frame's messages travel in one bundle, so a receiver applies a whole
frame at once. VRChat listens for ``/avatar/parameters/<name>`` on port 9000:
``-B osc.face_path=/avatar/parameters/{name} -B osc.joints=false``.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from convodrive.backends.net import UdpBackend
from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_NAMES
from convodrive.motion.targets import TargetFrame
from convodrive.plugins.options import PluginOptions, option

NAME = "{name}"
"""The one placeholder of ``face_path`` and ``joint_path``: replaced as text, never a format string."""


@dataclasses.dataclass(frozen=True)
class OscOptions(PluginOptions):
    host: str = option("127.0.0.1", help="Where the receiver listens")
    port: int = option(9000, low=1, high=65535, help="Its UDP port")
    face_path: str = option("/convodrive/face/{name}", help="Address of each ARKit channel; {name} is its name")
    joint_path: str = option("/convodrive/joint/{name}", help="Address of each joint; {name} is its SMPL-X name")
    prefix: str = option("/convodrive", help="Address prefix of vad and state")
    face: bool = option(True, help="Send the 52 face channels")
    joints: bool = option(True, help="Send the 55 joint rotations")
    rotation: str = option(
        "quaternion", choices=("quaternion", "euler"), help="Joints as x, y, z, w or as yaw, pitch, roll degrees (YXZ)"
    )

    def __post_init__(self) -> None:
        for key in ("face_path", "joint_path"):
            value = getattr(self, key)
            if not value.startswith("/") or "{name}" not in value:
                raise ValueError(f"option '{key}' must start with / and hold {{name}}, got {value!r}")
            if re.search(r"[{}]", value.replace(NAME, "")):
                raise ValueError(f"option '{key}': {{name}} is the only field a path may hold, got {value!r}")
        if not self.prefix.startswith("/"):
            raise ValueError(f"option 'prefix' must start with /, got {self.prefix!r}")


class OscBackend(UdpBackend):
    name = "osc"
    description = "Face channels, joints and voice activity as OSC bundles (Unity, VRChat, TouchDesigner)"
    unit = "bundles"
    requires = ("pythonosc",)
    extra = "live"
    Options = OscOptions
    options: OscOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        o = self.options
        self._face_addresses = [o.face_path.replace(NAME, n) for n in ARKIT_NAMES]
        self._joint_addresses = [o.joint_path.replace(NAME, n) for n in JOINT_NAMES]

    def datagram(self, frame: TargetFrame) -> bytes:
        """One frame as one OSC bundle (timetag: immediately)."""
        from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
        from pythonosc.osc_message_builder import OscMessageBuilder

        motion = frame.motion
        bundle = OscBundleBuilder(IMMEDIATELY)

        def add(address: str, values: Any, tag: str = "f") -> None:
            message = OscMessageBuilder(address)
            for v in np.atleast_1d(values):
                message.add_arg(float(v) if tag == "f" else int(v), tag)
            bundle.add_content(message.build())

        if self.options.face:
            for address, value in zip(self._face_addresses, motion.face):
                add(address, value)
        if self.options.joints:
            if self.options.rotation == "quaternion":
                w_xyz = rotations.axis_angle_to_quat(motion.pose)
                values = np.concatenate([w_xyz[:, 1:], w_xyz[:, :1]], axis=1)
            else:
                values = np.degrees(rotations.axis_angle_to_euler(motion.pose, "YXZ"))
            for address, value in zip(self._joint_addresses, values):
                add(address, value)
        add(f"{self.options.prefix}/vad", motion.vad)
        add(f"{self.options.prefix}/state", int(motion.state), "i")
        return bundle.build().dgram
