"""The robot's own voice in a live run: where it comes from, and the thread that keeps it queued.

``--self`` names the source: a file (played at its own rate), ``-`` (raw PCM on stdin), or
``tcp://HOST:PORT`` (a local socket an agent's speech synthesiser connects to and writes raw PCM
into; one speaker at a time, and the next may connect after one hangs up), or ``none``. Raw PCM is
signed 16-bit little-endian mono at ``--self-rate``. Off loopback the socket asks for a token
(``tcp://HOST:PORT?token=T``, or a fresh one the run prints): a speaker first sends it as one
line, then its PCM (``convodrive.plumbing.access``).

``SelfVoiceFeeder`` moves the voice into the playback ring and, at the same moment, into the
analysis time line the generator reads, so the generator always sees the voice ``lead`` seconds
before the speaker plays it: the self voice is delayed by the generator's look-ahead. When the
source has nothing (an agent between sentences, a stream that stopped mid-sentence) the feeder
queues silence instead, so the speaker, the clock and the generator go on, and the mouth closes.
"""

from __future__ import annotations

import abc
import os
import select
import socket
import sys
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import soundfile as sf

from convodrive.audio.live.ring import SampleRing
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.resample import StreamResampler
from convodrive.audio.source import ANALYSIS_RATE, AudioDecodeError, AudioSource, ChannelMap
from convodrive.plumbing.access import token_for, token_matches, token_problem
from convodrive.plumbing.errors import UserError

TOKEN_SECONDS = 5.0
"""A speaker off loopback has this long to send its token line before it is hung up on."""
READ_SECONDS = 0.02
"""The most the feeder reads from a source at once."""
POLL_SECONDS = 0.005


class VoiceSource(abc.ABC):
    """A mono voice at ``rate``. ``read`` never blocks longer than its timeout."""

    rate: int
    finite: bool = True
    """False for a socket: speakers come and go, and the run never runs out of them."""
    describe: str = ""

    @abc.abstractmethod
    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        """Up to ``max_samples`` float32 samples; empty if none came in ``timeout`` seconds; None
        once the voice has ended for good."""

    def streaming(self) -> bool:
        """True while a speaker is connected (a stall then means a stream stopped mid-sentence)."""
        return True

    def close(self) -> None:  # noqa: B027 (optional hook)
        pass

    def events(self) -> list[str]:
        """Things worth a line in the report (connections, hang-ups), drained by the feeder."""
        return []


class NoVoice(VoiceSource):
    """``--self none``: the robot does not speak; the generator hears self as silence."""

    def __init__(self, rate: int = ANALYSIS_RATE) -> None:
        self.rate = rate
        self.describe = "none"

    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        return None


class FileVoice(VoiceSource):
    """A recorded voice (WAV, FLAC, OGG) at its own rate; channel 0 of a multi-channel file.
    Checked as a partner file is (``AudioSource``: NaN or infinite samples are refused); a file
    that stops decoding part-way raises ``AudioDecodeError`` there."""

    def __init__(self, path: Path) -> None:
        info = AudioSource(path, ChannelMap(0, None)).info
        self.path = path
        self.rate = info.sample_rate
        self.describe = str(path)
        self.duration = info.duration
        self._fh = sf.SoundFile(str(path))
        self._read = 0

    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        try:
            data = self._fh.read(max(int(max_samples), 1), dtype="float32", always_2d=True)
        except (sf.LibsndfileError, RuntimeError) as exc:
            detail = str(exc).split(":")[-1].strip().rstrip(".") or exc.__class__.__name__
            raise AudioDecodeError(self.path, self._read / self.rate, detail) from None
        self._read += len(data)
        return data[:, 0].copy() if len(data) else None

    def close(self) -> None:
        self._fh.close()


class _PcmDecoder:
    """Raw s16le bytes to float32 samples, carrying an odd byte across reads."""

    def __init__(self) -> None:
        self._carry = b""

    def decode(self, data: bytes) -> np.ndarray:
        data = self._carry + data
        whole = len(data) // 2 * 2
        self._carry = data[whole:]
        return np.frombuffer(data[:whole], dtype="<i2").astype(np.float32) / 32768.0


