"""What every serial-bus servo's register table answers alike (Dynamixel control tables, Feetech
memory tables): registers by name, the table's size, ticks to radians, and status bits to faults.
Each bus's table is a frozen dataclass that derives from ``RegisterMap`` and adds its byte order."""

from __future__ import annotations

from typing import Any


class RegisterMap:
    family: str
    registers: dict[str, Any]
    resolution: int
    span_rad: float
    error_bits: dict[int, str]

    @property
    def rad_per_tick(self) -> float:
        return self.span_rad / self.resolution

    @property
    def max_tick(self) -> int:
        return self.resolution - 1

    @property
    def size(self) -> int:
        return max(r.address + r.size for r in self.registers.values())

    def reg(self, name: str) -> Any:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"{self.family} has no register {name!r}") from None

    def has(self, name: str) -> bool:
        return name in self.registers

    def decode_errors(self, status: int) -> list[str]:
        return [name for bit, name in sorted(self.error_bits.items()) if status & (1 << bit)]
