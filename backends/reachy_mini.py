"""Backend ``reachy_mini``: Pollen Robotics' Reachy Mini through its daemon.

The robot profile ``reachy_mini`` maps the canonical neck and head to the head's rotation and a
few millimetres of position, the torso's twist to the body's yaw and the face to the antennas;
here the conversation adds its part (``reachy.expression``: the body turns toward the partner while
they speak, the head tilts and sways as it listens, the antennas perk up when they start and droop
in a long silence). Every frame becomes one ``set_full_target`` on the daemon's SDK WebSocket
(``reachy.link``; ``-B reachy_mini.client=sdk``: through the official client, ``reachy.sdk_link``),
clamped first to the backend's own limits (``reachy.pose``), because the daemon silently drops a
pose its IK cannot reach. The daemon's state stream gives the health (disconnects, a stale stream,
a head that does not follow: an unreachable pose or a move of the daemon's own) and the run
report's lag and tracking error (``reachy.tracking``). On open and on close the backend streams a
calm minimum-jerk ease itself (the daemon's own ``goto`` would make it ignore every target meanwhile).

The daemon runs apart (``scripts/reachy_daemon.py``, README "Reachy Mini"): a simulated robot on
127.0.0.1 by default, the real one with ``-B reachy_mini.host=ADDRESS``. Names are never resolved
by mDNS. The daemon owns the motors: on exit the head rests at neutral with torque on, and the
daemon's own stop puts it to sleep.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, RobotOptions, Session
from convodrive.backends.reachy import pose as rp
from convodrive.backends.reachy.expression import Expression
from convodrive.backends.reachy.link import DaemonLink
from convodrive.backends.reachy.sdk_link import SdkLink
from convodrive.backends.reachy.tracking import follow_figures, speeds_by_state
from convodrive.backends.servo.servo_report import latency_summary
from convodrive.motion.channels import ConversationState
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.errors import UserError

TICK_HZ = 30.0
STALE_S = 0.5
"""No state message for this long: the daemon's stream has stalled."""
FOLLOW_WINDOW_S = 0.4
"""A read-back is 'following' when it is near some command of this last window (covers the lag)."""
FOLLOW_TOLERANCE = (math.radians(4.0), 0.004)
"""Head angle (rad) and position (m) off every recent command: the daemon did not take the pose."""
NOT_FOLLOWING_FRAMES = 10
NEUTRAL_TOLERANCE = (math.radians(1.5), 0.0015, 0.05)
"""Head angle (rad), position (m) and body/antenna (rad) from neutral that count as arrived."""
NEUTRAL_SETTLE_S = 1.0
READBACK_GUARD_S = 0.1
"""Read-backs this near a change of conversation state count in neither (``_liveliness``)."""
EASE = -1
"""The state recorded with an ease's commands (not a frame's conversation state)."""
JOINTS = {
    "head_x": rp.X,
    "head_y": rp.Y,
    "head_z": rp.Z,
    "head_roll": rp.ROLL,
    "head_pitch": rp.PITCH,
    "head_yaw": rp.YAW,
    "body_yaw": rp.BODY,
    "antenna_right": rp.ANT_R,
    "antenna_left": rp.ANT_L,
}
"""Profile joint -> command field; head_yaw is relative to the body (the backend adds the body)."""


@dataclasses.dataclass(frozen=True)
class ReachyMiniOptions(RobotOptions):
    host: str = option("127.0.0.1", help="Address of the robot's daemon (an IP address or a name; mDNS is never used)")
    port: int = option(8000, low=1, high=65535, help="Port of the daemon (reachy-mini-daemon --fastapi-port)")
    client: str = option(
        "websocket",
        choices=("websocket", "sdk"),
        help="websocket: speak the daemon's SDK protocol directly; sdk: through the official client "
        "(PyPI reachy-mini, installed without its pins: README, 'Reachy Mini')",
    )
    partner_yaw_deg: float = option(
        20.0, low=-150, high=150, help="Where the partner sits (deg, + to the robot's left): the body turns there"
    )
    home_yaw_deg: float = option(0.0, low=-150, high=150, help="Where the body faces while self speaks (deg)")
    listening: float = option(
        1.0, low=0, high=3, help="How much the head tilts and sways while the partner speaks (0: not at all)"
    )
    ease_s: float = option(1.0, low=0.1, high=10, help="Calm ease to neutral on open and on close (s)")


