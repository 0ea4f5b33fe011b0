"""Fault schedules for the emulated servo buses: the ``--fault KIND[:ARG][@AT][+FOR]`` grammar.

``split_fault`` parses the grammar for any emulator (the Maestro's too); ``parse_fault`` checks the
kinds a servo bus can have, and ``Fault.apply`` injects one into a ``bus_emulator.BusEmulator``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

from convodrive.plumbing.errors import UserError
from convodrive.plumbing.text import clip_value

if TYPE_CHECKING:
    from convodrive.backends.servo.bus_emulator import BusEmulator

SERVO_FAULTS = ("overload", "overheating", "input_voltage", "vanish")
RATE_FAULTS = ("drop", "corrupt", "short")
FAULT_KINDS = (*RATE_FAULTS, *SERVO_FAULTS, "port")
MAX_FAULT_TIME = 86_400.0


@dataclasses.dataclass(frozen=True)
class Fault:
    """``KIND[:ARG][@AT][+FOR]``: e.g. ``drop:0.05`` (5 % of replies), ``short:0.1`` (10 % of
    replies one data byte short), ``overload:3@2``
    (servo 3 overloads 2 s in), ``vanish:4@1+2`` (servo 4 gone from 1 s to 3 s), ``port@5+1``."""

    kind: str
    arg: float | None = None
    at: float = 0.0
    duration: float | None = None

    def __str__(self) -> str:
        arg = "" if self.arg is None else f":{self.arg:g}"
        duration = "" if self.duration is None else f"+{self.duration:g}"
        return f"{self.kind}{arg}@{self.at:g}{duration}"

    @property
    def servo_id(self) -> int:
        """The servo a servo fault hits (servo 1 when none is named)."""
        return int(self.arg or 1)

    def apply(self, emu: BusEmulator) -> None:
        if self.kind == "drop":
            emu.drop_rate = self.arg if self.arg is not None else 0.05
        elif self.kind == "corrupt":
            emu.corrupt_rate = self.arg if self.arg is not None else 0.05
        elif self.kind == "short":
            emu.short_rate = self.arg if self.arg is not None else 0.05
        elif self.kind == "vanish":
            emu.vanish(self.servo_id, self.duration)
        elif self.kind == "port":
            emu.unplug(self.duration)
        else:
            emu.hardware_error(self.servo_id, self.kind)


def split_fault(text: str) -> Fault:
    """Parse the ``KIND[:ARG][@AT][+FOR]`` grammar without checking the kind (shared with the Maestro)."""
    try:
        rest, _, duration = text.partition("+")
        rest, _, at = rest.partition("@")
        kind, _, arg = rest.partition(":")
        fault = Fault(kind, float(arg) if arg else None, float(at or 0), float(duration) if duration else None)
    except ValueError:
        raise UserError(f"--fault {clip_value(text)}: expected KIND[:ARG][@SECONDS][+SECONDS]") from None
    times = [fault.at] + ([fault.duration] if fault.duration is not None else [])
    if not all(0 <= t <= MAX_FAULT_TIME for t in times):  # also refuses nan
        raise UserError(f"--fault {clip_value(text)}: times must be from 0 to {MAX_FAULT_TIME:g} seconds")
    if fault.arg is not None and not math.isfinite(fault.arg):
        raise UserError(f"--fault {clip_value(text)}: the argument must be a finite number")
    return fault


def parse_fault(text: str) -> Fault:
    fault = split_fault(text)
    if fault.kind not in FAULT_KINDS:
        raise UserError(
            f"--fault {clip_value(text)}: unknown kind {clip_value(fault.kind)} (known: {', '.join(FAULT_KINDS)})"
        )
    if fault.kind in RATE_FAULTS and fault.arg is not None and not 0 <= fault.arg <= 1:
        raise UserError(f"--fault {clip_value(text)}: {fault.kind} takes a rate from 0 to 1")
    if fault.kind in SERVO_FAULTS and not float(fault.arg or 1).is_integer():
        raise UserError(f"--fault {clip_value(text)}: {fault.kind} takes a servo id, e.g. {fault.kind}:3")
    return fault
