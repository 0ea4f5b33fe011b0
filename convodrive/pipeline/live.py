"""``convodrive live``: a live session (``pipeline.session``) in player mode, fed by the command
line's sources: the partner on a microphone (or a file played as one), the robot's own voice from
a file, stdin or a socket, played on a speaker, and motion in time with both.

The self voice's playback position is the clock (``PlaybackClock``): frame k goes out when sample
k/30 s of the voice leaves the speaker. The voice is queued ``self lead`` seconds ahead of the
speaker (the generator's look-ahead plus a margin), so the generator has heard it before it is
played; the partner is placed ``partner delay`` seconds after capture, which is the partner's
latency. Without a self voice (``--self none``) the clock is the monotonic clock.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from convodrive.pipeline.run import DriveResult
from convodrive.pipeline.session import LiveSession, SessionRequest

OPTIONS = {
    "voice": "--self",
    "partner": "--partner",
    "speaker": "--play",
    "monitor": "--monitor",
    "seconds": "--seconds",
    "backends": "--backend",
}
"""How the command line names the request's fields, for its one-line errors."""


def live(request: SessionRequest, on_start: Callable[[], None] | None = None) -> DriveResult:
    """Run until the inputs end, ``seconds`` pass, or Ctrl-C; write the report. ``UserError`` for
    a user mistake (an unknown device, a busy port, a missing file, a bad option)."""
    request = dataclasses.replace(request, mode="player", labels={**OPTIONS, **request.labels})
    return LiveSession(request).run(on_start)
