"""A live session's report: its figures (the run report's ``live`` section), the lines a user
reads first, and the report itself (``scheduler.report``) with what the run wrote."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from convodrive.pipeline.backends import safe_outputs
from convodrive.pipeline.run import DriveResult
from convodrive.pipeline.session.inputs import QueuedVoice
from convodrive.scheduler import build_report, write_report

if TYPE_CHECKING:
    from convodrive.pipeline.session.running import SessionRun


def figures(session: SessionRun) -> dict[str, Any]:
    """The ``live`` section: clock, voices, latencies, offsets, events."""
    assert session.audio is not None
    player = session.player
    heard, own = session.measures.offsets(session.monitor, session.label("monitor"))
    sync_error = None
    if heard.get("median_ms") is not None and own.get("median_ms") is not None:
        sync_error = round(heard["median_ms"] - own["median_ms"], 1)
    feeder, follower, audio = session.feeder, session.follower, session.audio
    texts = (feeder.events if feeder is not None else []) + audio.events
    voice = session.voice
    return {
        "mode": session.request.mode,
        "clock": "playback" if session.speaker is not None else "monotonic",
        "self_voice": feeder.report() if feeder is not None else (follower.report() if follower else None),
        "playback": session.speaker.report() if session.speaker is not None else None,
        "partner": {**session.partner.report(), **audio.report()},
        "latency_ms": {
            "self_lead": round(1000.0 * session.self_lead, 1) if player else None,
            "partner_delay": round(1000.0 * audio.partner_delay, 1),
            "follower_delay": None if player else round(1000.0 * session.delay, 1),
            **session.measures.latency(),
        },
        "audio_motion_offset": heard,
        "generator_offset": own,
        "sync_error_ms": sync_error,
        "events": sorted(texts, key=lambda e: (e["time"] is None, e["time"] or 0.0)),
        "conversation_events": [{"time": round(e.at, 3), "event": e.kind.value} for _, e in session.events],
        "dropped_self_seconds": round(voice.dropped, 3) if isinstance(voice, QueuedVoice) else None,
    }


def write_session_report(session: SessionRun) -> DriveResult:
    """``run_report.json`` and its summary, with the outputs of every backend and ``sync.npz``."""
    assert session.run_result is not None
    out_dir = Path(session.request.out_dir)
    outputs = [p for r in session.routes for p in safe_outputs(r.backend)]
    outputs += session.measures.write_evidence(session.monitor, out_dir)
    live = figures(session)
    generator = session.generator
    context: dict[str, Any] = {
        "generator": {
            "name": generator.name,
            "seed": session.request.seed,
            "lookahead_frames": generator.lookahead_frames,
            "lookahead_ms": round(1000.0 * generator.lookahead_seconds, 1),
            "options": session.generator_options,
        },
        "config": str(session.request.config) if session.request.config else None,
        "live": live,
        "outputs": [str(p) for p in outputs],
        "summary_lines": summary_lines(live),
    }
    report = build_report(session.run_result, context, session.failed_at_open, session.hardware)
    report_path, summary_path = write_report(report, out_dir)
    return DriveResult(report, report_path, summary_path, outputs)


def summary_lines(live: dict[str, Any], max_events: int = 12) -> list[str]:
    """The live figures a user looks at first, for the run's printed summary."""
    lines = []
    playback, voice, partner, latency = live["playback"], live["self_voice"], live["partner"], live["latency_ms"]
    if live["mode"] == "follower":
        lines.append(
            f"live (follower): the voice plays elsewhere; the motion follows it {latency['follower_delay']:.0f} ms late"
        )
    elif playback is not None:
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
    sent = ", ".join(
        f"{name} {h['p50']:.0f}/{h['p99']:.0f} ms" for name, h in latency["partner_capture_to_sent"].items() if h
    )
    lines.append(
        f"partner {partner['source']}: placed {latency['partner_delay']:.0f} ms after capture"
        + (f"; capture to body p50/p99: {sent}" if sent else "")
        + (f"; {partner['overruns']} overruns" if partner.get("overruns") else "")
    )
    if live["conversation_events"]:
        lines.append(f"conversation: {len(live['conversation_events'])} events from the voice agent")
    for event in live["events"][:max_events]:
        when = f"{event['time']:8.2f} s" if event["time"] is not None else "         "
        lines.append(f"  {when}  {event['event']}")
    if len(live["events"]) > max_events:
        lines.append(f"  … {len(live['events']) - max_events} more events in run_report.json")
    return lines
