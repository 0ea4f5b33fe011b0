"""How long this process has itself been watching a stream.

A stream's callbacks run on a thread of this process: when the process is starved of CPU (or
stopped), no callback comes, and that silence is the process's, not the device's. So a verdict
like "no audio for half a second" counts only time this process demonstrably ran: a watch
restarts whenever two looks at the stream are further apart than a healthy run ever leaves them.
"""

from __future__ import annotations


class Watch:
    """The time since which the stream has been watched without a gap longer than ``max_gap``."""

    def __init__(self, max_gap: float) -> None:
        self.max_gap = max_gap
        self.since: float | None = None
        self._looked: float | None = None

    def look(self, now: float) -> bool:
        """Note a look at monotonic time ``now``; True when the watch starts over here: at the first
        look, or after a gap in which this process did not look (what the stream did then is unknown)."""
        restarted = self._looked is None or now - self._looked > self.max_gap
        if restarted:
            self.since = now
        self._looked = now
        return restarted
