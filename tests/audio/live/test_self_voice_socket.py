"""``--self tcp://HOST:PORT``: off loopback a speaker must send the token first. Every speaker
here connects on 127.0.0.1 (a token given there is asked for too); a socket bound to every
interface is only opened to see that it asks for a token, and closed before anyone connects."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from convodrive.audio.live.self_voice import TcpVoice
from convodrive.plumbing.errors import UserError


def _pump(voice: TcpVoice, seconds: float = 0.5) -> tuple[np.ndarray, list[str]]:
    """Read what the voice gives for a while, as the feeder would."""
    got, events, end = [], [], time.monotonic() + seconds
    while time.monotonic() < end:
        data = voice.read(1600, 0.01)
        assert data is not None
        got.append(data)
        events += voice.events()
    return np.concatenate(got), events


def _speak(port: int, first: bytes, samples: np.ndarray) -> socket.socket:
    conn = socket.create_connection(("127.0.0.1", port), timeout=5)
    conn.sendall(first + (samples * 32767).astype("<i2").tobytes())
    return conn


def test_every_interface_needs_a_token() -> None:
    voice = TcpVoice("tcp://0.0.0.0:0", 16000)
    voice.close()
    assert voice.token is not None and len(voice.token) >= 16, "a fresh token off loopback"


def test_a_speaker_without_the_token_is_refused() -> None:
    voice = TcpVoice("tcp://127.0.0.1:0?token=my-own-secret", 16000)
    try:
        assert voice.token == "my-own-secret" and "secret" not in voice.describe
        tone = np.full(800, 0.5, np.float32)
        for first in (b"", b"wrong-token-guess\n"):
            conn = _speak(voice.port, first, tone)
            got, events = _pump(voice)
            conn.close()
            assert not np.any(got), "PCM without the token is never played"
            assert any("refused" in e for e in events), events
        conn = _speak(voice.port, voice.token.encode() + b"\n", tone)
        got, events = _pump(voice)
        conn.close()
        assert any(e.startswith("speaker connected from 127.0.0.1") for e in events), events
        np.testing.assert_allclose(got[got != 0], 0.5, atol=1e-4)
        assert np.count_nonzero(got) == len(tone)
        assert voice.connections == 1 and voice.refused == 2
    finally:
        voice.close()


def test_loopback_needs_none() -> None:
    voice = TcpVoice("tcp://127.0.0.1:0", 16000)
    try:
        assert voice.token is None
        conn = _speak(voice.port, b"", np.full(400, 0.25, np.float32))
        got, _ = _pump(voice)
        conn.close()
        assert np.count_nonzero(got) == 400
    finally:
        voice.close()


@pytest.mark.parametrize("spec", ["tcp://0.0.0.0:0?token=short", "tcp://0.0.0.0:0?tokn=abcdefghij"])
def test_a_bad_token_option_is_one_line(spec: str) -> None:
    with pytest.raises(UserError) as error:
        TcpVoice(spec, 16000)
    assert "\n" not in str(error.value) and "--self tcp://0.0.0.0:0" in str(error.value)
