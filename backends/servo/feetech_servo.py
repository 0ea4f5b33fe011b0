"""One emulated Feetech servo: its register table in memory and a position that moves toward the goal.

What a real STS/SCS servo does and a driver relies on: a write changes later reads; a goal outside
the position limits is clamped to them; Present_Position slews toward Goal_Position at
Goal_Velocity (steps per second, 0 = the servo's full speed) while torque is on; the load reads
high while it moves; a fault raises its bit in every status packet and in ``Status``, and switches
torque off when ``Unloading_Condition`` lists it. EEPROM registers survive a power cycle only if
they were written with ``Lock`` 0.
"""

from __future__ import annotations

from collections.abc import Callable

from convodrive.backends.servo.feetech_table import Model
from convodrive.plumbing.errors import UserError

Clock = Callable[[], float]

FAULT_READINGS = {"overheating": ("Present_Temperature", 80), "input_voltage": ("Present_Voltage", 45)}
"""What a servo reads while the fault lasts (the voltage of a sagging supply, in 0.1 V)."""
MOVING_LOAD, OVERLOAD = 120, 1000  # Present_Load, 0.1 % of the stall torque


class FeetechServo:
    def __init__(self, servo_id: int, model: Model, clock: Clock) -> None:
        self.id = servo_id
        self.model = model
        self.table = model.table
        self.mem = bytearray(self.table.size)
        self.saved = bytearray(self.table.size)
        """EEPROM as it would be after a power cycle."""
        self._clock = clock
        self.alive = True
        self.error = 0
        self.pending: tuple[int, bytes] | None = None  # REG_WRITE, applied by ACTION
        self._present = 0.0
        self._last = clock()
        self.factory_reset()

    def factory_reset(self) -> None:
        self.mem[:] = bytes(len(self.mem))
        self._set("Model_Number", self.model.number)
        self._set("Firmware_Major_Version", self.model.firmware[0])
        self._set("Firmware_Minor_Version", self.model.firmware[1])
        self._set("ID", self.id)
        for name, value in self.table.defaults.items():
            self._set(name, value)
        self.saved[:] = self.mem
        self._present = float(self.get("Present_Position"))

    def power_cycle(self) -> None:
        """Power back after an outage: RAM back to defaults, the saved EEPROM kept, errors cleared."""
        self.update()
        present, saved = round(self._present), bytes(self.saved)
        self.mem[:] = self.saved[:] = saved  # RAM at its factory values (kept in ``saved``), EEPROM as saved
        self.error = 0
        self._set("Present_Position", present)
        self._set("Goal_Position", present)
        self._present = float(present)

    # ------------------------------------------------------------- registers
    def get(self, name: str) -> int:
        reg = self.table.reg(name)
        return self.table.decode(self.mem[reg.address : reg.address + reg.size], reg)

    def _set(self, name: str, value: int) -> None:
        reg = self.table.reg(name)
        self.mem[reg.address : reg.address + reg.size] = self.table.encode(value, reg)

    @property
    def torque(self) -> bool:
        return bool(self.get("Torque_Enable"))

    @property
    def present(self) -> float:
        self.update()
        return self._present

    def read(self, address: int, length: int) -> bytes | None:
        """The bytes asked for; None when the span is outside the table (the servo stays silent)."""
        if address + length > len(self.mem) or length == 0:
            return None
        self.update()
        return bytes(self.mem[address : address + length])

    def write(self, address: int, data: bytes) -> bool:
        """Apply a write; False (nothing written) when it touches a read-only register or leaves the table."""
        if address + len(data) > len(self.mem) or not data:
            return False
        end = address + len(data)
        touched = [r for r in self.table.registers.values() if r.address < end and address < r.address + r.size]
        if any(not r.writable for r in touched):
            return False
        self.update()
        self.mem[address : address + len(data)] = data
        goal = self.table.reg("Goal_Position")
        if address <= goal.address < address + len(data):
            low, high = self.get("Min_Position_Limit"), self.get("Max_Position_Limit")
            self._set("Goal_Position", min(max(self.get("Goal_Position"), low), high))
        if self.get("Lock") == 0:
            for r in touched:
                if r.eeprom:
                    self.saved[r.address : r.address + r.size] = self.mem[r.address : r.address + r.size]
        return True

    def set_error(self, fault: str) -> None:
        """Raise a fault's bit; torque drops if ``Unloading_Condition`` lists it."""
        bits = {name: bit for bit, name in self.table.error_bits.items()}
        if fault not in bits:
            raise UserError(f"a {self.model.name} has no fault {fault!r} (known: {', '.join(bits)})")
        self.update()
        self.error |= 1 << bits[fault]
        self._set("Status", self.error)
        if fault in FAULT_READINGS:
            self._set(*FAULT_READINGS[fault])
        if self.get("Unloading_Condition") & (1 << bits[fault]):
            self._set("Torque_Enable", 0)

    def move_by_hand(self, tick: int) -> None:
        """A person turns the horn (torque off): Present_Position follows."""
        self._present = float(tick)
        self._set("Present_Position", tick)

    def update(self) -> None:
        now = self._clock()
        dt, self._last = max(0.0, now - self._last), now
        moving = False
        if self.torque:
            goal = self.get("Goal_Position")
            speed = abs(self.get("Goal_Velocity")) or self.table.max_speed
            step = min(speed, self.table.max_speed) * dt
            delta = goal - self._present
            self._present = goal if abs(delta) <= step else self._present + step * (1 if delta > 0 else -1)
            moving = abs(goal - self._present) > 0.5
        self._set("Moving", int(moving))
        overloaded = bool(self.error & (1 << 5))
        self._set("Present_Load", OVERLOAD if overloaded else MOVING_LOAD if moving else 0)
        self._set("Present_Position", int(round(self._present)))
