"""A live run: the partner on a microphone, the robot's own voice on a speaker, motion in time with both.

The self voice's playback position is the clock (``PlaybackClock``): frame k goes out when sample
k/30 s of the voice leaves the speaker. The voice is queued ``self lead`` seconds ahead of the
speaker (the generator's look-ahead plus a margin), so the generator has heard it before it is
played; the partner is placed ``partner delay`` seconds after capture, which is the partner's
latency. Without a self voice (``--self none``) the clock is the monotonic clock.

The audio side (devices, threads, measurements) is ``convodrive.pipeline.live_run``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from convodrive import FPS
from convodrive.audio.live.self_voice import FileVoice
from convodrive.backends.base import Session
from convodrive.pipeline.backends import (
    close_all,
    make_backends,
    open_backends,
    run_in_own_processes,
    safe_outputs,
)
from convodrive.pipeline.config import load_run_config
from convodrive.pipeline.live_run import LiveRequest, LiveRun
from convodrive.pipeline.run import DriveResult, make_generator
from convodrive.plumbing.errors import UserError
from convodrive.scheduler import Scheduler, build_report, write_report


def live(request: LiveRequest, on_start: Callable[[], None] | None = None) -> DriveResult:
    """Run until the inputs end, ``seconds`` pass, or Ctrl-C; write the report. ``UserError`` for
    a user mistake (an unknown device, a busy port, a missing file, a bad option)."""
    if not request.backends:
        raise UserError("name at least one backend with --backend")
    if request.seconds is not None and not (math.isfinite(request.seconds) and request.seconds > 0):
        raise UserError(f"--seconds must be positive and finite, got {request.seconds:g}")
    config = load_run_config(request.config)
    generator, gen_options = make_generator(request.generator, config, request.generator_options, live=True)
    planned = make_backends(request.backends, config, request.backend_options)
    run_in_own_processes(planned)  # a live run is paced: heavy and hardware backends must not shake it
    if request.partner == "none" and request.self_voice == "none" and request.seconds is None:
        raise UserError("--self none and --partner none: nothing to listen to (give one, or --seconds)")
    need = generator.lookahead_seconds
    run = LiveRun(request, need)
    try:
        run.open_audio()
        out_dir = Path(request.out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        session = Session(
            out_dir=out_dir,
            audio_path=Path(request.self_voice) if isinstance(run.voice, FileVoice) else None,
            fps=FPS,
            offline=False,
            seed=request.seed,
        )
        routes, failed_at_open = open_backends(planned, session)
    except BaseException:
        run.close()
        raise
    try:
        run.start()
        scheduler = Scheduler(
            run.frames(generator.stream_takes(run.chunks(), [request.seed])),
            routes,
            clock=run.clock,
            on_frame=run.dispatched,
            on_start=lambda: run.clock_started(on_start),
            on_sent=run.sent,
        )
    except BaseException:
        close_all(routes)
        run.close()
        raise
    try:
        result = scheduler.run()  # closes every backend and the clock (the speaker), whatever happens
    finally:
        run.close()
    outputs = [p for r in routes for p in safe_outputs(r.backend)]
    outputs += run.write_evidence(out_dir)
    live_figures = run.report()
    context: dict[str, Any] = {
        "generator": {
            "name": request.generator,
            "seed": request.seed,
            "lookahead_frames": generator.lookahead_frames,
            "lookahead_ms": round(1000.0 * generator.lookahead_seconds, 1),
            "options": gen_options.as_dict(),
        },
        "config": str(request.config) if request.config else None,
        "live": live_figures,
        "outputs": [str(p) for p in outputs],
        "summary_lines": summary_lines(live_figures),
    }
    report = build_report(result, context, failed_at_open, [p.name for p in planned if p.backend.hardware])
    report_path, summary_path = write_report(report, out_dir)
    return DriveResult(report, report_path, summary_path, outputs)


def summary_lines(live: dict[str, Any], max_events: int = 12) -> list[str]:
    """The live figures a user looks at first, for the run's printed summary."""
    lines = []
    playback, voice, partner = live["playback"], live["self_voice"], live["partner"]
    if playback is not None:
        lines.append(
            f"live: the clock is the speaker {playback['device']!r} (output latency {playback['output_latency_ms']:.0f} ms); "
            f"self voice {voice['voice_seconds']:.1f} s queued {voice['lead_ms']:.0f} ms ahead, "
            f"{playback['underruns']} underruns, {voice['stalls']} stalls"
        )
    else:
        lines.append("live: no self voice; the clock is the monotonic clock")
    heard = live["audio_motion_offset"]
    if heard.get("measured") and heard.get("median_ms") is not None:
        lines.append(
            f"audio–motion offset at the monitor: median {heard['median_ms']:+.1f} ms over {heard['pairs']} speech onsets "
            f"({heard['min_ms']:+.1f} to {heard['max_ms']:+.1f} ms); the generator's own "
            f"{live['generator_offset']['median_ms']:+.1f} ms, so the clock's error {live['sync_error_ms']:+.1f} ms"
        )
    elif heard.get("measured"):
        lines.append("audio–motion offset: no speech onsets to measure it by")
    latency = live["latency_ms"]
    sent = ", ".join(
        f"{name} {h['p50']:.0f}/{h['p99']:.0f} ms" for name, h in latency["partner_capture_to_sent"].items() if h
    )
    lines.append(
        f"partner {partner['source']}: placed {latency['partner_delay']:.0f} ms after capture"
        + (f"; capture to body p50/p99: {sent}" if sent else "")
        + (f"; {partner['overruns']} overruns" if partner.get("overruns") else "")
    )
    for event in live["events"][:max_events]:
        when = f"{event['time']:8.2f} s" if event["time"] is not None else "         "
        lines.append(f"  {when}  {event['event']}")
    if len(live["events"]) > max_events:
        lines.append(f"  … {len(live['events']) - max_events} more events in run_report.json")
    return lines
