"""What a servo head tells the run: events as they happen, a live ``health()`` and the ``report()``
after close (the state they read belongs to ``servo_base.ServoBackend``)."""

from __future__ import annotations

import collections
import logging
import time
from typing import Any

from convodrive.backends.servo.bus_hooks import BusHooks
from convodrive.backends.servo.safety import SafetyGuard, Watchdog
from convodrive.backends.servo.servo_options import ServoOptions
from convodrive.plumbing.stats import percentiles

log = logging.getLogger(__name__)
_LOG_REPEAT_S = 5.0
MAX_EVENTS = 100


class ServoReporting(BusHooks):
    """Events, faults, ``health()`` and ``report()`` of a servo backend, from its state and its bus's
    ``_hw_health``/``_hw_bus`` (``ServoBackend`` holds the state)."""

    name: str
    options: ServoOptions
    names: list[str]
    guard: SafetyGuard | None
    watchdog: Watchdog
    _closed: bool
    _eased: bool
    _events: list[dict[str, Any]]
    _faults: set[str]
    _last_logged: dict[tuple[str, str | None], float]
    _counts: collections.Counter[str]
    _write_ms: collections.deque[float]
    _read_ms: collections.deque[float]
    _torque_off: dict[str, bool]
    _neutral_error: dict[str, float | None]

    def _event(self, kind: str, joint: str | None, detail: str, fault: bool = True) -> None:
        # Logged as it happens; the same event again within a few seconds (a servo refusing every
        # frame) only at debug level, the report counts them all.
        now = time.monotonic()
        repeat = now - self._last_logged.get((kind, joint), -1e9) < _LOG_REPEAT_S
        if not repeat:
            self._last_logged[(kind, joint)] = now
        level = logging.DEBUG if repeat else logging.WARNING if fault else logging.INFO
        log.log(level, "%s: %s%s: %s", self.name, kind, f" {joint}" if joint else "", detail)
        if fault:
            self._faults.add(f"{kind}:{joint}" if joint else kind)
        if len(self._events) < MAX_EVENTS:
            self._events.append({"t": round(time.monotonic(), 3), "event": kind, "joint": joint, "detail": detail})

    def _add_fault(self, kind: str, joint: str | None, detail: str) -> None:
        """A fault counted by the driver rather than seen as one event: kept for the report, and
        logged the first time it is seen."""
        key = f"{kind}:{joint}" if joint else kind
        if key not in self._faults:
            self._faults.add(key)
            log.warning("%s: %s%s: %s", self.name, kind, f" {joint}" if joint else "", detail)

    def health(self) -> dict[str, Any]:
        """Live snapshot: ``degraded`` while anything is wrong now; ``faults`` lists all seen so far."""
        servos = self._hw_health()
        current = [f"{s['status']}:{n}" for n, s in servos.items() if s.get("status", "ok") != "ok"]
        for n, s in servos.items():
            current += [f"{f}:{n}" for f in s.get("faults", [])]
        if self.guard is not None and not self._closed and not self._hw_connected():
            current.append("port_lost")
        if self._counts["frames_refused"]:
            current.append("frames_refused")
        current = sorted(set(current))
        return {
            "status": "degraded" if current else "ok",
            **({"reason": fault_text(current)} if current else {}),
            "port": self.options.port,
            "active_faults": current,
            "faults": sorted(self._faults),
            "frames": self._counts["frames"],
            "frames_refused": self._counts["frames_refused"],
            "watchdog_trips": self.watchdog.tripped,
            "servos": servos,
            "torque_off": (bool(self.names) and all(self._torque_off.get(n, False) for n in self.names))
            if self._closed
            else None,
        }

    def report(self) -> dict[str, Any]:
        """After close: ``ok``, ``degraded`` (faults seen, head safe) or ``failed`` (torque off unconfirmed)."""
        torque_off = bool(self.names) and all(self._torque_off.get(n, False) for n in self.names)
        faults = sorted(self._faults)
        status = "failed" if not torque_off else ("degraded" if faults else "ok")
        if not torque_off:
            unconfirmed = [n for n in self.names if not self._torque_off.get(n, False)] or ["every servo"]
            reason: str | None = f"torque off not confirmed for {', '.join(unconfirmed)}"
            if faults:
                reason += f"; {fault_text(faults)}"
        else:
            reason = fault_text(faults) if faults else None
        return {
            "status": status,
            **({"reason": reason} if reason else {}),
            "faults": faults,
            "port": self.options.port,
            "frames": self._counts["frames"],
            "frames_refused": self._counts["frames_refused"],
            "frames_unsent": self._counts["frames_unsent"],
            "goal_writes": self._counts["goal_writes"],
            "watchdog_trips": self.watchdog.tripped,
            "eased_to_neutral": self._eased,
            "neutral_error_raw": dict(self._neutral_error),
            "torque_off": torque_off,
            "torque_off_per_joint": dict(self._torque_off),
            "bus_ms": {"write": latency_summary(self._write_ms), "health_read": latency_summary(self._read_ms)},
            "bus": self._hw_bus(),
            "clamped_frames": self.guard.clamped if self.guard else 0,
            "servos": self._hw_health(),
            "events": list(self._events),
        }


def fault_text(faults: list[str], limit: int = 6) -> str:
    """``overload:jaw, servo_lost:eye_tilt`` as ``overload (jaw), servo lost (eye_tilt)``, on one line."""
    items = []
    for fault in faults[:limit]:
        kind, _, where = fault.partition(":")
        items.append(kind.replace("_", " ") + (f" ({where})" if where else ""))
    more = len(faults) - limit
    return ", ".join(items) + (f" and {more} more" if more > 0 else "")


def latency_summary(values: collections.deque[float]) -> dict[str, float | None]:
    """p50 and p99 of a bus's times (ms) and how many there were, for the report."""
    p = percentiles(values)
    return {"p50": p["p50"] if p else None, "p99": p["p99"] if p else None, "n": len(values)}
