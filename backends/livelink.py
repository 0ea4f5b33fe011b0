"""Backend ``livelink``: the face and head as Live Link Face UDP packets, for Unreal Engine.

Unreal's Live Link plugin (with the Live Link Face source) lists the sender as a subject by its
``subject`` name and drives a MetaHuman or any ARKit face rig with it: 52 blendshapes plus head
and eye rotations in radians, one datagram a frame (``convodrive.motion.livelink.encode_packet``).
UDP needs no connection, so a listener may come and go; sending never waits for one (a closed
port is reported: ``convodrive.backends.net.UdpSender``).
"""

from __future__ import annotations

import dataclasses

from convodrive.backends.net import UdpBackend
from convodrive.motion.livelink import UDP_PORT, encode_packet, head_eye_rotations
from convodrive.motion.targets import TargetFrame
from convodrive.plugins.options import PluginOptions, option


@dataclasses.dataclass(frozen=True)
class LivelinkOptions(PluginOptions):
    host: str = option("127.0.0.1", help="Where Unreal listens (its machine's address)")
    port: int = option(UDP_PORT, low=1, high=65535, help="Its Live Link Face port")
    subject: str = option("convodrive", help="Subject name Unreal lists the face under")
    device_id: str = option("convodrive", help="Device id sent with every packet")


class LivelinkBackend(UdpBackend):
    name = "livelink"
    description = "Face and head as Live Link Face UDP packets (Unreal Engine's Live Link, MetaHumans)"
    unit = "packets"
    Options = LivelinkOptions
    options: LivelinkOptions

    def datagram(self, frame: TargetFrame) -> bytes:
        motion = frame.motion
        return encode_packet(
            self.options.device_id,
            self.options.subject,
            frame.index,
            motion.face,
            head_eye_rotations(motion.pose[None])[0],
            fps=int(round(self.session.fps if self.session else 30)),
        )
