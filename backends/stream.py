"""Backend ``stream``: every frame over a WebSocket, and a browser page that shows the avatar live.

One port serves both: ``/`` is the page (three.js, shipped in ``backends/web/``, no CDN), which
loads the mannequin as glTF (``/mannequin.glb``: the renderer's mesh, skin and 52 ARKit morph
targets) and opens ``/ws``. Each frame is one message: compact JSON, or binary (``format``):

- binary, little-endian: uint32 frame index, float32 time (s), uint32 state, uint32 0, then
  float32: root translation (3), the 55 joints' local rotations as quaternions x, y, z, w (220),
  the 52 ARKit weights (52), voice activity of self and partner (2). 1124 bytes.
- JSON: ``{"i": index, "t": time, "s": state, "tr": [3], "q": [220], "f": [52], "v": [2]}``.

A client first gets ``{"type": "hello", ...}`` naming the joints, the channels and the format.
In a live run frames go out when their sound leaves the speaker, so a page on the same machine
moves with the voice it hears. The server binds 127.0.0.1 unless ``host`` says otherwise; off
loopback it asks for a token (``token``, or a fresh one), which the page's URL carries (the page
then keeps it in a cookie for its own requests). A request whose ``Host`` is not the server's
own name (DNS rebinding), or whose ``Origin`` is another site's (a page open in the same browser
reading the motion), is refused (``convodrive.plumbing.access``). A slow client skips frames;
nobody waits for it.
"""

from __future__ import annotations

import asyncio
import dataclasses
import http
import json
import sys
import threading
import urllib.parse
from collections.abc import Mapping
from importlib.resources import files
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, Session
from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_NAMES
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.access import host_allowed, token_for, token_matches, token_problem
from convodrive.plumbing.errors import UserError

HEADER_WORDS = 4
LAYOUT = {"translation": 3, "rotations": 4 * len(JOINT_NAMES), "face": len(ARKIT_NAMES), "vad": 2}
WRITE_BUFFER_LIMIT = 256 * 1024
"""A client with this much unsent is too slow: it skips frames until it catches up."""
COOKIE = "convodrive_token"
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".glb": "model/gltf-binary"}


@dataclasses.dataclass(frozen=True)
class StreamOptions(PluginOptions):
    host: str = option("127.0.0.1", help="Address to listen on (0.0.0.0: every interface, then a token is needed)")
    port: int = option(8765, low=0, high=65535, help="Port of the page and the WebSocket (0: any free port)")
    format: str = option("binary", choices=("binary", "json"), help="How frames travel: binary (1124 bytes) or JSON")
    token: str | None = option(
        None, help="Token the page's URL must carry; default: none on loopback, else a fresh one"
    )

    def __post_init__(self) -> None:
        problem = token_problem(self.token) if self.token is not None else None
        if problem is not None:
            raise ValueError(f"option 'token': {problem}")


class StreamBackend(Backend):
    name = "stream"
    description = "Frames over a WebSocket, and a browser page (three.js) showing the avatar live"
    realtime = True
    requires = ("websockets",)
    extra = "live"
    Options = StreamOptions
    options: StreamOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.server: StreamServer | None = None
        self.sent = 0

    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        o = self.options
        token = token_for(o.host, o.token)
        hello = {
            "type": "hello",
            "fps": session.fps,
            "format": o.format,
            "joints": list(JOINT_NAMES),
            "face": list(ARKIT_NAMES),
            "header_words": HEADER_WORDS,
            "layout": LAYOUT,
        }
        self.server = StreamServer(o.host, o.port, token, json.dumps(hello))
        self.server.start()
        sys.stderr.write(f"convodrive: stream: the live page is at {self.server.url}\n")
        sys.stderr.flush()

    def send(self, frame: TargetFrame) -> None:
        assert self.server is not None
        message = encode_binary(frame) if self.options.format == "binary" else encode_json(frame)
        self.server.broadcast(message)
        self.sent += 1

    def close(self) -> None:
        if self.server is not None:
            self.server.stop()

    def report(self) -> dict[str, Any]:
        if self.server is None:
            return {}
        return {
            "url": self.server.url.split("?")[0],
            "token": self.server.token is not None,
            "frames": self.sent,
            "clients": self.server.clients_seen,
            "messages": self.server.messages,
            "skipped_for_slow_clients": self.server.skipped,
        }


