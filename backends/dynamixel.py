"""Backend ``dynamixel``: a servo head on Dynamixel Protocol 2.0 servos.

``send`` limits the frame (``safety.SafetyGuard``), converts it to ticks with the per-servo
calibration and writes every goal in one SYNC_WRITE. A supervisor thread reads position,
temperature, voltage and hardware errors at ``read_rate``, re-initialises servos that come back,
reconnects a lost port, and eases the head to neutral when frames stop for ``watchdog_s``.
``close`` eases to neutral over ``ease_s`` and switches torque off. Hardware faults never raise
out of ``send``: they mark the backend degraded and are named in ``health()`` and ``report()``.

Options (``backends.dynamixel`` in the robot profile)::

    port: /dev/ttyUSB0       baudrate: 1000000    protocol: 2     model: xl330
    read_rate: 10            retries: 2           latency_ms: 16  watchdog_s: 0.5   ease_s: 1.0
    profile_velocity: 0      profile_acceleration: 0   (raw units, defaults for every joint)
    joints:
      neck_pan: {id: 1, zero_tick: 2048, direction: 1, min_tick: 1136, max_tick: 2960,
                 profile_velocity: 0, profile_acceleration: 0, ticks_per_unit: null, model: null}

``ticks_per_unit`` is needed only for joints not in radians (eyelids in 0..1); joints missing
from ``joints`` are not driven; without ``joints`` the spec's joints take ids 1..N.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from typing import Any

import numpy as np

from convodrive.backends import dynamixel_table as dt
from convodrive.backends.base import Backend, Session
from convodrive.backends.dynamixel_bus import DynamixelBus, Motor, PortLost
from convodrive.backends.safety import Ease, RawMap, Refused, SafetyGuard, Watchdog
from convodrive.errors import UserError
from convodrive.targets import TargetFrame, TargetSpec

MAX_EVENTS = 100


class DynamixelBackend(Backend):
    name = "dynamixel"
    description = "Dynamixel Protocol 2.0 servo head (XL330, XM430, XL-320, ...) over dynamixel-sdk"
    realtime = True
    default_profile = "servo_head"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        super().__init__(options)
        self.bus: DynamixelBus | None = None
        self.guard: SafetyGuard | None = None
        self.names: list[str] = []
        self.columns = np.zeros(0, dtype=int)
        self.watchdog = Watchdog(float(self.options.get("watchdog_s", 0.5)))
        self.ease_s = float(self.options.get("ease_s", 1.0))
        self.read_period = 1.0 / max(0.1, float(self.options.get("read_rate", 10.0)))
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ease: Ease | None = None
        self._last_frame_time: float | None = None
        self._port_lost_at: float | None = None
        self._reconnect_after = 0.0
        self._events: list[dict[str, Any]] = []
        self._faults: set[str] = set()
        self._counts = collections.Counter()
        self._write_ms: collections.deque[float] = collections.deque(maxlen=10_000)
        self._read_ms: collections.deque[float] = collections.deque(maxlen=10_000)
        self._torque_off: dict[str, bool] = {}
        self._eased = False
        self._closed = False
        self._profile: dict[str, tuple[int, int]] = {}
        self._limits: dict[str, tuple[int, int]] = {}

    # ================================================================ open
    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        opts = self.options
        if int(opts.get("protocol", 2)) != 2:
            raise UserError("backends.dynamixel.protocol: only Protocol 2.0 is supported")
        port = opts.get("port")
        if not port:
            raise UserError("backends.dynamixel.port: no serial port given (e.g. /dev/ttyUSB0, or "
                            "run `convodrive emulate dynamixel` and use the path it prints)")
        motors, raw_map = self._calibration(spec)
        sub = _sub_spec(spec, self.names)
        try:
            self.guard = SafetyGuard(sub, raw_map)
        except ValueError as exc:
            raise UserError(f"backends.dynamixel.joints: {exc}") from None
        self.bus = DynamixelBus(str(port), motors, baudrate=int(opts.get("baudrate", 1_000_000)),
                                retries=int(opts.get("retries", 2)), latency_ms=float(opts.get("latency_ms", 16.0)))
        self.bus.connect()
        answering = [m.name for m in motors if self._check_model(m)]
        if not answering:
            self.bus.disconnect()
            ids = ", ".join(str(m.id) for m in motors)
            raise UserError(f"{port}: no servo answers (ids {ids} at {self.bus.baudrate} baud)")
        for name in set(self.names) - set(answering):
            self._event("servo_lost", name, "no answer at open")
        self._setup(answering)
        current = self._present_joint_values()
        self.guard.reset(current)
        if np.max(np.abs(current - self.guard.neutral) * np.abs(raw_map.scale)) > 2:
            self._run_ease(self.ease_s)  # start from neutral, smoothly, wherever the head was
        self.watchdog.feed()
        self._thread = threading.Thread(target=self._supervise, name="dynamixel-supervisor", daemon=True)
        self._thread.start()

    def _calibration(self, spec: TargetSpec) -> tuple[list[Motor], RawMap]:
        opts = self.options
        default_model = dt.model(str(opts.get("model", "xl330")))
        joints = opts.get("joints")
        if joints is None:
            joints = {name: {"id": i + 1} for i, name in enumerate(spec.names)}
        if not isinstance(joints, dict):
            raise UserError("backends.dynamixel.joints: expected a mapping of joint name to servo settings")
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(f"backends.dynamixel.joints: {', '.join(unknown)} not in {spec.name} "
                            f"(joints: {', '.join(spec.names)})")
        motors, zero, scale, low, high = [], [], [], [], []
        seen_ids: set[int] = set()
        for name in spec.names:
            if name not in joints:
                continue
            j = joints[name] or {}
            key = f"backends.dynamixel.joints.{name}"
            try:
                model = dt.model(str(j["model"])) if j.get("model") else default_model
                servo_id = int(j["id"])
                table = model.table
                direction = float(j.get("direction", 1))
                i = spec.index[name]
                per_unit = j.get("ticks_per_unit")
                if per_unit is None:
                    if spec.units[i] != "rad":
                        raise UserError(f"{key}: joint is in {spec.units[i]}, give ticks_per_unit")
                    per_unit = 1.0 / table.rad_per_tick
                s = math.copysign(float(per_unit), direction)
                z = float(j.get("zero_tick", table.center_tick))
                ends = sorted((z + s * spec.lower[i], z + s * spec.upper[i]))
                lo = int(j.get("min_tick", max(0, math.floor(ends[0]))))
                hi = int(j.get("max_tick", min(table.max_tick, math.ceil(ends[1]))))
                pv = int(j.get("profile_velocity", opts.get("profile_velocity", 0)))
                pa = int(j.get("profile_acceleration", opts.get("profile_acceleration", 0)))
            except (KeyError, TypeError, ValueError) as exc:
                raise UserError(f"{key}: bad servo settings ({exc})") from None
            if not 0 <= servo_id <= 252:
                raise UserError(f"{key}.id: {servo_id} is not a servo id (0..252)")
            if servo_id in seen_ids:
                raise UserError(f"{key}.id: servo id {servo_id} is used twice")
            if not 0 <= lo <= hi <= table.max_tick or direction not in (1, -1):
                raise UserError(f"{key}: need 0 <= min_tick <= max_tick <= {table.max_tick} and direction 1 or -1")
            seen_ids.add(servo_id)
            motors.append(Motor(name, servo_id, model))
            zero.append(z), scale.append(s), low.append(lo), high.append(hi)
            self._profile[name] = (pv, pa)
            self._limits[name] = (lo, hi)
        if not motors:
            raise UserError("backends.dynamixel.joints: no joint is mapped to a servo")
        self.names = [m.name for m in motors]
        self.columns = np.array([spec.index[n] for n in self.names])
        return motors, RawMap(np.array(zero), np.array(scale), np.array(low, float), np.array(high, float))

    def _check_model(self, motor: Motor) -> bool:
        found = self.bus.ping(motor.id) if self.bus else None
        if found is None:
            return False
        if found[0] != motor.model.number:
            self.bus.disconnect()
            raise UserError(f"backends.dynamixel.joints.{motor.name}: servo {motor.id} is "
                            f"{dt.model_name(found[0])}, the profile says {motor.model.name}")
        return True

    def _setup(self, names: list[str]) -> None:
        """Position limits (EEPROM, torque off), profile, goal = present, torque on."""
        bus = self.bus
        assert bus is not None
        for name in names:
            table = bus.motors[name].table
            lo_reg, hi_reg = (("Min_Position_Limit", "Max_Position_Limit") if table.has("Min_Position_Limit")
                              else ("CW_Angle_Limit", "CCW_Angle_Limit"))
            lo, hi = self._limits[name]
            if (bus.read(lo_reg, name), bus.read(hi_reg, name)) != (lo, hi):
                bus.write("Torque_Enable", name, 0)
                bus.write(lo_reg, name, lo)
                bus.write(hi_reg, name, hi)
            pv, pa = self._profile[name]
            bus.write("Profile_Velocity" if table.has("Profile_Velocity") else "Moving_Speed", name, pv)
            if table.has("Profile_Acceleration"):
                bus.write("Profile_Acceleration", name, pa)
            present = bus.read("Present_Position", name)
            if present is not None:
                bus.write("Goal_Position", name, int(np.clip(present, lo, hi)))
            if bus.write("Torque_Enable", name, 1):
                self._torque_off[name] = False

    def _present_joint_values(self) -> np.ndarray:
        assert self.bus is not None and self.guard is not None
        raw = self.guard.raw_map.to_raw(self.guard.neutral).astype(float)
        for i, name in enumerate(self.names):
            value = self.bus.read("Present_Position", name)
            if value is not None:
                raw[i] = value
        return self.guard.raw_map.to_joint(raw)

    # ================================================================ frames
    def send(self, frame: TargetFrame) -> None:
        if self._closed or self.guard is None:
            return
        self.watchdog.feed()
        with self._lock:
            self._ease = None
            try:
                values = self.guard.check(np.asarray(frame.values, dtype=float)[self.columns])
            except Refused as exc:
                self._counts["frames_refused"] += 1
                self._event("frame_refused", None, str(exc), fault=False)
                return
            fps = self.session.fps if self.session else 30.0
            prev, self._last_frame_time = self._last_frame_time, frame.time
            step = 1.0 / fps if prev is None else min(max(frame.time - prev, 0.25 / fps), 0.1)
            self._command(self.guard.limit(values, step))
            self._counts["frames"] += 1

    def _command(self, command: np.ndarray) -> None:
        """Write one limited command as goal ticks (a single SYNC_WRITE)."""
        assert self.guard is not None
        if self.bus is None or not self.bus.connected:
            self._counts["frames_unsent"] += 1
            return
        raw = self.guard.to_raw(command)
        t0 = time.perf_counter()
        try:
            self.bus.sync_write("Goal_Position", dict(zip(self.names, raw.tolist())))
            self._counts["goal_writes"] += 1
        except PortLost as exc:
            self._port_lost(str(exc))
        self._write_ms.append((time.perf_counter() - t0) * 1e3)

    def _run_ease(self, seconds: float) -> None:
        """Blocking ease from the last command to neutral at 30 Hz (open and close)."""
        assert self.guard is not None and self.guard.last is not None
        ease = Ease(self.guard.last.copy(), self.guard.neutral.copy(), seconds)
        period = 1.0 / 30.0
        deadline = time.monotonic() + seconds + 3.0  # velocity limits may stretch it; never hang
        while time.monotonic() < deadline:
            now = time.monotonic()
            self._command(self.guard.limit(ease.at(now), period))
            if ease.done(now) and np.allclose(self.guard.last, self.guard.neutral, atol=1e-9):
                return
            time.sleep(max(0.0, period - (time.monotonic() - now)))

    # ================================================================ supervisor
    def _supervise(self) -> None:
        period = 1.0 / 30.0
        next_read = time.monotonic()
        while not self._stop.wait(period):
            now = time.monotonic()
            with self._lock:
                if self.bus is not None and not self.bus.connected:
                    self._try_reconnect(now)
                    continue
                self._watch(now)
                if now >= next_read:
                    next_read = now + self.read_period
                    self._read_health()

    def _watch(self, now: float) -> None:
        assert self.guard is not None
        if self._ease is None and self.watchdog.expired(now) and self.guard.last is not None \
                and not np.allclose(self.guard.last, self.guard.neutral, atol=1e-9):
            self.watchdog.tripped += 1
            self._event("watchdog", None, f"no frame for {self.watchdog.timeout:.2f} s, easing to neutral", fault=False)
            self._ease = Ease(self.guard.last.copy(), self.guard.neutral.copy(), self.ease_s, now)
        if self._ease is not None:
            self._command(self.guard.limit(self._ease.at(now), 1.0 / 30.0))
            if self._ease.done(now) and np.allclose(self.guard.last, self.guard.neutral, atol=1e-9):
                self._ease = None
                self._last_frame_time = None

    def _read_health(self) -> None:
        bus = self.bus
        assert bus is not None
        lost_before = {n for n in self.names if bus.health[n].lost}
        t0 = time.perf_counter()
        try:
            data = bus.sync_read(["Present_Position", "Present_Input_Voltage", "Present_Temperature"])
            for name in bus.take_alerts():
                status = bus.read("Hardware_Error_Status", name)
                if status:
                    new = set(bus.motors[name].table.decode_errors(status)) - bus.health[name].faults_seen
                    bus.note_hardware_error(name, status)
                    for fault in sorted(new):
                        self._event(fault, name, f"hardware error status 0x{status:02x}")
        except PortLost as exc:
            self._port_lost(str(exc))
            return
        self._read_ms.append((time.perf_counter() - t0) * 1e3)
        for name, regs in data.items():
            h = bus.health[name]
            h.position, h.temperature = regs["Present_Position"], regs["Present_Temperature"]
            h.voltage = regs["Present_Input_Voltage"] / 10.0
        for name in self.names:
            h = bus.health[name]
            if h.lost and name not in lost_before:
                self._event("servo_lost", name, f"no status packet after {bus.retries} retries")
            if h.timeouts:
                self._faults.add(f"lost_replies:{name}")
            if h.corrupt:
                self._faults.add(f"bad_crc:{name}")
        recovered = sorted(lost_before & set(data))
        if recovered:
            self._event("servo_recovered", ",".join(recovered), "answering again; re-initialised", fault=False)
            self._setup(recovered)

    def _port_lost(self, detail: str) -> None:
        if self._port_lost_at is None:
            self._port_lost_at = time.monotonic()
            self._reconnect_after = time.monotonic() + 0.2
            self._event("port_lost", None, detail)

    def _try_reconnect(self, now: float) -> None:
        if now < self._reconnect_after or self.bus is None:
            return
        lost_for = now - (self._port_lost_at or now)
        self._reconnect_after = now + min(2.0, 0.2 + lost_for / 2)
        try:
            self.bus.connect()
        except UserError:
            return
        answering = [m for m in self.names if self.bus.ping(self.bus.motors[m].id)]
        if not answering:
            self.bus.disconnect()
            return
        self._setup(answering)
        self._port_lost_at = None
        self._event("port_recovered", None, f"after {lost_for:.2f} s", fault=False)

    # ================================================================ close
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
                self._shutdown()
            except Exception as exc:  # noqa: BLE001 - a fault here must not hide the run's result
                self._event("close_error", None, repr(exc))
            finally:
                if self.bus is not None:
                    self.bus.disconnect()

    def _shutdown(self) -> None:
        bus = self.bus
        if bus is None or self.guard is None:
            return
        if not bus.connected:
            self._reconnect_after = 0.0
            self._try_reconnect(time.monotonic())
        if bus.connected and self.guard.last is not None:
            self._run_ease(self.ease_s)
            self._eased = bus.connected
        for name in self.names:
            self._torque_off[name] = bool(bus.connected and bus.write("Torque_Enable", name, 0))
        off = [n for n, ok in self._torque_off.items() if not ok]
        if off:
            self._event("torque_off_failed", ",".join(off), "could not confirm torque off")

    # ================================================================ reporting
    def _event(self, kind: str, joint: str | None, detail: str, fault: bool = True) -> None:
        if fault:
            self._faults.add(f"{kind}:{joint}" if joint else kind)
        self._counts[f"event:{kind}"] += 1
        if len(self._events) < MAX_EVENTS:
            self._events.append({"t": round(time.monotonic(), 3), "event": kind, "joint": joint, "detail": detail})

    def health(self) -> dict[str, Any]:
        bus = self.bus
        if bus is None:
            return {"status": "failed" if self._closed else "ok", "faults": sorted(self._faults)}
        servos = {n: bus.health[n].as_dict() for n in self.names}
        current = [f"{s['status']}:{n}" for n, s in servos.items() if s["status"] != "ok"]
        for n, s in servos.items():
            current += [f"{f}:{n}" for f in s["faults"]]
        if not bus.connected:
            current.append("port_lost")
        return {
            "status": "degraded" if current else "ok",
            "port": bus.port_name, "connected": bus.connected,
            "active_faults": sorted(set(current)), "faults": sorted(self._faults),
            "frames": self._counts["frames"], "frames_refused": self._counts["frames_refused"],
            "watchdog_trips": self.watchdog.tripped, "servos": servos,
        }

    def report(self) -> dict[str, Any]:
        health = self.health()
        torque_off = all(self._torque_off.get(n, False) for n in self.names) if self.names else False
        status = "ok" if not self._faults else "degraded"
        if not torque_off and self.bus is not None:
            status = "failed"
        return {
            "status": status, "faults": sorted(self._faults), "port": self.options.get("port"),
            "frames": self._counts["frames"], "frames_refused": self._counts["frames_refused"],
            "frames_unsent": self._counts["frames_unsent"], "goal_writes": self._counts["goal_writes"],
            "watchdog_trips": self.watchdog.tripped, "eased_to_neutral": self._eased,
            "torque_off": torque_off, "torque_off_per_servo": dict(self._torque_off),
            "bus_ms": {"sync_write": _percentiles(self._write_ms), "health_read": _percentiles(self._read_ms)},
            "clamped_frames": self.guard.clamped if self.guard else 0,
            "servos": health.get("servos", {}), "events": list(self._events),
        }


def _sub_spec(spec: TargetSpec, names: list[str]) -> TargetSpec:
    idx = [spec.index[n] for n in names]
    return TargetSpec(spec.name, tuple(names), spec.lower[idx], spec.upper[idx], spec.neutral[idx],
                      spec.max_velocity[idx], spec.max_acceleration[idx], tuple(spec.units[i] for i in idx))


def _percentiles(values: collections.deque[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p99": None, "n": 0}
    arr = np.fromiter(values, float)
    return {"p50": round(float(np.percentile(arr, 50)), 3), "p99": round(float(np.percentile(arr, 99)), 3),
            "n": int(arr.size)}
