"""What the Dynamixel and Feetech heads share between ``ServoBackend``'s safety loop and their bus.

Both address id'd servos on one serial bus through a name-addressed ``servo_bus.SerialBus``, and
both take the same ``joints`` calibration (``id``, ``zero_tick``, ``direction``, ``min_tick``,
``max_tick``, ``ticks_per_unit``, a speed and an acceleration). So the raw map, the checks at open
(every servo answers, and is the model the profile names), the health poll (positions, temperature,
voltage, lost and bad replies, first sight of each fault), re-initialising a servo that comes back,
reconnecting, torque off and the health report live here once. A bus's backend says what differs:
its bus and model table, how it writes its EEPROM limits and its motion profile.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np

from convodrive.backends.servo.safety import RawMap
from convodrive.backends.servo.serial_port import PortLost
from convodrive.backends.servo.servo_base import ServoBackend
from convodrive.backends.servo.servo_bus import Motor, SerialBus
from convodrive.motion.targets import TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import UserError


class SerialBusBackend(ServoBackend):
    """A servo head on one bus of id'd servos; subclasses fill in the class attributes and hooks."""

    Bus: ClassVar[type[SerialBus]]
    Joint: ClassVar[type[PluginOptions]]
    lookup_model: ClassVar[Callable[[str], Any]]
    """The model table's ``model(name)``."""
    HEALTH_REGISTERS: ClassVar[list[str]]
    VOLTAGE_REGISTER: ClassVar[str]
    CORRUPT_FAULT: ClassVar[str]
    """The fault a reply with a bad checksum is reported as."""
    OPEN_PINGS: ClassVar[int] = 1
    """Pings a servo gets at open before it counts as missing."""
    REFUSE_MISSING: ClassVar[bool] = True
    """Whether a mapped servo that does not answer at open refuses the run (else: ``servo_lost``)."""
    bus: SerialBus | None

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.bus = None
        self._motors: list[Motor] = []
        self._motion: dict[str, tuple[int, int]] = {}
        """Per joint (speed, acceleration) in the bus's units."""
        self._limits: dict[str, tuple[int, int]] = {}
        # Factory Return_Delay_Time is 250 (500 us per status packet); 0 keeps a 7-servo read short.
        self._return_delay = self.options.return_delay_us // 2  # type: ignore[attr-defined]

    # ---------------------------------------------------------------- what a bus's backend gives
    def _motion_of(self, joint: Any) -> tuple[int, int]:
        """A joint's (speed, acceleration), the bus's default where the joint gives none."""
        raise NotImplementedError

    def _found_model(self, motor: Motor) -> tuple[bool, str] | None:
        """Ping ``motor.id``: None if nothing answers, else (is the profile's model, model found)."""
        raise NotImplementedError

    def _write_eeprom(self, name: str, values: dict[str, int]) -> None:
        """Write EEPROM registers (position limits, return delay) that differ from ``values``."""
        raise NotImplementedError

    def _write_motion(self, name: str, speed: int, acceleration: int) -> None:
        raise NotImplementedError

    def _limit_registers(self, table: Any) -> tuple[str, str]:
        return "Min_Position_Limit", "Max_Position_Limit"

    # ---------------------------------------------------------------- the bus's servos
    @classmethod
    def motors_for(cls, options: Any, names: list[str] | None = None) -> list[Motor]:
        """The servos of ``options.joints`` (only ``names`` when given), each with its model."""
        default = cls.lookup_model(options.model)
        return [
            Motor(name, j.id, cls.lookup_model(j.model) if j.model else default)
            for name, j in (options.joints or {}).items()
            if names is None or name in names
        ]

    @classmethod
    def new_bus(cls, options: Any, motors: list[Motor], port: str | None = None) -> SerialBus:
        """A bus (not yet connected) for ``motors`` at the options' speed and timing."""
        return cls.Bus(
            port or options.port,
            motors,
            baudrate=options.baudrate,
            retries=options.retries,
            latency_ms=options.latency_ms,
        )

    # ---------------------------------------------------------------- calibration
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        key = f"backends.{self.name}.joints"
        joints = self.options.joints  # type: ignore[attr-defined]
        if joints is None:
            joints = {name: self.Joint(id=i + 1) for i, name in enumerate(spec.names)}
        unknown = sorted(set(joints) - set(spec.names))
        if unknown:
            raise UserError(f"{key}: {', '.join(unknown)} not in profile {spec.name} (joints: {', '.join(spec.names)})")
        default_model = self.lookup_model(self.options.model)  # type: ignore[attr-defined]
        zero, scale, low, high = [], [], [], []
        for name in (n for n in spec.names if n in joints):
            motor, z, s, lo, hi = self._joint(spec, name, joints[name], default_model)
            self._motors.append(motor)
            zero.append(z), scale.append(s), low.append(lo), high.append(hi)
        if not self._motors:
            raise UserError(f"{key}: no joint is mapped to a servo")
        self.names = [m.name for m in self._motors]
        return RawMap(np.array(zero), np.array(scale), np.array(low, float), np.array(high, float))

    def _joint(self, spec: TargetSpec, name: str, j: Any, default: Any) -> tuple[Motor, float, float, int, int]:
        """Raw map of one joint; the options are typed and ranged, so only what depends on the
        servo's model and the profile's limits is checked here."""
        key = f"backends.{self.name}.joints.{name}"
        i = spec.index[name]
        model = self.lookup_model(j.model) if j.model else default
        table = model.table
        if j.ticks_per_unit is None and spec.units[i] != "rad":
            raise UserError(f"{key}: joint is in {spec.units[i]}, give ticks_per_unit")
        s = math.copysign(j.ticks_per_unit or 1.0 / table.rad_per_tick, j.direction)
        z = table.center_tick if j.zero_tick is None else j.zero_tick
        ends = sorted((z + s * spec.lower[i], z + s * spec.upper[i]))
        lo = max(0, math.floor(ends[0])) if j.min_tick is None else j.min_tick
        hi = min(table.max_tick, math.ceil(ends[1])) if j.max_tick is None else j.max_tick
        if not 0 <= lo <= hi <= table.max_tick:
            raise UserError(f"{key}: need 0 <= min_tick <= max_tick <= {table.max_tick} ({model.name})")
        self._motion[name] = self._motion_of(j)
        self._limits[name] = (lo, hi)
        return Motor(name, j.id, model), z, s, lo, hi

    # ---------------------------------------------------------------- open
    def _hw_open(self) -> None:
        self.bus = bus = self.new_bus(self.options, self._motors)
        bus.connect()
        answering = {m.name for m in self._motors if self._check_model(m)}
        if answering:  # a reply lost on a noisy bus or a busy host is not a missing servo: ask again
            retry = [m for m in self._motors if m.name not in answering]
            answering |= {m.name for m in retry if any(self._check_model(m) for _ in range(self.OPEN_PINGS - 1))}
        if not answering:
            bus.disconnect()
            ids = ", ".join(str(m.id) for m in self._motors)
            raise UserError(f"{self.options.port}: no servo answers (ids {ids} at {bus.baudrate} baud)")
        missing = [m for m in self._motors if m.name not in answering]
        if missing and self.REFUSE_MISSING:  # a servo the profile drives must be there, as a Maestro's channel must
            bus.disconnect()
            raise UserError(
                f"backends.{self.name}.joints.{missing[0].name}.id: servo {missing[0].id} does not answer on "
                f"{self.options.port} at {bus.baudrate} baud"
                + (f" (nor {', '.join(str(m.id) for m in missing[1:])})" if len(missing) > 1 else "")
            )
        for motor in missing:
            self._event("servo_lost", motor.name, "no answer at open")
        self._setup([n for n in self.names if n in answering])

    def _check_model(self, motor: Motor) -> bool:
        assert self.bus is not None
        found = self._found_model(motor)
        if found is None:
            return False
        if not found[0]:
            self.bus.disconnect()
            raise UserError(
                f"backends.{self.name}.joints.{motor.name}: servo {motor.id} is {found[1]}, "
                f"the profile says {motor.model.name}"
            )
        return True

    def _setup(self, names: list[str]) -> None:
        """EEPROM (position limits, return delay; written only if changed), motion profile,
        goal = present, torque on."""
        bus = self.bus
        assert bus is not None
        for name in names:
            lo_reg, hi_reg = self._limit_registers(bus.motors[name].table)
            lo, hi = self._limits[name]
            eeprom = {lo_reg: lo, hi_reg: hi, "Return_Delay_Time": self._return_delay}
            if any(bus.read(reg, name) != value for reg, value in eeprom.items()):
                self._write_eeprom(name, eeprom)
            self._write_motion(name, *self._motion[name])
            present = bus.read("Present_Position", name)
            if present is not None:
                bus.write("Goal_Position", name, int(np.clip(present, lo, hi)))
            bus.write("Torque_Enable", name, 1)

    # ---------------------------------------------------------------- frames and health
    def _hw_present(self) -> np.ndarray:
        assert self.bus is not None
        values = [self.bus.read("Present_Position", n) for n in self.names]
        return np.array([np.nan if v is None else v for v in values], dtype=float)

    def _hw_write(self, raw: np.ndarray) -> None:
        assert self.bus is not None
        self.bus.sync_write("Goal_Position", dict(zip(self.names, raw.tolist())))

    def _hw_poll(self) -> None:
        bus = self.bus
        assert bus is not None
        lost_before = {n for n in self.names if bus.health[n].lost}
        data = bus.sync_read(self.HEALTH_REGISTERS)
        for name, regs in data.items():
            h = bus.health[name]
            h.position, h.temperature = regs["Present_Position"], regs["Present_Temperature"]
            h.voltage = regs[self.VOLTAGE_REGISTER] / 10.0
        for name, fault, bits in bus.take_new_faults():
            self._event(fault, name, f"{bus.FAULT_SOURCE} 0x{bits:02x}")
        for name in self.names:
            h = bus.health[name]
            if h.lost and name not in lost_before:
                self._event("servo_lost", name, f"no status packet after {bus.retries} retries")
            if h.timeouts:
                self._add_fault("lost_replies", name, f"{h.timeouts} status read(s) timed out")
            if h.corrupt:
                self._add_fault(self.CORRUPT_FAULT, name, f"{h.corrupt} status packet(s) failed their checksum")
            if h.short:
                self._add_fault("short_replies", name, f"{h.short} status packet(s) shorter than the data asked for")
        recovered = sorted(lost_before & set(data))
        if recovered:
            self._event("servo_recovered", ",".join(recovered), "answering again; re-initialised", fault=False)
            with self._lock:  # not between a frame's goals
                self._setup(recovered)

    def _hw_reconnect(self) -> bool:
        bus = self.bus
        if bus is None:
            return False
        try:
            bus.connect()
            answering = [n for n in self.names if bus.ping(bus.motors[n].id)]
        except (UserError, PortLost):
            bus.disconnect()
            return False
        if not answering:
            bus.disconnect()
            return False
        self._setup(answering)
        return True

    def _hw_connected(self) -> bool:
        return self.bus is not None and self.bus.connected

    def _hw_off(self) -> dict[str, bool]:
        assert self.bus is not None
        return {n: self.bus.write("Torque_Enable", n, 0) for n in self.names}

    def _hw_close(self) -> None:
        if self.bus is not None:
            self.bus.disconnect()

    def _hw_bus(self) -> dict[str, Any]:
        return {"group_read_timeouts": self.bus.group_timeouts if self.bus is not None else 0}

    def _hw_health(self) -> dict[str, dict[str, Any]]:
        if self.bus is None:
            return {}
        return {n: self.bus.health[n].as_dict() for n in self.names}