def _quaternions_xyzw(pose: np.ndarray) -> np.ndarray:
    wxyz = rotations.axis_angle_to_quat(pose)
    return np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)


def encode_binary(frame: TargetFrame) -> bytes:
    m = frame.motion
    header = np.array([frame.index, 0, int(m.state), 0], "<u4")
    header[1:2] = np.array([frame.time], "<f4").view("<u4")
    body = np.concatenate([m.translation, _quaternions_xyzw(m.pose).reshape(-1), m.face, m.vad]).astype("<f4")
    return header.tobytes() + body.tobytes()


def encode_json(frame: TargetFrame) -> str:
    m = frame.motion
    return json.dumps(
        {
            "i": frame.index,
            "t": round(frame.time, 4),
            "s": int(m.state),
            "tr": np.round(m.translation, 4).tolist(),
            "q": np.round(_quaternions_xyzw(m.pose).reshape(-1), 4).tolist(),
            "f": np.round(m.face, 3).tolist(),
            "v": np.round(m.vad, 3).tolist(),
        },
        separators=(",", ":"),
    )


class StreamServer:
    """The page and the WebSocket on one port, run by an asyncio loop in a thread of its own."""

    def __init__(self, host: str, port: int, token: str | None, hello: str) -> None:
        self.host, self.port, self.token, self.hello = host, port, token, hello
        self.clients: set[Any] = set()
        self.clients_seen = 0
        self.messages = 0
        self.skipped = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="stream-server", daemon=True)
        self._server: Any = None
        self._avatar = _Avatar()

    @property
    def url(self) -> str:
        host = self.host if ":" not in self.host else f"[{self.host}]"
        query = f"?token={urllib.parse.quote(self.token)}" if self.token else ""
        return f"http://{host}:{self.port}/{query}"

    def start(self) -> None:
        from websockets.asyncio.server import serve

        async def listen() -> Any:
            # open_timeout bounds the handshake, which includes answering the page's request for
            # the avatar: on a loaded machine its first build can take longer than the default 10 s.
            return await serve(
                self._session, self.host, self.port, process_request=self._http, compression=None, open_timeout=60
            )

        self._thread.start()
        future = asyncio.run_coroutine_threadsafe(listen(), self._loop)
        try:
            self._server = future.result(timeout=10)
        except OSError as exc:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
            problem = "the port is busy" if exc.errno in (98, 48) else exc.strerror or str(exc)
            raise UserError(f"backend stream: cannot listen on {self.host}:{self.port} ({problem})") from None
        self.port = self._server.sockets[0].getsockname()[1]
        self._avatar.start()

    def stop(self) -> None:
        if self._server is None:
            return

        async def shut() -> None:
            self._server.close()
            await self._server.wait_closed()

        try:
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(timeout=5)
        except Exception:
            pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)
        self._server = None

    def broadcast(self, message: bytes | str) -> None:
        """Hand a frame to the loop; it goes to every client not too far behind."""
        self._loop.call_soon_threadsafe(self._broadcast, message)

    def _broadcast(self, message: bytes | str) -> None:
        from websockets.asyncio.server import broadcast

        ready = []
        for client in self.clients:
            if client.transport.get_write_buffer_size() > WRITE_BUFFER_LIMIT:
                self.skipped += 1
            else:
                ready.append(client)
        broadcast(ready, message)
        self.messages += len(ready)

    async def _session(self, connection: Any) -> None:
        self.clients_seen += 1
        await connection.send(self.hello)
        self.clients.add(connection)
        try:
            await connection.wait_closed()
        finally:
            self.clients.discard(connection)

    async def _http(self, connection: Any, request: Any) -> Any:
        """Serve the page and its files; let an authorised ``/ws`` through to the WebSocket."""
        url = urllib.parse.urlsplit(request.path)
        query = urllib.parse.parse_qs(url.query)
        host = request.headers.get("Host", "")
        if not host_allowed(host, self.host):
            return _response(http.HTTPStatus.FORBIDDEN, b"this server answers to its own address only\n")
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() != f"http://{host}".lower():
            return _response(http.HTTPStatus.FORBIDDEN, b"only the page this server serves may connect\n")
        given = (query.get("token") or [""])[0] or _cookie(request.headers.get("Cookie", ""), COOKIE)
        if self.token is not None and not token_matches(given, self.token):
            return _response(http.HTTPStatus.FORBIDDEN, b"a token is needed: use the URL convodrive printed\n")
        if url.path == "/ws":
            return None
        if url.path == "/mannequin.glb":
            try:
                body = await asyncio.wrap_future(self._avatar.future)
            except Exception as exc:
                reason = f"the avatar could not be built: {exc.__class__.__name__}: {exc}\n"
                return _response(http.HTTPStatus.INTERNAL_SERVER_ERROR, reason.encode())
            return _response(http.HTTPStatus.OK, body, ".glb")
        path = "index.html" if url.path in ("/", "/index.html") else url.path.lstrip("/")
        data = _page_file(path)
        if data is None:
            return _response(http.HTTPStatus.NOT_FOUND, b"not found\n")
        response = _response(http.HTTPStatus.OK, data, "." + path.rsplit(".", 1)[-1])
        if self.token is not None and path == "index.html":
            response.headers["Set-Cookie"] = f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
        return response


