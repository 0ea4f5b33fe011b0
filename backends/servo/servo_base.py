"""What every servo-head backend shares: the safety loop around a bus.

``send`` checks and limits a frame (``safety.SafetyGuard``), converts it to raw units and hands it
to the subclass's ``_write``. A supervisor thread eases to neutral when frames stop for
``watchdog_s``, polls health at ``read_rate`` and reconnects a lost port with back-off; its bus
reads take the bus one exchange at a time, so frames go out between them. ``close`` (called by the
scheduler on every exit path, signals included) eases to neutral over ``ease_s`` (never longer
than ``MAX_EASE_S``), reads the servos back to check they reached neutral, and switches them off;
``hurry`` (a second Ctrl-C) cuts the easing short and switches them off at once. Hardware faults
never raise out of ``send`` or ``close``: they are events, named in ``health()`` and ``report()``,
and mark the backend degraded.

A subclass implements the ``_hw_*`` hooks of ``bus_hooks.BusHooks`` for its bus; everything here
is bus-agnostic. Events, ``health()`` and ``report()`` are ``servo_report.ServoReporting``.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, Session
from convodrive.backends.servo.safety import Ease, Refused, SafetyGuard, Watchdog, sub_spec
from convodrive.backends.servo.serial_port import PortLost
from convodrive.backends.servo.servo_options import ServoOptions
from convodrive.backends.servo.servo_report import ServoReporting
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import UserError, error_line

TICK_HZ = 30.0
MAX_EASE_S = 10.0
"""No ease to neutral takes longer than this, whatever ``ease_s`` says: closing must end (the option's
own range stops there too; this holds whoever made the options)."""
EASE_SETTLE_S = 3.0
"""Time beyond the ease for velocity and acceleration limits to bring the command to neutral."""
NEUTRAL_SETTLE_S = 0.5
"""How long the servos get to arrive at the neutral goal before their positions are checked."""


class ServoBackend(ServoReporting, Backend):
    Options = ServoOptions
    options: ServoOptions
    neutral_tolerance_raw: float = 20.0
    """How far (raw units) a servo may read from its neutral goal after easing and count as there."""

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.guard: SafetyGuard | None = None
        self.names: list[str] = []
        self.columns = np.zeros(0, dtype=int)
        self.watchdog = Watchdog(self.options.watchdog_s)
        self.ease_s = self.options.ease_s
        self.read_period = 1.0 / self.options.read_rate
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._frame_written = threading.Event()
        """Set when a frame's goals went out; the supervisor's health reads follow it."""
        self._frame_written_at = -math.inf
        self._ease: Ease | None = None
        self._last_frame_time: float | None = None
        self._port_lost_at: float | None = None
        self._reconnect_after = 0.0
        self._events: list[dict[str, Any]] = []
        self._faults: set[str] = set()
        self._last_logged: dict[tuple[str, str | None], float] = {}
        self._counts: collections.Counter[str] = collections.Counter()
        self._write_ms: collections.deque[float] = collections.deque(maxlen=10_000)
        self._read_ms: collections.deque[float] = collections.deque(maxlen=10_000)
        self._torque_off: dict[str, bool] = {}
        self._eased = False
        self._neutral_error: dict[str, float | None] = {}
        self._hurry = threading.Event()
        self._closed = False
        self._opened = False
        """Set once ``_hw_open`` returned: before that no servo was switched on, so ``close``
        has nothing to ease or switch off (a port that would not open is one error, not two)."""

    # ---------------------------------------------------------------- open
    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        if not self.options.port:
            raise UserError(
                f"backends.{self.name}.port: no serial port given (run `convodrive emulate "
                f"{self.name}` for an emulated one and use the path it prints)"
            )
        raw_map = self._hw_calibration(spec)
        self.columns = np.array([spec.index[n] for n in self.names])
        try:
            self.guard = SafetyGuard(sub_spec(spec, self.names), raw_map)
        except ValueError as exc:
            raise UserError(f"backends.{self.name}.joints: {exc}") from None
        self._hw_open()
        self._opened = True
        present = self._hw_present()
        neutral_raw = raw_map.to_raw(self.guard.neutral).astype(float)
        present = np.where(np.isfinite(present), present, neutral_raw)
        self.guard.reset(raw_map.to_joint(present))
        if np.max(np.abs(present - neutral_raw)) > 2:
            self._run_ease(self.ease_s)  # start from neutral, smoothly, wherever the head was
        self.watchdog.feed()
        self._thread = threading.Thread(target=self._supervise, name=f"{self.name}-supervisor", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- frames
    def send(self, frame: TargetFrame) -> float | None:
        """Returns when the goals went out on the bus (None if they did not)."""
        if self._closed or self.guard is None:
            return None
        with self._lock:
            try:
                values = self.guard.check(np.asarray(frame.values, dtype=float)[self.columns])
            except Refused as exc:  # not fed to the watchdog: a stream of bad frames ends at neutral
                self._counts["frames_refused"] += 1  # a fault: the head did not do what the run asked
                self._event("frame_refused", None, str(exc))
                return None
            self.watchdog.feed()
            self._ease = None
            fps = self.session.fps if self.session else TICK_HZ
            prev, self._last_frame_time = self._last_frame_time, frame.time
            step = 1.0 / fps if prev is None else min(max(frame.time - prev, 0.25 / fps), 0.1)
            written = self._command(self.guard.limit(values, step))
            self._counts["frames"] += 1
        if written is not None:
            self._frame_written_at = written
            self._frame_written.set()
        return written

    def _command(self, command: np.ndarray) -> float | None:
        """Write one limited command in raw units, timing the bus; returns when it was written."""
        assert self.guard is not None
        if not self._hw_connected():
            self._counts["frames_unsent"] += 1
            return None
        raw = self.guard.to_raw(command)
        t0 = time.perf_counter()
        written = None
        try:
            self._hw_write(raw)
            written = time.monotonic()
            self._counts["goal_writes"] += 1
        except PortLost as exc:
            self._port_lost(str(exc))
        self._write_ms.append((time.perf_counter() - t0) * 1e3)
        return written

    def _run_ease(self, seconds: float) -> bool:
        """Blocking ease from the last command to neutral at 30 Hz (open and close); True when the
        command reached neutral. Ends early on ``hurry`` or a lost port, and always within
        ``MAX_EASE_S + EASE_SETTLE_S``."""
        assert self.guard is not None and self.guard.last is not None
        seconds = min(max(seconds, 0.0), MAX_EASE_S) if math.isfinite(seconds) else MAX_EASE_S
        ease = Ease(self.guard.last.copy(), self.guard.neutral.copy(), seconds)
        period = 1.0 / TICK_HZ
        deadline = time.monotonic() + seconds + EASE_SETTLE_S  # velocity limits may stretch it
        while not self._hurry.is_set() and time.monotonic() < deadline and self._hw_connected():
            now = time.monotonic()
            self._command(self.guard.limit(ease.at(now), period))
            if ease.done(now) and np.allclose(self.guard.last, self.guard.neutral, atol=1e-9):
                return True
            self._hurry.wait(max(0.0, period - (time.monotonic() - now)))
        return False

    def _check_neutral(self) -> bool:
        """Read the servos back: True when each is within ``neutral_tolerance_raw`` of neutral.

        The ease only says what was commanded; a servo that is overloaded, unpowered or blocked
        stays where it is. They get ``NEUTRAL_SETTLE_S`` to arrive."""
        assert self.guard is not None
        goal = self.guard.to_raw(self.guard.neutral).astype(float)
        deadline = time.monotonic() + NEUTRAL_SETTLE_S
        while True:
            error = np.abs(self._hw_present() - goal)
            arrived = np.isfinite(error) & (error <= self.neutral_tolerance_raw)
            if arrived.all() or time.monotonic() >= deadline or self._hurry.wait(1.0 / TICK_HZ):
                break
        self._neutral_error = {n: (round(float(e), 1) if np.isfinite(e) else None) for n, e in zip(self.names, error)}
        for name, e in self._neutral_error.items():
            if e is None:
                self._event("not_at_neutral", name, "no position reading after easing")
            elif e > self.neutral_tolerance_raw:
                self._event("not_at_neutral", name, f"{e:g} raw units from neutral after easing")
        return bool(arrived.all())

    def hurry(self) -> None:
        """Stop easing: ``close`` switches torque off at once, wherever the servos are."""
        self._hurry.set()

    # ---------------------------------------------------------------- supervisor
    def _supervise(self) -> None:
        next_read = time.monotonic()
        while not self._stop.wait(1.0 / TICK_HZ):
            now = time.monotonic()
            with self._lock:
                if not self._hw_connected():
                    self._try_reconnect(now)
                    continue
                self._watch(now)
            if now < next_read:
                continue
            next_read = now + self.read_period
            self._after_next_frame(now)
            # Outside the lock: a health read (with its retries on a noisy bus) must not hold up
            # the frames, which the bus interleaves between its exchanges.
            t0 = time.perf_counter()
            try:
                self._hw_poll()
            except PortLost as exc:
                with self._lock:
                    self._port_lost(str(exc))
                continue
            except Exception as exc:  # a driver's surprise must not end the watchdog with this thread
                self._event("poll_error", None, error_line(exc))
                continue
            self._read_ms.append((time.perf_counter() - t0) * 1e3)

    def _after_next_frame(self, now: float) -> None:
        """While frames flow, wait for the next frame's goals before a health read.

        The bus carries one exchange at a time, so a frame that comes during a read waits for the
        read's replies (a few ms, more from a slow or retried servo). Read at once after a frame,
        the bus is free again as early as it can be. On a real bus this is what matters: at
        57600 baud (the Dynamixel X series' factory rate) a health read of seven servos is some
        200 bytes, 35 ms of wire time, longer than a frame; at 1 Mbaud it is 2 ms. (The emulator's
        pseudo-terminal has no wire time, so ``bench/bench_live.py`` cannot show the difference.)"""
        period = 1.0 / (self.session.fps if self.session else TICK_HZ)
        if now - self._frame_written_at > 2 * period:
            return  # no frames (a file's end, a watchdog's ease): read on the timer
        self._frame_written.clear()
        self._frame_written.wait(2 * period)

    def _watch(self, now: float) -> None:
        guard = self.guard
        assert guard is not None
        if (
            self._ease is None
            and self.watchdog.expired(now)
            and guard.last is not None
            and not np.allclose(guard.last, guard.neutral, atol=1e-9)
        ):
            self.watchdog.tripped += 1
            self._event("watchdog", None, f"no frame for {self.watchdog.timeout:.2f} s, easing to neutral", fault=False)
            self._ease = Ease(guard.last.copy(), guard.neutral.copy(), self.ease_s, now)
        if self._ease is not None:
            self._command(guard.limit(self._ease.at(now), 1.0 / TICK_HZ))
            if self._ease.done(now) and np.allclose(guard.last, guard.neutral, atol=1e-9):
                self._ease = None
                self._last_frame_time = None

    def _port_lost(self, detail: str) -> None:
        if self._port_lost_at is None:
            self._port_lost_at = time.monotonic()
            self._reconnect_after = self._port_lost_at + 0.2
            self._event("port_lost", None, detail)

    def _try_reconnect(self, now: float) -> None:
        if now < self._reconnect_after:
            return
        lost_for = now - (self._port_lost_at or now)
        self._reconnect_after = now + min(2.0, 0.2 + lost_for / 2)  # back off while it stays gone
        if self._hw_reconnect():
            self._port_lost_at = None
            self._event("port_recovered", None, f"after {lost_for:.2f} s", fault=False)

    # ---------------------------------------------------------------- close
    def close(self) -> None:
        """Ease to neutral, torque off, close the port. Never raises: it runs on every exit path."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        with self._lock:
            try:
                if self._opened:
                    if not self._hw_connected():
                        self._reconnect_after = 0.0
                        self._try_reconnect(time.monotonic())
                    if self._hw_connected() and self.guard.last is not None and not self._hurry.is_set():
                        self._run_ease(self.ease_s)
                        self._eased = self._hw_connected() and not self._hurry.is_set() and self._check_neutral()
                    if self._hurry.is_set():
                        self._event("hurried", None, "stopped at once: torque cut without easing to neutral")
                    self._torque_off = self._hw_off() if self._hw_connected() else {n: False for n in self.names}
                    off = [n for n, ok in self._torque_off.items() if not ok]
                    if off:
                        self._event("torque_off_failed", ",".join(off), "could not confirm torque off")
            except Exception as exc:  # noqa: BLE001 - a fault here must not hide the run's result
                self._event("close_error", None, repr(exc))
            finally:
                self._hw_close()