class StdinVoice(VoiceSource):
    """``--self -``: raw PCM on standard input; its end is the voice's end."""

    def __init__(self, rate: int, stream: BinaryIO | None = None) -> None:
        self.rate = rate
        self.describe = "stdin"
        self._fd = (stream or sys.stdin.buffer).fileno()
        self._pcm = _PcmDecoder()

    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        ready, _, _ = select.select([self._fd], [], [], timeout)
        if not ready:
            return np.zeros(0, np.float32)
        data = os.read(self._fd, 2 * int(max_samples))
        return self._pcm.decode(data) if data else None


class TcpVoice(VoiceSource):
    """``--self tcp://HOST:PORT``: listens there; a speaker connects and writes raw PCM (after
    its token line when ``token`` is set: always off loopback)."""

    finite = False

    def __init__(self, spec: str, rate: int) -> None:
        self.rate = rate
        host, port, given = parse_tcp(spec)
        self.describe = spec.split("?", 1)[0]  # the token stays out of the report
        self.token = token_for(host, given)
        self._server = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._server.bind((host, port))
            self._server.listen(1)
        except OSError as exc:
            self._server.close()
            problem = "the port is busy" if exc.errno in (98, 48) else exc.strerror or str(exc)
            raise UserError(f"--self {self.describe}: cannot listen there ({problem})") from None
        self.port = self._server.getsockname()[1]
        self._conn: socket.socket | None = None
        self._peer = ""
        self._waiting_token: bytes | None = None
        """What an unauthenticated speaker has sent so far (None once it is let in)."""
        self._token_due = 0.0
        self._pcm = _PcmDecoder()
        self._events: list[str] = []
        self.connections = 0
        self.refused = 0

    def read(self, max_samples: int, timeout: float) -> np.ndarray | None:
        if self._conn is None:
            ready, _, _ = select.select([self._server], [], [], timeout)
            if ready:
                self._conn, peer = self._server.accept()
                self._conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._peer = f"{peer[0]}:{peer[1]}"
                self._pcm = _PcmDecoder()
                self._waiting_token = b"" if self.token is not None else None
                self._token_due = time.monotonic() + TOKEN_SECONDS
                if self._waiting_token is None:
                    self._admit()
            return np.zeros(0, np.float32)
        ready, _, _ = select.select([self._conn], [], [], timeout)
        if not ready:
            if self._waiting_token is not None and time.monotonic() > self._token_due:
                self._hang_up(f"speaker from {self._peer} refused: no token in {TOKEN_SECONDS:g} s", refused=True)
            return np.zeros(0, np.float32)
        try:
            data = self._conn.recv(2 * int(max_samples))
        except OSError as exc:
            data = b""
            self._events.append(f"speaker connection failed ({exc.strerror or exc})")
        if not data:
            self._hang_up("speaker hung up", refused=self._waiting_token is not None)
            return np.zeros(0, np.float32)
        if self._waiting_token is not None:
            data = self._check_token(data)
        return self._pcm.decode(data)

    def _check_token(self, data: bytes) -> bytes:
        """Collect the speaker's first line; let it in when it is the token. What follows is PCM."""
        assert self.token is not None and self._waiting_token is not None
        line = self._waiting_token + data
        if b"\n" not in line:
            self._waiting_token = line
            if len(line) > len(self.token) + 2:
                self._hang_up(f"speaker from {self._peer} refused: wrong token", refused=True)
            return b""
        given, _, rest = line.partition(b"\n")
        if not token_matches(given.rstrip(b"\r"), self.token):
            self._hang_up(f"speaker from {self._peer} refused: wrong token", refused=True)
            return b""
        self._admit()
        return rest

    def _admit(self) -> None:
        self._waiting_token = None
        self.connections += 1
        self._events.append(f"speaker connected from {self._peer}")

    def _hang_up(self, event: str, refused: bool) -> None:
        assert self._conn is not None
        self._conn.close()
        self._conn = None
        self._waiting_token = None
        self.refused += refused
        self._events.append(event)

    def streaming(self) -> bool:
        return self._conn is not None and self._waiting_token is None

    def events(self) -> list[str]:
        out, self._events = self._events, []
        return out

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._server.close()


