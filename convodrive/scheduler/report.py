"""The run report: what every run ends with, as JSON (for tools) and as a readable summary."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from convodrive import __version__
from convodrive.plumbing.atomic import write_text_atomic
from convodrive.plumbing.stats import percentiles
from convodrive.scheduler.workers import BackendStats


@dataclasses.dataclass
class RunResult:
    """Everything the run report is made of; see ``convodrive.scheduler.report``."""

    mode: str
    frames: int
    expected_frames: int | None
    wall_seconds: float
    clock_seconds: float
    """From the first frame's deadline to one period after the last dispatch: the clock's own span."""
    jitter_ms: list[float]
    late_frames: int
    generator_seconds: float
    audio_seconds: float
    drift_frames: float
    interrupted: bool
    backends: list[BackendStats]
    backend_reports: dict[str, dict[str, Any]]
    backend_health: dict[str, dict[str, Any]]
    clock_priority: str = "normal"
    input_error: str | None = None
    """Set when the input failed part-way (audio that stopped decoding): the run ended there."""
    stop_signal: str | None = None
    """The signal that interrupted the run, if one did."""
    retarget_seconds: float = 0.0


def _rate(frames: int, seconds: float) -> float | None:
    return round(frames / seconds, 2) if seconds > 0 else None


def build_report(
    result: RunResult,
    context: dict[str, Any],
    failed_at_open: dict[str, str] | None = None,
    hardware: Iterable[str] = (),
) -> dict[str, Any]:
    """Turn a scheduler result plus run context (audio, generator, outputs) into the report dict.

    ``hardware`` names the backends that are physical devices: ``hardware_failed`` lists those
    that failed (at open, during the run, or closing with torque off unconfirmed), and a run with
    any exits non-zero."""
    backends: dict[str, Any] = {}
    for stats in result.backends:
        backends[stats.name] = {
            "frames_sent": stats.sent,
            "frames_dropped": stats.dropped,
            "errors": stats.errors,
            "last_error": stats.last_error,
            "failed": stats.failed,
            "close_error": stats.close_error,
            "send_ms": percentiles(stats.send_seconds, 1000.0),
            "dispatch_to_sent_ms": stats.dispatch_to_sent_ms.summary(2),
            "health": result.backend_health.get(stats.name, {}),
            "health_events": stats.health_events,
            "report": result.backend_reports.get(stats.name, {}),
        }
    for name, problem in (failed_at_open or {}).items():
        backends[name] = {"failed": True, "open_error": problem, "frames_sent": 0, "frames_dropped": result.frames}
    failed = {}
    for name, entry in backends.items():
        state, reason = backend_state(entry)
        if state == "FAILED":
            failed[name] = reason
    hardware_failed = {name: failed[name] for name in hardware if name in failed}
    gen_rtf = result.audio_seconds / result.generator_seconds if result.generator_seconds > 0 else None
    report = {
        "convodrive_version": __version__,
        "mode": result.mode,
        "interrupted": result.interrupted,
        "input_error": result.input_error,
        "stop_signal": result.stop_signal,
        "frames": result.frames,
        "expected_frames": result.expected_frames,
        "wall_seconds": round(result.wall_seconds, 3),
        "clock_seconds": round(result.clock_seconds, 3),
        # Real time: the clock's own rate. Offline: how fast every backend got through the run.
        "effective_fps": _rate(
            result.frames, result.clock_seconds if result.mode == "realtime" else result.wall_seconds
        ),
        "jitter_ms": percentiles(result.jitter_ms),
        "late_frames": result.late_frames,
        "clock_priority": result.clock_priority,
        "drift_frames": round(result.drift_frames, 3),
        "generator_real_time_factor": round(gen_rtf, 1) if gen_rtf else None,
        "retarget_ms_per_frame": round(1000 * result.retarget_seconds / result.frames, 3) if result.frames else None,
        "backends": backends,
        "hardware_failed": hardware_failed,
        "every_backend_failed": bool(backends) and len(failed) == len(backends),
    }
    report.update(context)
    return report


def summarize(report: dict[str, Any]) -> str:
    """A few readable lines: the figures a user looks at first."""
    lines = [
        (
            f"realtime run: {report['frames']} frames, clock at {report['effective_fps']} fps; {report['wall_seconds']:.2f} s in all"
            if report["mode"] == "realtime"
            else f"offline run: {report['frames']} frames in {report['wall_seconds']:.2f} s ({report['effective_fps']} fps)"
        )
        + (" — interrupted" if report["interrupted"] else ""),
    ]
    if report.get("input_error"):
        lines.append(f"stopped early: {report['input_error']}")
    for warning in report.get("warnings", []):
        lines.append(f"warning: {warning}")
    jit = report.get("jitter_ms")
    if jit:
        lines.append(
            f"frame-time jitter p50 {jit['p50']:.3f} ms, p99 {jit['p99']:.3f} ms, max {jit['max']:.3f} ms; "
            f"late frames {report['late_frames']}; drift {report['drift_frames']:.2f} frames"
        )
    if report.get("generator_real_time_factor"):
        lines.append(
            f"generator {report.get('generator', {}).get('name', '?')}: {report['generator_real_time_factor']}x real time"
        )
    for name, b in report["backends"].items():
        state, detail = backend_state(b)
        lines.append(
            f"  {name:<10} {state:<9} sent {b.get('frames_sent', 0):>6}  dropped {b.get('frames_dropped', 0):>6}  "
            f"errors {b.get('errors', 0):>4}" + (f"  ({detail})" if detail else "")
        )
    lines.extend(report.get("summary_lines", []))  # what the kind of run adds (a live run's figures)
    return "\n".join(lines)


FAILED_RATIO = 0.9
"""A backend whose sends failed this often (or that never sent a frame) failed, however short the run."""
DEGRADED_RATIO = 0.1
"""One whose sends failed this often is degraded."""


def backend_state(entry: dict[str, Any]) -> tuple[str, str]:
    """("ok" | "degraded" | "FAILED", why) for one backend of a report: the worst of its health,
    its final report and the share of its sends that failed, and a reason a user can act on (no
    display, which servo was lost)."""
    health = entry.get("health") or {}
    final = entry.get("report") or {}
    statuses = {str(health.get("status", "ok")), str(final.get("status", "ok"))}
    reason = (
        entry.get("open_error")
        or (entry.get("last_error") if entry.get("failed") else "")
        or (final.get("reason") if final.get("status") in ("failed", "degraded") else "")
        or health.get("reason")
        or final.get("error")
        or entry.get("close_error")
        or entry.get("last_error")
        or ""
    )
    if bool(entry.get("failed")) or "failed" in statuses:
        return "FAILED", str(reason)
    errors, sent = int(entry.get("errors") or 0), int(entry.get("frames_sent") or 0)
    ratio = errors / (errors + sent) if errors else 0.0
    if ratio >= FAILED_RATIO or (errors and not sent):
        return "FAILED", f"{errors} of {errors + sent} sends failed: {entry.get('last_error')}"
    if "degraded" in statuses:
        return "degraded", str(reason or "no reason given")
    if ratio >= DEGRADED_RATIO:
        return "degraded", f"{errors} of {errors + sent} sends failed: {entry.get('last_error')}"
    return "ok", str(reason)


def write_report(report: dict[str, Any], out_dir: Path, name: str = "run_report") -> tuple[Path, Path]:
    json_path = out_dir / f"{name}.json"
    text_path = out_dir / f"{name}.txt"
    write_text_atomic(json_path, json.dumps(report, indent=2, default=_json_default) + "\n")
    write_text_atomic(text_path, summarize(report) + "\n")
    return json_path, text_path


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)
