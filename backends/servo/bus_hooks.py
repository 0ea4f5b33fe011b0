"""The bus interface of a servo-head backend: what ``ServoBackend`` asks of the bus it drives.

A backend for another bus (Dynamixel, Maestro, ...) subclasses ``servo_base.ServoBackend`` and
implements these hooks; the safety loop around them (limits, watchdog, easing, torque off,
reporting) is the same for every bus. Joint values arrive here already checked and limited, in the
bus's raw units (``safety.RawMap``). A hook that finds the port gone raises
``serial_port.PortLost``; a fault of one servo is an event (``_event``), never an exception.
"""

from __future__ import annotations

import abc
from typing import Any

import numpy as np

from convodrive.backends.servo.safety import RawMap
from convodrive.motion.targets import TargetSpec


class BusHooks(abc.ABC):
    """The ``_hw_*`` methods a servo backend implements for its bus."""

    names: list[str]
    """The driven joints, in spec order: ``_hw_calibration`` sets them."""

    @abc.abstractmethod
    def _hw_calibration(self, spec: TargetSpec) -> RawMap:
        """Validate options, set ``self.names`` (driven joints, spec order); return the raw map."""

    @abc.abstractmethod
    def _hw_open(self) -> None:
        """Connect and initialise the servos; UserError if nothing usable answers."""

    @abc.abstractmethod
    def _hw_present(self) -> np.ndarray:
        """Present raw positions per driven joint (NaN where unknown)."""

    @abc.abstractmethod
    def _hw_write(self, raw: np.ndarray) -> None:
        """Send one raw goal per driven joint; raise PortLost if the port failed."""

    @abc.abstractmethod
    def _hw_poll(self) -> None:
        """Read health (at ``read_rate``); raise PortLost; report faults through ``_event``."""

    @abc.abstractmethod
    def _hw_reconnect(self) -> bool:
        """Try to reopen a lost port and re-initialise; True on success."""

    @abc.abstractmethod
    def _hw_connected(self) -> bool: ...

    @abc.abstractmethod
    def _hw_off(self) -> dict[str, bool]:
        """Torque off (stop pulses) per joint, confirmed where the bus allows."""

    @abc.abstractmethod
    def _hw_close(self) -> None: ...

    def _hw_health(self) -> dict[str, dict[str, Any]]:
        """Per-joint health for ``health()``."""
        return {}

    def _hw_bus(self) -> dict[str, Any]:
        """Bus-wide counters for ``report()``."""
        return {}