def parse_tcp(spec: str) -> tuple[str, int, str | None]:
    """HOST, PORT and the token (``?token=T``; None when not given) of ``tcp://HOST:PORT``."""
    parsed = urllib.parse.urlsplit(spec)
    try:
        port = parsed.port
    except ValueError:
        port = None
    query = urllib.parse.parse_qs(parsed.query, keep_blank_values=True)
    unknown = set(query) - {"token"}
    if parsed.scheme != "tcp" or not parsed.hostname or port is None or parsed.path not in ("", "/") or unknown:
        raise UserError(
            f"--self {spec.split('?', 1)[0]}: expected tcp://HOST:PORT or tcp://HOST:PORT?token=T, such as tcp://127.0.0.1:5100"
        )
    token = query["token"][-1] if "token" in query else None
    problem = token_problem(token) if token is not None else None
    if problem is not None:
        raise UserError(f"--self {spec.split('?', 1)[0]}: {problem}")
    return parsed.hostname, port, token


def open_voice(spec: str, rate: int) -> VoiceSource:
    """The source ``--self`` names (a ``UserError`` for a missing file or a busy port)."""
    if spec == "none":
        return NoVoice()
    if spec == "-":
        return StdinVoice(rate)
    if spec.startswith("tcp:"):
        return TcpVoice(spec, rate)
    return FileVoice(Path(spec))


