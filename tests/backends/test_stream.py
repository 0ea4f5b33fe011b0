"""``stream``: frames over a WebSocket as the page reads them; the token off loopback; a busy port."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from convodrive.motion import rotations
from convodrive.motion.npz import load_clip
from tests.conftest import run_cli

pytestmark = [pytest.mark.live, pytest.mark.espeak]


def start_drive(audio: Path, out: Path, *options: str) -> tuple[subprocess.Popen, str]:
    """A real-time drive into the stream backend; returns the process and the page's URL."""
    run = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "drive", str(audio), "--realtime", "--backend", "stream,record",
         "--out", str(out), "-B", "stream.port=0", *options],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy(),
    )  # fmt: skip
    assert run.stderr is not None
    for line in run.stderr:
        if "the live page is at" in line:
            return run, line.split(" at ", 1)[1].strip()
    run.wait()
    raise AssertionError("the stream backend never said where its page is")


def receive_all(url: str, **headers: str) -> tuple[dict, list]:
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    ws_url = url.replace("http://", "ws://").replace("/?", "/ws?").rstrip("/")
    if "/ws" not in ws_url:
        ws_url += "/ws"
    messages = []
    with connect(ws_url, additional_headers=headers or None) as ws:
        hello = json.loads(ws.recv(timeout=30))
        try:
            while True:
                messages.append(ws.recv(timeout=30))
        except ConnectionClosed:
            pass
    return hello, messages


def decode_binary(message: bytes, hello: dict) -> dict:
    words = np.frombuffer(message[: 4 * hello["header_words"]], "<u4")
    floats = np.frombuffer(message[4 * hello["header_words"] :], "<f4")
    layout = hello["layout"]
    cut = np.cumsum([layout["translation"], layout["rotations"], layout["face"]])
    tr, q, face, vad = np.split(floats, cut)
    return {"i": int(words[0]), "s": int(words[2]), "tr": tr, "q": q, "f": face, "v": vad}


