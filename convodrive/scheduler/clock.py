"""Clocks that pace a run (DESIGN, "Scheduler"): the scheduler asks one for the time and waits on it.

Three clocks serve three kinds of run:

- ``SimulatedClock``: offline runs from files. Time is whatever frame was dispatched last; waiting
  costs nothing, so the run goes as fast as the slowest backend takes frames.
- ``MonotonicClock``: real-time runs from files. Frame k is due at ``t0 + k / fps`` on the
  monotonic clock, an absolute deadline, so lateness never accumulates into drift.
- ``PlaybackClock``: live runs. Time is the position of the self voice that has left the
  speaker (``convodrive.audio.live.playback``), so the mouth moves with the sound, not with the
  process; frame k goes out when sample k/30 s of the voice is being heard.

A clock says whether it is ``paced``: a paced clock is wall time that cannot be held back, so the
scheduler feeds real-time backends through drop-oldest slots; an unpaced one delivers every frame.
"""

from __future__ import annotations

import abc
import time
from typing import Protocol


class Clock(abc.ABC):
    """Seconds since the run's first frame, and a way to wait for a given time."""

    paced: bool = True
    """True when time passes on its own (wall clock, audio playback); False when it is simulated."""

    @abc.abstractmethod
    def start(self, delay: float) -> None:
        """Make time 0 be ``delay`` seconds from now (the first frame's deadline)."""

    @abc.abstractmethod
    def now(self) -> float:
        """Seconds since time 0 (negative before it)."""

    @abc.abstractmethod
    def wait_until(self, t: float) -> None:
        """Return when ``now() >= t`` (at once if it already is)."""

    def close(self) -> None:  # noqa: B027 (optional hook: only a playback clock holds anything)
        """Release what the clock holds (an audio stream); called once when the run ends."""


class SimulatedClock(Clock):
    """Offline time: jumps to each deadline the scheduler waits for."""

    paced = False

    def __init__(self) -> None:
        self._t = 0.0

    def start(self, delay: float) -> None:
        self._t = 0.0

    def now(self) -> float:
        return self._t

    def wait_until(self, t: float) -> None:
        self._t = max(self._t, t)


class MonotonicClock(Clock):
    """Wall time on ``time.monotonic``, with wake-ups sharpened by a short spin.

    A sleeping thread wakes when the OS gets round to it, which under load is a millisecond or two
    late, and then it must take the interpreter lock back; waking ``spin_seconds`` early and
    spinning the rest absorbs both. The spin keeps the lock (no ``time.sleep(0)``): giving it away
    at every turn let the producer, under real-time priority on the other core, take it just
    before the deadline, and the clock waited a switch interval for it (p50 jitter 0.02 -> 0.37 ms
    measured). Another thread that asks still gets it after the switch interval. The cost is
    ``spin_seconds`` of one core per frame (6 % at 2 ms and 30 fps).
    """

    paced = True

    def __init__(self, spin_seconds: float = 0.002) -> None:
        self.spin_seconds = spin_seconds
        self._t0 = time.monotonic()

    def start(self, delay: float) -> None:
        self._t0 = time.monotonic() + delay

    def now(self) -> float:
        return time.monotonic() - self._t0

    def wait_until(self, t: float) -> None:
        deadline = self._t0 + t
        remaining = deadline - time.monotonic()
        if remaining > self.spin_seconds:
            time.sleep(remaining - self.spin_seconds)
        while time.monotonic() < deadline:
            pass


class PlaybackPosition(Protocol):
    """An output stream that knows how much of itself has been heard (``audio.live.Playback``)."""

    def start(self) -> None: ...

    def position_at(self, mono: float) -> float | None:
        """Seconds of the stream that have left the speaker at ``time.monotonic()`` = ``mono``;
        None while the stream has not yet said where it is."""
        ...

    def close(self) -> None: ...


class PlaybackClock(Clock):
    """Time is the playback position of the self voice: the master clock of a live run.

    ``start`` starts the stream; time 0 is when its first sample leaves the speaker, whatever
    ``delay`` says (the audio server decides when that is). Until the stream reports its first
    position, ``now`` says ``UNKNOWN`` (before time 0) and ``wait_until`` keeps waiting. Waiting
    converts the remaining stream time to monotonic time, sleeps, and spins the last
    ``spin_seconds``, like ``MonotonicClock``; it re-reads the position after each sleep, so the
    stream's rate governs, not the CPU's clock.
    """

    paced = True
    UNKNOWN = -1.0
    """What ``now`` says before the stream has reported a position."""
    MAX_SLEEP = 0.05

    def __init__(self, playback: PlaybackPosition, spin_seconds: float = 0.002) -> None:
        self.playback = playback
        self.spin_seconds = spin_seconds
        self._closed = False

    def start(self, delay: float) -> None:
        self.playback.start()

    def now(self) -> float:
        position = self.playback.position_at(time.monotonic())
        return self.UNKNOWN if position is None else position

    def wait_until(self, t: float) -> None:
        while True:
            position = self.playback.position_at(time.monotonic())
            if position is None:
                time.sleep(0.002)
                continue
            remaining = t - position
            if remaining <= 0:
                return
            if remaining > self.spin_seconds:  # re-read at least every MAX_SLEEP: the stream may jump
                time.sleep(min(remaining - self.spin_seconds, self.MAX_SLEEP))
            else:
                time.sleep(0)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.playback.close()
