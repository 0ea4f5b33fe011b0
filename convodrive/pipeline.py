"""Wires a run: audio → generator → retargeter → backends, under the scheduler.

This is the one module that knows generators, retargeting and backends together (DESIGN, "Which
part may know which"); the CLI calls it and nothing else imports it.

Which joint space a backend gets: a backend with no ``default_profile`` (render, record) takes
canonical motion only. A robot backend uses the run config's profile when the config is one (it
has ``joints``), else its own default profile from config/robots. Its options merge, lowest first:
its profile's ``backends.<name>``, the run config's ``backends.<name>``, then the caller's.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Callable

import yaml

from convodrive import FPS
from convodrive.audio.source import ANALYSIS_RATE, CHUNK_SAMPLES, AudioSource, ChannelMap
from convodrive.backends.base import Backend, Session
from convodrive.errors import InputFileError, UserError
from convodrive.generators.base import Generator, take_seed
from convodrive.plugins import BACKEND_GROUP, GENERATOR_GROUP, load_plugin
from convodrive.report import build_report, write_report
from convodrive.scheduler import Route, Scheduler
from convodrive.targets import TargetSpec

DEFAULT_GENERATOR = "procedural"


@dataclasses.dataclass
class RunConfig:
    """A ``--config`` YAML: a robot profile and/or ``generator:`` and ``backends:`` option sections."""

    path: Path | None = None
    data: dict[str, Any] = dataclasses.field(default_factory=dict)
    profile: Any = None  # convodrive.retargeting.RobotProfile when the file is a robot profile

    def generator_options(self, name: str) -> dict[str, Any]:
        return dict(_section(self.data, "generator", self.path).get(name) or {})

    def backend_options(self, name: str) -> dict[str, Any]:
        return dict(_section(self.data, "backends", self.path).get(name) or {})


def _section(data: dict[str, Any], key: str, path: Path | None) -> dict[str, Any]:
    value = data.get(key) or {}
    if not isinstance(value, dict):
        raise InputFileError(path or "config", f"'{key}' must be a mapping of names to options")
    return value


def load_run_config(path: str | os.PathLike[str] | None) -> RunConfig:
    if path is None:
        return RunConfig()
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such config file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise InputFileError(path, f"not valid YAML{line}") from None
    if not isinstance(data, dict):
        raise InputFileError(path, "a config must be a YAML mapping")
    config = RunConfig(path=path, data=data)
    if "joints" in data:
        from convodrive.retargeting import load_profile

        config.profile = load_profile(path)
    return config


@dataclasses.dataclass
class DriveRequest:
    audio: Path
    generator: str = DEFAULT_GENERATOR
    backends: tuple[str, ...] = ("record",)
    config: Path | None = None
    out_dir: Path = Path("convodrive-out")
    seed: int = 0
    samples: int = 1
    realtime: bool | None = None
    """True: the wall clock; False: a simulated clock; None: real time if any backend is real-time
    (hardware must be paced at 30 fps), else offline."""
    channels: ChannelMap | None = None
    generator_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    backend_options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class DriveResult:
    report: dict[str, Any]
    report_path: Path
    summary_path: Path
    outputs: list[Path]


def drive(
    request: DriveRequest,
    on_frame: Callable[[int, int], None] | None = None,
    on_start: Callable[[bool], None] | None = None,
) -> DriveResult:
    """Run one session end to end and write its report. ``UserError`` for any user mistake."""
    if request.samples < 1:
        raise UserError(f"--samples must be at least 1, got {request.samples}")
    if not request.backends:
        raise UserError("name at least one backend with --backend")
    source = AudioSource(request.audio, request.channels)
    config = load_run_config(request.config)
    planned = _make_backends(request, config)
    realtime = request.realtime if request.realtime is not None else any(p.backend.realtime for p in planned)
    out_dir = Path(request.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    session = Session(
        out_dir=out_dir,
        audio_path=Path(request.audio),
        duration=source.duration,
        num_frames=source.info.num_motion_frames,
        fps=FPS,
        offline=not realtime,
        seed=request.seed,
        num_samples=request.samples,
    )

    gen_cls = load_plugin(GENERATOR_GROUP, request.generator)
    gen_options = {**config.generator_options(request.generator), **request.generator_options}
    generator: Generator = gen_cls(gen_options)
    seeds = [take_seed(request.seed, i) for i in range(request.samples)]
    # Real time reads audio in 100 ms chunks (the streaming latency); offline in 1 s chunks, which
    # gives the same frames (generators are chunk-invariant) with less per-chunk overhead.
    chunk_samples = CHUNK_SAMPLES if realtime else ANALYSIS_RATE

    routes, failed_at_open = _open_backends(planned, session)
    total = session.num_frames or 0

    def frame_done(index: int) -> None:
        if on_frame is not None:
            on_frame(index + 1, total)

    try:
        scheduler = Scheduler(
            generator.stream_takes(source.chunks(chunk_samples), seeds),
            routes,
            realtime=realtime,
            expected_frames=session.num_frames,
            audio_seconds=source.duration,
            on_frame=frame_done,
            on_start=(lambda: on_start(realtime)) if on_start is not None else None,
        )
    except BaseException:  # e.g. Ctrl-C before the scheduler took the backends over
        _close_all(routes)
        raise
    result = scheduler.run()  # from here the scheduler closes every backend, whatever happens
    outputs = [p for r in routes for p in _safe_outputs(r.backend)]
    context = {
        "audio": {
            "path": str(request.audio),
            "sample_rate": source.info.sample_rate,
            "channels": source.info.channels,
            "duration_s": round(source.duration, 3),
            "self_channel": source.channel_map.self_channel,
            "other_channel": source.channel_map.other_channel,
        },
        "generator": {
            "name": request.generator,
            "seed": request.seed,
            "samples": request.samples,
            "lookahead_frames": generator.lookahead_frames,
            "options": gen_options,
        },
        "config": str(request.config) if request.config else None,
        "outputs": [str(p) for p in outputs],
    }
    report = build_report(result, context, failed_at_open)
    report_path, summary_path = write_report(report, out_dir)
    return DriveResult(report, report_path, summary_path, outputs)


@dataclasses.dataclass
class _Planned:
    """A backend made with its options, not yet opened, and the profile that drives it."""

    name: str
    backend: Backend
    profile: Any  # RobotProfile or None


def _make_backends(request: DriveRequest, config: RunConfig) -> list[_Planned]:
    """Instantiate each named backend with its merged options (a bad name or option is a UserError).

    Instances, not classes, say whether they are real-time: the renderer becomes one when its
    live window can open."""
    planned = []
    for name in dict.fromkeys(request.backends):
        cls: type[Backend] = load_plugin(BACKEND_GROUP, name)
        profile = _profile_for(cls, config)
        options: dict[str, Any] = {}
        if profile is not None:
            if profile.model_path is not None:
                options["model"] = str(profile.model_path)  # the body a simulator loads
            options.update(profile.backend_options(name))
        options.update(config.backend_options(name))
        options.update(request.backend_options.get(name, {}))
        planned.append(_Planned(name, cls(options), profile))
    return planned


def _open_backends(planned: list[_Planned], session: Session) -> tuple[list[Route], dict[str, str]]:
    """Open each backend. A user mistake aborts the run (closing what opened); any other fault at
    open fails that backend alone, and the run goes on without it."""
    routes: list[Route] = []
    failed: dict[str, str] = {}
    retargeters: dict[str, Any] = {}
    try:
        for item in planned:
            profile = item.profile
            spec = profile.spec if profile is not None else TargetSpec.empty()
            try:
                item.backend.open(spec, session)
            except UserError:
                raise
            except Exception as exc:  # hardware or driver fault: this backend only
                failed[item.name] = f"{exc.__class__.__name__}: {exc}"
                continue
            retarget = None
            key = ""
            if profile is not None:
                key = str(profile.path)
                if key not in retargeters:
                    from convodrive.retargeting import Retargeter

                    retargeters[key] = Retargeter(profile)
                retarget = retargeters[key]
            routes.append(Route(item.backend, retarget, key))
    except BaseException:
        _close_all(routes)
        raise
    return routes, failed


def _close_all(routes: list[Route]) -> None:
    for route in routes:
        try:
            route.backend.close()
        except Exception:
            pass


def _profile_for(cls: type[Backend], config: RunConfig) -> Any:
    if cls.default_profile is None:
        return None
    override = config.backend_options(cls.name).get("profile") if config.path else None
    from convodrive.retargeting import load_profile

    if override:
        return load_profile(override)
    if config.profile is not None:
        return config.profile
    return load_profile(cls.default_profile)


def _safe_outputs(backend: Backend) -> list[Path]:
    try:
        return list(backend.outputs())
    except Exception:
        return []