class ReachyMiniBackend(Backend):
    name = "reachy_mini"
    description = "Pollen Robotics Reachy Mini (head, antennas, body) through its daemon's SDK WebSocket"
    realtime = True
    hardware = True
    light = True
    default_profile = "reachy_mini"
    requires = ("websockets",)
    extra = "reachy"
    Options = ReachyMiniOptions
    options: ReachyMiniOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.limits = rp.Limits()
        self.link: DaemonLink | None = None
        self.expression = Expression(
            math.radians(self.options.partner_yaw_deg),
            math.radians(self.options.home_yaw_deg),
            self.options.listening,
        )
        self._columns: list[tuple[int, int]] = []
        self._last: np.ndarray | None = None
        self._lock = threading.Lock()
        self._hurry = threading.Event()
        self._closed = False
        self._commands: list[tuple[float, np.ndarray, int]] = []  # (sent at, command, state; -1: an ease)
        self._send_ms: collections.deque[float] = collections.deque(maxlen=100_000)
        self._counts = collections.Counter[str]()
        self._not_following_run = 0
        self._events: list[dict[str, Any]] = []
        self._eased = False
        self._neutral_error: dict[str, float] | None = None

    # ---------------------------------------------------------------- open
    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        self._columns = [(spec.index[n], JOINTS[n]) for n in spec.names if n in JOINTS]
        if not self._columns:
            raise UserError(f"backend reachy_mini: profile {spec.name} has none of the joints {', '.join(JOINTS)}")
        self.link = (SdkLink if self.options.client == "sdk" else DaemonLink)(self.options.host, self.options.port)
        try:
            self.link.open()
        except (OSError, TimeoutError) as exc:
            self.link = None
            raise UserError(
                f"backend reachy_mini: no daemon at {self.options.host}:{self.options.port} ({exc}); start it "
                "(README, 'Reachy Mini') or give -B reachy_mini.host=... / reachy_mini.port=..."
            ) from None
        start = self.link.latest()
        assert start is not None
        if not self.limits.within(start, tolerance=1e-3):
            self._event(
                "outside_limits_at_open", "the head was outside the limits (asleep?); eased in from the nearest pose"
            )
        self._last = self.limits.clamp(start)
        self._ease(rp.neutral(), self.options.ease_s, "open")

    # ---------------------------------------------------------------- frames
    def command_of(self, frame: TargetFrame, dt: float) -> np.ndarray:
        """The limited command for one frame: the profile's joints plus the conversation's part."""
        command = rp.neutral()
        values = np.asarray(frame.values, dtype=float)
        for col, field in self._columns:
            command[field] = values[col]
        if frame.takes:
            part = self.expression.step(frame.motion, dt)
            command[rp.BODY] += part.body
            command[rp.HEAD_ANGLES] += part.head
            command[rp.ANT_R] -= part.antennas  # the right antenna's outward side is negative
            command[rp.ANT_L] += part.antennas
        command[rp.YAW] += command[rp.BODY]  # the daemon's head yaw is in the world frame
        clamped = self.limits.clamp(command)
        if not np.allclose(clamped, command, atol=1e-9):
            self._counts["clamped_frames"] += 1
        return clamped

    def send(self, frame: TargetFrame) -> float | None:
        if self._closed or self.link is None:
            return None
        dt = 1.0 / (self.session.fps if self.session else TICK_HZ)
        command = self.command_of(frame, dt)
        state = int(frame.motion.state) if frame.takes else int(ConversationState.SILENCE)
        with self._lock:
            sent = self._send(command, state)
        self._counts["frames"] += 1
        self._check_following()
        return sent

    def _send(self, command: np.ndarray, state: int) -> float | None:
        """One set_full_target (the only place commands leave); every command is checked first."""
        assert self.link is not None
        if not self.limits.within(command):
            self._counts["commands_outside_limits"] += 1  # cannot happen after clamp; counted to prove it
            command = self.limits.clamp(command)
        t0 = time.perf_counter()
        sent = self.link.send_target(
            rp.head_matrix(command), float(command[rp.BODY]), (float(command[rp.ANT_R]), float(command[rp.ANT_L]))
        )
        if sent is not None:
            self._send_ms.append((time.perf_counter() - t0) * 1e3)
            self._commands.append((sent, command, state))
        self._last = command
        return sent

    def _check_following(self) -> None:
        """Count read-backs far from every recent command: the daemon dropped the pose (IK) or a
        move of its own runs; a run of them marks the backend degraded."""
        assert self.link is not None
        now = self.link.last_state_at
        back = self.link.latest()
        recent = [c for t, c, _ in self._commands[-int(FOLLOW_WINDOW_S * TICK_HZ) - 2 :] if t >= now - FOLLOW_WINDOW_S]
        if back is None or not recent:
            return
        angles = np.stack(recent)[:, rp.HEAD_ANGLES] - back[rp.HEAD_ANGLES]
        position = np.stack(recent)[:, rp.X : rp.Z + 1] - back[rp.X : rp.Z + 1]
        near = (np.abs(angles).max(axis=1) <= FOLLOW_TOLERANCE[0]) & (
            np.abs(position).max(axis=1) <= FOLLOW_TOLERANCE[1]
        )
        if near.any():
            self._not_following_run = 0
            return
        self._counts["readbacks_off_command"] += 1
        self._not_following_run += 1
        if self._not_following_run == NOT_FOLLOWING_FRAMES:
            self._event(
                "not_following", "the head stayed away from its commands (pose dropped by the IK, or a daemon move)"
            )

    # ---------------------------------------------------------------- easing
    def _ease(self, goal: np.ndarray, seconds: float, why: str) -> None:
        """Stream a minimum-jerk ease from the last command to ``goal`` at 30 Hz (blocking)."""
        assert self._last is not None
        start, goal = self._last.copy(), self.limits.clamp(goal)
        t0 = time.monotonic()
        period = 1.0 / TICK_HZ
        steps = max(1, math.ceil(seconds * TICK_HZ))
        for k in range(1, steps + 1):
            if self._hurry.is_set():
                return
            with self._lock:
                self._send(rp.min_jerk(start, goal, k / steps), EASE)
            self._counts[f"{why}_ease_commands"] += 1
            self._hurry.wait(max(0.0, t0 + k * period - time.monotonic()))

    def _at_neutral(self) -> bool:
        """Wait up to ``NEUTRAL_SETTLE_S`` for the read-back to reach neutral; keep the error."""
        assert self.link is not None
        goal = rp.neutral()
        deadline = time.monotonic() + NEUTRAL_SETTLE_S
        while True:
            back = self.link.latest()
            if back is not None:
                err = np.abs(back - goal)
                self._neutral_error = {
                    "head_deg": round(math.degrees(float(err[rp.HEAD_ANGLES].max())), 3),
                    "position_mm": round(1e3 * float(err[rp.X : rp.Z + 1].max()), 3),
                    "body_deg": round(math.degrees(float(err[rp.BODY])), 3),
                    "antennas_rad": round(float(err[rp.ANTENNAS].max()), 4),
                }
                ok = (
                    err[rp.HEAD_ANGLES].max() <= NEUTRAL_TOLERANCE[0]
                    and err[rp.X : rp.Z + 1].max() <= NEUTRAL_TOLERANCE[1]
                    and max(err[rp.BODY], err[rp.ANTENNAS].max()) <= NEUTRAL_TOLERANCE[2]
                )
                if ok:
                    return True
            if time.monotonic() >= deadline or self._hurry.wait(0.02):
                return False

    # ---------------------------------------------------------------- close
    def hurry(self) -> None:
        """Stop easing: the head stays where it is (the daemon holds it)."""
        self._hurry.set()

    def close(self) -> None:
        """Ease to neutral and check the read-back got there. Never raises."""
        if self._closed:
            return
        self._closed = True
        if self.link is None:
            return
        try:
            if self._last is not None and self.link.connected.is_set():
                self._ease(rp.neutral(), self.options.ease_s, "close")
                self._eased = not self._hurry.is_set() and self._at_neutral()
                if not self._eased:
                    self._event("not_at_neutral", f"read-back off neutral after easing: {self._neutral_error}")
            elif self._last is not None:
                self._event("not_at_neutral", "no daemon to ease to neutral with")
        except Exception as exc:  # noqa: BLE001 - a fault here must not hide the run's result
            self._event("close_error", repr(exc))
        finally:
            self.link.close()

    # ---------------------------------------------------------------- reporting
    def _event(self, kind: str, detail: str) -> None:
        self._counts[f"event_{kind}"] += 1
        if len(self._events) < 100:
            self._events.append({"t": round(time.monotonic(), 3), "event": kind, "detail": detail})

    def _problems(self) -> list[str]:
        link = self.link
        if link is None:
            return []
        problems = []
        if not self._closed and not link.connected.is_set():
            problems.append(f"disconnected from the daemon at {link.uri}")
        elif not self._closed and time.monotonic() - link.last_state_at > STALE_S:
            problems.append(f"no state from the daemon for {time.monotonic() - link.last_state_at:.1f} s")
        if self._not_following_run >= NOT_FOLLOWING_FRAMES:
            problems.append("the head is not following its commands (unreachable pose or a daemon move)")
        backend_status = link.status.get("backend_status") or {}
        if link.status.get("error") or backend_status.get("error"):
            problems.append(f"daemon error: {link.status.get('error') or backend_status.get('error')}")
        mode = backend_status.get("motor_control_mode")
        if mode not in (None, "enabled"):
            problems.append(f"motors {mode}")
        return problems

    def health(self) -> dict[str, Any]:
        problems = self._problems()
        link = self.link
        return {
            "status": "degraded" if problems else "ok",
            **({"reason": "; ".join(problems)} if problems else {}),
            "daemon": link.uri if link else None,
            "frames": self._counts["frames"],
            "disconnects": link.disconnects if link else 0,
        }

    def report(self) -> dict[str, Any]:
        link = self.link
        events = [e["event"] for e in self._events]
        if link is not None and link.disconnects:
            events.append("disconnected")
        status = "ok" if not events and self._eased else "degraded"
        sent = [(t, c) for t, c, _ in self._commands]
        run = [t for t, _, s in self._commands if s != EASE]
        span = run[-1] - run[0] if len(run) > 1 else 0.0
        follow = follow_figures(sent, list(link.readback) if link else [])
        return {
            "status": status,
            **({"reason": ", ".join(sorted(set(events))) or "not eased to neutral"} if status != "ok" else {}),
            "daemon": link.uri if link else None,
            "client": self.options.client,
            "frames": self._counts["frames"],
            "commands": len(sent),
            "commands_per_s": round((len(run) - 1) / span, 2) if span > 0 else None,  # the frames' only
            "commands_outside_limits": self._counts["commands_outside_limits"],
            "clamped_frames": self._counts["clamped_frames"],
            "ease_commands": {"open": self._counts["open_ease_commands"], "close": self._counts["close_ease_commands"]},
            "unsent": link.unsent if link else 0,
            "disconnects": link.disconnects if link else 0,
            "reconnects": link.reconnects if link else 0,
            "readbacks_off_command": self._counts["readbacks_off_command"],
            "set_target_ms": latency_summary(self._send_ms),
            "follow": follow,
            "liveliness": self._liveliness(follow.get("lag_ms")),
            "eased_to_neutral": self._eased,
            "neutral_error": self._neutral_error,
            "events": list(self._events),
        }

    def _liveliness(self, lag_ms: float | None) -> dict[str, dict[str, dict[str, float]]]:
        """How lively the head and antennas are in each conversation state, over the run's frames
        (not the eases): as commanded (world frame: the body's turn is in the head's yaw), and as
        the daemon read them back, each read-back counted in the state of the command in force
        ``lag_ms`` before it arrived."""
        names = {int(state): state.name.lower() for state in ConversationState}
        run = [c for c in self._commands if c[2] != EASE]
        if len(run) < 2:
            return {}
        dt = 1.0 / (self.session.fps if self.session else TICK_HZ)  # frame steps: no wall-clock jitter
        commanded = speeds_by_state(
            dt * np.arange(len(run)), np.stack([c[1] for c in run]), np.array([c[2] for c in run]), names
        )
        back = list(self.link.readback) if self.link else []
        if len(back) < 2:
            return {"commanded": commanded, "readback": {}}
        sent = np.array([t for t, _, _ in self._commands])
        sent_states = np.array([s for _, _, s in self._commands])
        times = np.array([t for t, _ in back])

        def state_at(t: np.ndarray) -> np.ndarray:
            which = np.searchsorted(sent, t, side="right") - 1
            return np.where(which >= 0, sent_states[np.maximum(which, 0)], EASE)

        # Near a change of state the read-back still carries the last state's motion (the stream's
        # jitter blurs the lag): those read-backs are left out.
        at = times - 1e-3 * (lag_ms or 0.0)
        states = state_at(at)
        for shift in (-READBACK_GUARD_S, READBACK_GUARD_S):
            states = np.where(state_at(at + shift) == states, states, EASE)
        readback = speeds_by_state(times, np.stack([v for _, v in back]), states, names)
        return {"commanded": commanded, "readback": readback}
