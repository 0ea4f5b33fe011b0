"""The pipeline: the one package that knows generators, retargeting and backends together.

It wires audio → generator → retargeter → backends under the scheduler (DESIGN, "Which part may
know which"); the CLI calls it and nothing but the CLI imports it.
"""

from convodrive.pipeline.config import RunConfig, load_run_config
from convodrive.pipeline.live import live
from convodrive.pipeline.live_run import LiveRequest
from convodrive.pipeline.run import DEFAULT_GENERATOR, MAX_SAMPLES, DriveRequest, DriveResult, drive

__all__ = [
    "DEFAULT_GENERATOR",
    "MAX_SAMPLES",
    "DriveRequest",
    "DriveResult",
    "LiveRequest",
    "RunConfig",
    "drive",
    "live",
    "load_run_config",
]
