"""The scheduler: a clock, a producer, one worker per backend, and the run report."""

from convodrive.scheduler.clock import Clock, MonotonicClock, PlaybackClock, SimulatedClock
from convodrive.scheduler.loop import Scheduler
from convodrive.scheduler.report import RunResult, build_report, summarize, write_report
from convodrive.scheduler.route import Route
from convodrive.scheduler.slots import BlockingSlot, DropOldestSlot
from convodrive.scheduler.workers import BackendStats, BackendWorker

__all__ = [
    "BackendStats",
    "BackendWorker",
    "BlockingSlot",
    "Clock",
    "DropOldestSlot",
    "MonotonicClock",
    "PlaybackClock",
    "Route",
    "RunResult",
    "Scheduler",
    "SimulatedClock",
    "build_report",
    "summarize",
    "write_report",
]
