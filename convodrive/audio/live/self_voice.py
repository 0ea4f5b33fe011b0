"""The robot's own voice in a live run: where it comes from (``audio.live.feeder`` keeps it queued).

``--self`` names the source: a file (played at its own rate), ``-`` (raw PCM on stdin), or
``tcp://HOST:PORT`` (a local socket an agent's speech synthesiser connects to and writes raw PCM
into; one speaker at a time, and the next may connect after one hangs up), or ``none``. Raw PCM is
signed 16-bit little-endian mono at ``--self-rate``. Off loopback the socket asks for a token
(``tcp://HOST:PORT?token=T``, or a fresh one the run prints): a speaker first sends it as one
line, then its PCM (``convodrive.plumbing.access``).
"""

from __future__ import annotations

import abc
import os
import select
import socket
import sys
import time
import urllib.parse
from pathlib import Path
from typing import BinaryIO

import numpy as np
import soundfile as sf

from convodrive.audio.source import ANALYSIS_RATE, AudioDecodeError, AudioSource, ChannelMap
from convodrive.plumbing.access import token_for, token_matches, token_problem
from convodrive.plumbing.errors import UserError

TOKEN_SECONDS = 5.0
"""A speaker off loopback has this long to send its token line before it is hung up on."""


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
