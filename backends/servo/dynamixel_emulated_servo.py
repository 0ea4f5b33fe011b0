"""One emulated Dynamixel servo: its whole control table in RAM and a first-order position model
(``bus_emulator.LoggedWrite`` is one register write as the servo saw it).

A write changes later reads, EEPROM writes need torque off, Goal_Position outside the position
limits is refused, and Present_Position slews toward Goal_Position at the profile velocity (or the
velocity limit when the profile is 0) while torque is on. ``dynamixel_emulator`` puts servos on a bus.
"""

from __future__ import annotations

from collections.abc import Callable

from convodrive.backends.servo import dynamixel_packet as dp
from convodrive.backends.servo.dynamixel_table import Model, decode, encode
from convodrive.plumbing.errors import UserError

Clock = Callable[[], float]


class EmulatedServo:
    """One servo: a control table in RAM plus a first-order position model."""

    def __init__(self, servo_id: int, model: Model, clock: Clock) -> None:
        self.id = servo_id
        self.model = model
        self.table = model.table
        self.mem = bytearray(self.table.size)
        self._clock = clock
        self.alive = True
        self._pending: tuple[int, bytes] | None = None  # REG_WRITE, applied by ACTION
        self._present = 0.0
        self._last = clock()
        self.factory_reset()

    def factory_reset(self) -> None:
        self.mem[:] = bytes(len(self.mem))
        self._set("Model_Number", self.model.number)
        self._set("Firmware_Version", self.model.firmware)
        self._set("ID", self.id)
        for name, value in self.table.defaults.items():
            self._set(name, value)
        self._present = float(self.get("Present_Position"))

    def power_cycle(self) -> None:
        """Power back after an outage: as a REBOOT (RAM lost, torque off)."""
        self.reboot()

    def reboot(self) -> None:
        """RAM back to defaults, EEPROM kept, errors cleared (what REBOOT does)."""
        self.update()
        self._set("Torque_Enable", 0)
        self._set("Hardware_Error_Status", 0)
        self._set("Goal_Position", int(round(self._present)))

    # ------------------------------------------------------------- registers
    def get(self, name: str) -> int:
        reg = self.table.reg(name)
        return decode(self.mem[reg.address : reg.address + reg.size], reg)

    def _set(self, name: str, value: int) -> None:
        reg = self.table.reg(name)
        self.mem[reg.address : reg.address + reg.size] = bytes(encode(value, reg))

    @property
    def torque(self) -> bool:
        return bool(self.get("Torque_Enable"))

    @property
    def hardware_error(self) -> int:
        return self.get("Hardware_Error_Status")

    @property
    def present(self) -> float:
        self.update()
        return self._present

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        if address + length > len(self.mem) or length == 0:
            return dp.ERR_DATA_RANGE, b""
        self.update()
        return 0, bytes(self.mem[address : address + length])

    def write(self, address: int, data: bytes) -> int:
        """Apply a write and return the status error number (0 = accepted)."""
        if address + len(data) > len(self.mem) or not data:
            return dp.ERR_DATA_RANGE
        touched = [
            (n, r)
            for n, r in self.table.registers.items()
            if r.address < address + len(data) and address < r.address + r.size
        ]
        for _name, reg in touched:
            if not reg.writable:
                return dp.ERR_ACCESS
            if reg.eeprom and self.torque:
                return dp.ERR_ACCESS
        goal = self.table.reg("Goal_Position")
        if goal.address >= address and goal.address + goal.size <= address + len(data):
            value = decode(data[goal.address - address :], goal)
            low, high = self._position_limits()
            if not low <= value <= high:
                return dp.ERR_DATA_LIMIT
        self.update()
        self.mem[address : address + len(data)] = data
        return 0

    def _position_limits(self) -> tuple[int, int]:
        if self.table.has("Min_Position_Limit"):
            return self.get("Min_Position_Limit"), self.get("Max_Position_Limit")
        return self.get("CW_Angle_Limit"), self.get("CCW_Angle_Limit")

    def set_error(self, fault: str) -> None:
        """Raise a hardware-error bit; torque drops if the Shutdown register lists it."""
        bits = {name: bit for bit, name in self.table.error_bits.items()}
        if fault not in bits:
            raise UserError(f"{self.model.name} has no hardware error {fault!r} (known: {', '.join(bits)})")
        self._set("Hardware_Error_Status", self.hardware_error | (1 << bits[fault]))
        if self.get("Shutdown") & (1 << bits[fault]):
            self.update()
            self._set("Torque_Enable", 0)

    def move_by_hand(self, tick: int) -> None:
        """A person turns the horn (torque off): Present_Position follows."""
        self._present = float(tick)
        self._set("Present_Position", tick)

    def update(self) -> None:
        now = self._clock()
        dt, self._last = max(0.0, now - self._last), now
        if self.torque:
            goal = self.get("Goal_Position")
            velocity = self.get("Profile_Velocity") if self.table.has("Profile_Velocity") else self.get("Moving_Speed")
            if velocity == 0:
                velocity = self.get("Velocity_Limit") if self.table.has("Velocity_Limit") else 1023
            ticks_per_s = velocity * self.table.velocity_unit_rpm / 60.0 * self.table.resolution
            step = ticks_per_s * dt
            delta = goal - self._present
            self._present = goal if abs(delta) <= step else self._present + step * (1 if delta > 0 else -1)
            self._set("Moving", int(abs(goal - self._present) > 0.5))
        self._set("Present_Position", int(round(self._present)))