class SelfVoiceFeeder(threading.Thread):
    """Keeps the voice queued ``lead`` to ``lead + jitter`` seconds ahead of the speaker.

    ``heard`` gives the position (in ring samples) the speaker has reached, or its stand-in when
    nothing is played (``--self none``). Whatever goes into the ``ring`` also goes, resampled, into
    ``analysis``; without a ring only the analysis time line advances. ``speaker_stopped`` says why
    the speaker was given up (``Playback.stopped``): from then on the voice is paced by the clock
    and goes to the analysis alone, so the mouth and the run go on without it.
    """

    def __init__(
        self,
        source: VoiceSource,
        ring: SampleRing | None,
        rate: int,
        analysis: Timeline,
        heard: Callable[[], int],
        lead: float,
        jitter: float,
        clock_now: Callable[[], float],
        speaker_stopped: Callable[[], str | None] | None = None,
    ) -> None:
        super().__init__(name="self-voice", daemon=True)
        self.source = source
        self.ring = ring
        self.rate = rate
        self.analysis = analysis
        self.heard = heard
        self.low_water = int(round(lead * rate))
        self.high_water = int(round((lead + jitter) * rate))
        self.clock_now = clock_now
        self.speaker_stopped = speaker_stopped
        self.speaker_lost = False
        self.unheard_samples = 0
        """Voice queued after the speaker was given up: the analysis had it, nobody heard it."""
        self._to_ring = StreamResampler(source.rate, rate) if source.rate != rate else None
        self._to_analysis = StreamResampler(rate, ANALYSIS_RATE)
        self._pending = np.zeros(0, np.float32)
        self._halt = threading.Event()
        self.written = 0
        """Ring samples queued so far (voice and silence)."""
        self.voice_samples = 0
        self.ended_at: int | None = None
        """Ring position where a finite voice ended."""
        self.stalls = 0
        self.stalled_samples = 0
        self._stalled = False
        self._stall_len = 0
        self._voice_last = False
        """The last thing queued was voice (not silence)."""
        self.events: list[dict[str, Any]] = []
        self.error: BaseException | None = None

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        try:
            while not self._halt.is_set():
                self._step()
        except BaseException as exc:  # handed to the pipeline, which reports it
            self.error = exc
            self._event(f"self voice failed: {exc.__class__.__name__}: {exc}")
            while not self._halt.wait(POLL_SECONDS):  # the speaker and the clock go on, silent
                self._top_up(stall=False)
        finally:
            self.source.close()

    def _step(self) -> None:
        if self.ring is not None and self.speaker_stopped is not None:
            reason = self.speaker_stopped()
            if reason is not None:
                self._lose_speaker(reason)
        if len(self._pending):  # the ring was full last time: offer the rest first
            self._commit(np.zeros(0, np.float32))
        if self.ended_at is not None or len(self._pending) or self._space() <= 0:
            time.sleep(POLL_SECONDS)  # plenty queued, or nothing more will come
            self._top_up(stall=False)
            return
        want = max(1, min(self._space(), int(READ_SECONDS * self.rate)) * self.source.rate // self.rate)
        data = self.source.read(want, POLL_SECONDS)
        for text in self.source.events():
            self._event(text)
        if data is None:
            self._end()
        elif len(data):
            self._voice(data)
            return
        self._top_up(stall=self.ended_at is None)  # the source had nothing just now

    def _lose_speaker(self, reason: str) -> None:
        """Pace the voice by the clock from now on; the ring (and what it still holds) is left."""
        self.ring = None
        self.speaker_lost = True
        self.heard = lambda: int(max(self.clock_now(), 0.0) * self.rate)
        self._event(f"{reason}: the self voice goes on unheard, paced by the clock")

    def _space(self) -> int:
        if self.ring is None:
            return max(self.heard() + self.high_water - self.written, 0)
        return self.ring.space()

    def _voice(self, data: np.ndarray) -> None:
        if self._to_ring is not None:
            data = self._to_ring.push(data)
        if self._stalled:
            self._stalled = False
            self._event(f"self voice resumed after {1000.0 * self._stall_len / self.rate:.0f} ms of silence")
        self._voice_last = True
        self.voice_samples += len(data)
        if self.speaker_lost:
            self.unheard_samples += len(data)
        self._commit(data)

    def _end(self) -> None:
        if self._to_ring is not None:
            self._commit(self._to_ring.finish())
        self.ended_at = self.written + len(self._pending)
        if not isinstance(self.source, NoVoice):
            self._event("self voice ended")

    def _top_up(self, stall: bool) -> None:
        """Queue silence when the voice runs low, so the speaker and the generator never wait."""
        level = self.written + len(self._pending) - self.heard()
        if level >= self.low_water:
            return
        fill = self.high_water - level
        if self._stalled and not self.source.streaming():
            self._stalled = False  # the speaker hung up: this silence is nobody's stall
        if stall and self.source.streaming() and self._voice_last:
            self.stalls += 1  # the speaker is connected but its voice ran out, mid-sentence or not
            self._stalled, self._stall_len = True, 0
            self._event("self voice ran out while its speaker is connected: silence until more comes")
        if self._stalled:
            self._stall_len += fill
            self.stalled_samples += fill
        self._voice_last = False
        self._commit(np.zeros(fill, np.float32))

    def _commit(self, new: np.ndarray) -> None:
        """Queue ``new`` after anything left over; what the ring cannot take yet waits."""
        data = np.concatenate([self._pending, new]) if len(self._pending) else new
        used = self.ring.write(data) if self.ring is not None else len(data)
        self._pending = data[used:]
        self.written += used
        self.analysis.append(self._to_analysis.push(data[:used]))

    def _event(self, text: str) -> None:
        self.events.append({"time": round(self.clock_now(), 3), "event": text})

    def report(self) -> dict[str, Any]:
        return {
            "source": self.source.describe,
            "sample_rate": self.source.rate,
            "voice_seconds": round(self.voice_samples / self.rate, 3),
            "lead_ms": round(1000.0 * self.low_water / self.rate, 1),
            "queued_ms": round(1000.0 * self.high_water / self.rate, 1),
            "stalls": self.stalls,
            "stalled_ms": round(1000.0 * self.stalled_samples / self.rate, 1),
            "unheard_ms": round(1000.0 * self.unheard_samples / self.rate, 1),
            "events": self.events,
        }
