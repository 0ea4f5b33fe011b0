"""Runs one drive: audio → generator → retargeter → backends, under the scheduler's clock."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.audio.source import (
    ANALYSIS_RATE,
    CHUNK_SAMPLES,
    AudioSource,
    ChannelMap,
    SilentSource,
    motion_frames_for,
)
from convodrive.backends.base import Session
from convodrive.generators.base import Generator, take_seed
from convodrive.pipeline.backends import (
    close_all,
    make_backends,
    open_backends,
    run_in_own_processes,
    safe_outputs,
)
from convodrive.pipeline.config import RunConfig, load_run_config
from convodrive.plugins import GENERATOR_GROUP, load_plugin
from convodrive.plugins.options import PluginOptions, merge_options
from convodrive.plumbing.errors import UserError
from convodrive.plumbing.outdir import OutputFolder
from convodrive.scheduler import MonotonicClock, Scheduler, SimulatedClock, build_report, write_report
from convodrive.scheduler.loop import DrainCallback

DEFAULT_GENERATOR = "procedural"
MAX_SAMPLES = 16
"""Most takes one run generates: each take costs generator time and the renderer's grid space."""


@dataclasses.dataclass
class DriveRequest:
    audio: Path | None
    """The conversation; None for a run clocked by silence (``duration`` then sets its length)."""
    generator: str = DEFAULT_GENERATOR
    backends: tuple[str, ...] = ("record",)
    config: str | Path | None = None
    """A run config or robot profile: a YAML path or a bundled profile's name."""
    out_dir: Path = Path("convodrive-out")
    seed: int = 0
    samples: int = 1
    realtime: bool | None = None
    """True: the wall clock; False: a simulated clock; None: real time if any backend is real-time
    (hardware must be paced at 30 fps), else offline."""
    own_processes: bool | None = None
    """Run the backends that may (render, mujoco) in child processes of their own: True, False, or
    None for "when the run is real time", where their work would otherwise delay the clock."""
    channels: ChannelMap | None = None
    generator_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    backend_options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    duration: float | None = None
    """Seconds of silence that clock a run without audio."""
    report_name: str = "run_report"
    """The report's file stem in ``out_dir`` (``.json`` and ``.txt``)."""
    out_label: str | None = None
    """How messages name the output folder (default ``--out OUT_DIR``)."""


@dataclasses.dataclass
class DriveResult:
    report: dict[str, Any]
    report_path: Path
    summary_path: Path
    outputs: list[Path]


def make_generator(
    name: str, config: RunConfig, options: dict[str, Any], live: bool = False
) -> tuple[Generator, PluginOptions]:
    """The named generator with its options merged (a live run's defaults when ``live``, the
    config's, then the caller's); a bad name or option is a ``UserError``."""
    gen_cls: type[Generator] = load_plugin(GENERATOR_GROUP, name)
    layers = [(config.where, config.generator_options(name)), ("", options)]
    if live:
        layers.insert(0, ("", dict(gen_cls.live_options)))
    merged = merge_options(gen_cls.Options, layers, plugin=f"generator {name}")
    return gen_cls(merged), merged


def drive(
    request: DriveRequest,
    on_frame: Callable[[int, int], None] | None = None,
    on_start: Callable[[bool], None] | None = None,
    on_drain: DrainCallback | None = None,
) -> DriveResult:
    """Run one session end to end and write its report. ``UserError`` for any user mistake found
    before the run; one found during it (audio that stops decoding) ends the run early, and the
    report says so in ``input_error``."""
    if not 1 <= request.samples <= MAX_SAMPLES:
        raise UserError(f"--samples must be between 1 and {MAX_SAMPLES}, got {request.samples}")
    if not request.backends:
        raise UserError("name at least one backend with --backend")
    source = _audio_source(request)
    config = load_run_config(request.config)
    planned = make_backends(request.backends, config, request.backend_options)
    generator, gen_options = make_generator(request.generator, config, request.generator_options)
    realtime = request.realtime if request.realtime is not None else any(p.backend.realtime for p in planned)
    if request.own_processes if request.own_processes is not None else realtime:
        run_in_own_processes(planned)
    seeds = [take_seed(request.seed, i) for i in range(request.samples)]

    out = OutputFolder(request.out_dir, request.out_label)
    with out.kept_on_success() as out_dir:
        session = Session(
            out_dir=out_dir,
            audio_path=Path(request.audio) if request.audio is not None else None,
            duration=source.duration,
            num_frames=motion_frames_for(source.duration),
            fps=FPS,
            offline=not realtime,
            seed=request.seed,
            num_samples=request.samples,
        )
        # Real time reads audio in 100 ms chunks (the streaming latency); offline in 1 s chunks, which
        # gives the same frames (generators are chunk-invariant) with less per-chunk overhead.
        chunk_samples = CHUNK_SAMPLES if realtime else ANALYSIS_RATE
        routes, failed_at_open = open_backends(planned, session)
        total = session.num_frames or 0

        def frame_done(index: int) -> None:
            if on_frame is not None:
                on_frame(index + 1, total)

        try:
            scheduler = Scheduler(
                generator.stream_takes(source.chunks(chunk_samples), seeds),
                routes,
                clock=MonotonicClock() if realtime else SimulatedClock(),
                expected_frames=session.num_frames,
                audio_seconds=source.duration,
                on_frame=frame_done,
                on_start=(lambda: on_start(realtime)) if on_start is not None else None,
                on_drain=on_drain,
            )
        except BaseException:  # e.g. Ctrl-C before the scheduler took the backends over
            close_all(routes)
            raise
        result = scheduler.run()  # from here the scheduler closes every backend, whatever happens
        outputs = [p for r in routes for p in safe_outputs(r.backend)]
        generator_notes = _safe_report(generator)
        context = {
            "audio": source.describe(),
            "generator": {
                "name": request.generator,
                "seed": request.seed,
                "samples": request.samples,
                "lookahead_frames": generator.lookahead_frames,
                "options": gen_options.as_dict(),
                **generator_notes,
            },
            "config": str(request.config) if request.config else None,
            "outputs": [str(p) for p in outputs],
            "warnings": list(generator_notes.get("warnings", [])),
        }
        hardware = [p.name for p in planned if p.backend.hardware]
        report = build_report(result, context, failed_at_open, hardware)
        report_path, summary_path = write_report(report, out_dir, request.report_name)
    return DriveResult(report, report_path, summary_path, outputs)


def _audio_source(request: DriveRequest) -> AudioSource | SilentSource:
    if request.audio is not None:
        return AudioSource(request.audio, request.channels)
    if request.duration is None:
        raise UserError("a run needs audio, or a duration of silence")
    return SilentSource(request.duration)


def _safe_report(generator: Generator) -> dict[str, Any]:
    try:
        notes = generator.report()
    except Exception as exc:  # a third-party generator's report must not lose the run's
        return {"report_error": f"{exc.__class__.__name__}: {exc}"}
    return dict(notes) if isinstance(notes, dict) else {}