def _cookie(header: str, name: str) -> str:
    for part in header.split(";"):
        key, _, value = part.strip().partition("=")
        if key == name:
            return value
    return ""


def _response(status: http.HTTPStatus, body: bytes, suffix: str = "") -> Any:
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    headers = Headers(
        {
            "Content-Type": _TYPES.get(suffix, "text/plain; charset=utf-8"),
            "Content-Length": str(len(body)),
            "Cache-Control": "no-store",
            "Connection": "close",
        }
    )
    return Response(status.value, status.phrase, headers, body)


def _page_file(path: str) -> bytes | None:
    """A file of the page (``backends/web``), or None; never anything outside that folder."""
    parts = path.split("/")
    if not path or any(p in ("", ".", "..") or p.startswith(".") for p in parts):
        return None
    resource = files("convodrive.backends").joinpath("web", *parts)
    return resource.read_bytes() if resource.is_file() else None


class _Avatar:
    """The mannequin as glTF, built once in the background (a few seconds) while the run starts."""

    def __init__(self) -> None:
        import concurrent.futures

        self.future: concurrent.futures.Future[bytes] = concurrent.futures.Future()

    def start(self) -> None:
        # Imported here, on the thread that opens the backend, before the producer starts: the
        # builder thread's first import of scipy raced the producer's import of scipy.signal, and
        # one of the two failed with KeyError: 'scipy'.
        from convodrive.backends.avatar.gltf_write import glb_bytes, rig_to_gltf
        from convodrive.backends.avatar.mannequin import build_mannequin

        def build() -> None:
            try:
                self.future.set_result(glb_bytes(*rig_to_gltf(build_mannequin())))
            except BaseException as exc:  # the page then shows why; frames still flow
                self.future.set_exception(exc)

        # Running before anyone waits: a request that gives up (its wrap_future cancelled) would
        # otherwise cancel the one shared build, and every later request would fail with it.
        self.future.set_running_or_notify_cancel()
        threading.Thread(target=build, name="stream-avatar", daemon=True).start()
