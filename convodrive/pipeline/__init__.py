"""The pipeline: the one package that knows generators, retargeting and backends together.

It wires audio → generator → retargeter → backends under the scheduler (DESIGN, "Which part may
know which"); the CLI calls it and nothing but the CLI imports it.
"""

from convodrive.pipeline.config import RunConfig, load_run_config
from convodrive.pipeline.live import live
from convodrive.pipeline.run import DEFAULT_GENERATOR, MAX_SAMPLES, DriveRequest, DriveResult, drive
from convodrive.pipeline.session import LiveSession, SessionRequest

__all__ = [
    "DEFAULT_GENERATOR",
    "MAX_SAMPLES",
    "DriveRequest",
    "DriveResult",
    "LiveSession",
    "RunConfig",
    "SessionRequest",
    "drive",
    "live",
    "load_run_config",
]