@pytest.mark.parametrize("fmt", ["binary", "json"])
def test_every_frame_reaches_a_client(tmp_path: Path, talk: Path, fmt: str) -> None:
    run, url = start_drive(talk, tmp_path, "-B", f"stream.format={fmt}")
    try:
        assert "token" not in url, "loopback needs no token"
        hello, messages = receive_all(url)
        run.wait(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, run.stderr.read()[-3000:] if run.stderr else ""
    assert hello["type"] == "hello" and hello["format"] == fmt and len(hello["joints"]) == 55
    frames = [decode_binary(m, hello) if fmt == "binary" else json.loads(m) for m in messages]
    if fmt == "binary":
        assert all(len(m) == 1124 for m in messages)
    clip = load_clip(tmp_path / "motion.npz")
    first = frames[0]["i"]  # the client connects once the run has begun
    assert first < clip.num_frames / 2 and len(frames) >= 0.9 * (clip.num_frames - first)
    tol = 1e-6 if fmt == "binary" else 6e-4
    for frame in frames[::5]:
        k = frame["i"]
        np.testing.assert_allclose(frame["f"], clip.face[k], atol=tol)
        q = rotations.axis_angle_to_quat(clip.pose[k])
        np.testing.assert_allclose(
            np.reshape(frame["q"], (55, 4)), np.concatenate([q[:, 1:], q[:, :1]], 1), atol=tol * 2
        )
        np.testing.assert_allclose(frame["v"], clip.vad[k], atol=tol)
    entry = json.loads((tmp_path / "run_report.json").read_text())["backends"]["stream"]
    report = entry["report"]
    # A real-time worker on a loaded machine may skip a frame for a newer one; each is counted.
    assert report["clients"] == 1 and report["frames"] == entry["frames_sent"]
    assert entry["frames_sent"] + entry["frames_dropped"] == clip.num_frames and not entry["errors"]


def test_off_loopback_a_token_is_needed(tmp_path: Path, talk: Path) -> None:
    run, url = start_drive(talk, tmp_path, "-B", "stream.host=0.0.0.0")
    try:
        assert "?token=" in url
        local = url.replace("0.0.0.0", "127.0.0.1")
        bare = local.split("?")[0]
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(bare, timeout=10)
        assert refused.value.code == 403
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(bare + "?token=wrong-token-here", timeout=10)
        page = urllib.request.urlopen(local, timeout=10)
        assert page.status == 200 and b"live.js" in page.read()
        cookie = page.headers["Set-Cookie"].split(";")[0]
        from websockets.exceptions import InvalidStatus

        with pytest.raises(InvalidStatus):
            receive_all(bare)
        hello, messages = receive_all(bare, Cookie=cookie)  # what the page itself does
        run.wait(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    assert hello["type"] == "hello" and len(messages) > 30


def test_a_busy_port_is_one_line(tmp_path: Path, talk: Path) -> None:
    held = socket.socket()
    held.bind(("127.0.0.1", 0))
    held.listen(1)
    port = held.getsockname()[1]
    try:
        done = run_cli("drive", str(talk), "--backend", "stream", "--out", str(tmp_path), "-B", f"stream.port={port}")
    finally:
        held.close()
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"convodrive: error: backend stream: cannot listen on 127.0.0.1:{port} (the port is busy)"
    ]


def test_page_files_stay_inside_the_page(tmp_path: Path, talk: Path) -> None:
    run, url = start_drive(talk, tmp_path)
    try:
        for path in ("vendor/three/three.module.js", "vendor/three/LICENSE", "live.js"):
            assert urllib.request.urlopen(url + path, timeout=10).status == 200
        for path in ("../stream.py", "%2e%2e/stream.py", "vendor/three/../../../stream.py", ".hidden"):
            with pytest.raises(urllib.error.HTTPError) as err:
                urllib.request.urlopen(url + path, timeout=10)
            assert err.value.code == 404
    finally:
        run.kill()
        run.wait()


def _handshake(port: int, host: str, origin: str | None) -> str:
    """A WebSocket upgrade as a browser sends it, with the given Host and Origin; the status line."""
    lines = [
        "GET /ws HTTP/1.1",
        f"Host: {host}",
        "Connection: Upgrade",
        "Upgrade: websocket",
        "Sec-WebSocket-Version: 13",
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
    ]
    if origin is not None:
        lines.append(f"Origin: {origin}")
    with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
        conn.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        return conn.makefile("rb").readline().decode().strip()


def test_other_sites_and_rebound_names_are_refused(tmp_path: Path, talk: Path) -> None:
    """On loopback no token is asked, so the server checks who asks: a Host that is not its own
    name (DNS rebinding: evil.example re-pointed at 127.0.0.1) and an upgrade from another site's
    page (Origin) get 403; the page's own origin, and a client that sends none, get through."""
    run, url = start_drive(talk, tmp_path)
    try:
        port = int(urllib.parse.urlsplit(url).port or 0)
        own = f"127.0.0.1:{port}"
        assert _handshake(port, "evil.example:8765", "http://evil.example:8765").startswith("HTTP/1.1 403")
        assert _handshake(port, own, "http://evil.example").startswith("HTTP/1.1 403")
        assert _handshake(port, own, "null").startswith("HTTP/1.1 403")
        assert _handshake(port, f"localhost:{port}", f"http://localhost:{port}").startswith("HTTP/1.1 101")
        assert _handshake(port, own, f"http://{own}").startswith("HTTP/1.1 101")
        assert _handshake(port, own, None).startswith("HTTP/1.1 101")
        request = urllib.request.Request(url, headers={"Host": "evil.example"})
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=10)
        assert refused.value.code == 403
        assert urllib.request.urlopen(url, timeout=10).status == 200
        run.wait(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0


def test_a_request_that_gives_up_leaves_the_avatar_to_the_next() -> None:
    """The page's request for the avatar can be cancelled while the mannequin is built (its
    handshake timed out on a loaded machine, the page went away): the one shared build goes on, and
    the next request gets it. A cancelled waiter used to cancel the build, so the page never got
    its avatar and the builder thread died on setting a cancelled future's result."""
    import asyncio

    from convodrive.backends.stream import _Avatar

    avatar = _Avatar()
    avatar.start()

    async def give_up_then_ask_again() -> bytes:
        waiter = asyncio.ensure_future(asyncio.wrap_future(avatar.future))
        await asyncio.sleep(0)
        waiter.cancel()
        with pytest.raises(asyncio.CancelledError):
            await waiter
        return await asyncio.wait_for(asyncio.wrap_future(avatar.future), 120)

    assert asyncio.run(give_up_then_ask_again())[:4] == b"glTF"
