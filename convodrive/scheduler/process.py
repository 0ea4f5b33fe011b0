"""A backend in a child process of its own, so that its work cannot hold up the clock.

The avatar renderer and MuJoCo spend tens of milliseconds a frame in C calls that keep the GIL,
and compete with the clock for the CPU; in one process with the clock they delay its wake-ups by
10 to 100 ms. ``ProcessBackend`` is a Backend that runs the real one in a spawned child and
forwards each call to it over a pipe:

- Calls are synchronous: the parent's worker thread sends a call (a frame pickles to about 1.5 kB)
  and waits for the answer with the GIL released. The worker's mailbox stays in the parent, so the
  scheduler's rules (drop-oldest for real-time backends, a backlog for files) are unchanged.
- A child that feeds files runs at a lower CPU priority (``FILE_NICE``), since its outputs may lag
  while the parent paces hardware; a real-time child asks for a higher one (``REALTIME_NICE``).
- The child ignores SIGINT (Ctrl-C reaches the whole process group; the parent's scheduler decides
  what it means) and closes its backend on SIGTERM or when the parent's end of the pipe closes, so
  its outputs end complete whoever stops the run.
- Its health, errors, report, outputs and close errors come back through the pipe. The child
  dying, or not answering for ``CALL_TIMEOUT_S``, is a failure of this backend alone: ``send``
  raises ``BackendFailed`` and ``health`` says why.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from convodrive.backends.base import Backend, BackendFailed, Session
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plumbing.child import start_child
from convodrive.plumbing.errors import RemoteError, UserError, error_line
from convodrive.plumbing.priority import HelperPriority

FILE_NICE = 5
"""A child that feeds files takes this much less CPU priority: its outputs may lag, the clock not."""
REALTIME_NICE = -10
"""A real-time child (hardware, a live window) asks for the clock's weight (granted to root or with
CAP_SYS_NICE; otherwise it keeps its parent's)."""
OPEN_TIMEOUT_S = 120.0
"""Starting Python, importing the backend's libraries and opening it (GL, a model)."""
CALL_TIMEOUT_S = 60.0
"""One frame or query; a child that takes longer is taken to be hung and is killed."""
CLOSE_TIMEOUT_S = 300.0
"""Finishing the outputs (the video encoder's tail)."""


class ProcessBackend(Backend):
    """Runs ``inner`` (made, validated, not opened) in a child process; see the module docstring."""

    light = True  # this side only pickles a frame and waits on the pipe

    def __init__(self, inner: Backend, *, nice: int | None = None) -> None:
        super().__init__(inner.options)
        self.name = inner.name  # type: ignore[misc]  # instances take the inner backend's identity
        self.description = inner.description  # type: ignore[misc]
        self.realtime = inner.realtime  # type: ignore[misc]
        self.hardware = inner.hardware  # type: ignore[misc]
        self.inner_class = type(inner)
        self.nice = (REALTIME_NICE if inner.realtime else FILE_NICE) if nice is None else nice
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._process: subprocess.Popen[bytes] | None = None
        self._dead: str | None = None
        """Why the child takes no more calls (it died, hung, or closed on its own)."""
        self._final: dict[str, Any] | None = None
        """What the child said when it closed: health, report, outputs, close error."""
        self._last_health: dict[str, Any] = {"status": "ok"}

    # ------------------------------------------------------------------ the contract
    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        self._process, self._conn = start_child(serve, self.inner_class, self.options, self.nice, self.realtime)
        try:
            self._call("open", (spec, session), OPEN_TIMEOUT_S)
        except BaseException:
            try:
                self.close()
            except RemoteError:
                pass  # the open error is the one to report
            raise

    def send(self, frame: TargetFrame) -> float | None:
        """The child's answer is its backend's: when the frame left (the same clock: ``CLOCK_MONOTONIC``
        is system-wide), so the way back through the pipe is not counted as the frame's latency."""
        left = self._call("send", (frame,), CALL_TIMEOUT_S)
        return left if isinstance(left, float) else None

    def health(self) -> dict[str, Any]:
        if self._final is not None:
            return self._with_process(self._final["health"])
        if self._dead is None:
            try:
                self._last_health = self._call("health", (), CALL_TIMEOUT_S)
                return self._with_process(self._last_health)
            except (BackendFailed, RemoteError):
                pass
        return self._with_process({**self._last_health, "status": "failed", "reason": self._dead})

    def hurry(self) -> None:
        process = self._process
        if process is not None and process.poll() is None:
            process.send_signal(signal.SIGUSR1)

    def close(self) -> None:
        """Ask the child to close its backend and wait for its final word; raise its close error."""
        with self._lock:
            if self._process is None or self._conn is None:
                return
            if self._dead is None:
                try:
                    self._conn.send(("close", ()))
                    kind, value = self._receive(CLOSE_TIMEOUT_S)
                    if kind == "closed":
                        self._final = value
                except (BackendFailed, OSError):
                    pass
            if _wait(self._process, 5.0) is None:  # closed, yet not exiting: nothing of it is needed
                self._process.kill()
                _wait(self._process, 5.0)
            self._conn.close()
            self._conn = None
        if self._final is None:
            raise RemoteError(f"it could not be closed: {self._dead or 'its process did not answer'}")
        if self._final.get("close_error"):
            raise RemoteError(self._final["close_error"])

    def report(self) -> dict[str, Any]:
        if self._final is not None:
            return self._with_process(self._final["report"])
        return self._with_process({"error": self._dead or "no report: the backend's process never closed"})

    def outputs(self) -> list[Path]:
        return [Path(p) for p in self._final["outputs"]] if self._final is not None else []

    # ------------------------------------------------------------------ the pipe
    def _call(self, method: str, args: tuple[Any, ...], timeout: float) -> Any:
        """Send one call and return the child's answer; raise what it raised, or BackendFailed."""
        with self._lock:
            if self._dead is not None:
                raise BackendFailed(self._dead)
            if self._conn is None:
                raise RuntimeError(f"{self.name}: {method}() before open()")
            try:
                self._conn.send((method, args))
            except OSError:  # the child's end is gone; _receive says how it ended
                pass
            kind, value = self._receive(timeout)
        if kind == "ok":
            return value
        if kind == "user":
            raise UserError(value)
        if kind == "error":
            raise RemoteError(value)
        self._final = value  # "closed": it closed its backend on its own (SIGTERM)
        self._dead = "its process was sent SIGTERM and closed the backend"
        raise BackendFailed(self._dead)

    def _receive(self, timeout: float) -> tuple[str, Any]:
        assert self._conn is not None and self._process is not None
        try:
            if self._conn.poll(timeout):
                kind, value = self._conn.recv()
                return str(kind), value
        except (EOFError, OSError):
            self._dead = f"its process died ({_exit_text(_wait(self._process, 2.0))})"
            raise BackendFailed(self._dead) from None
        self._dead = f"its process did not answer for {timeout:.0f} s and was stopped"
        self._process.kill()
        raise BackendFailed(self._dead)

    def _with_process(self, data: dict[str, Any]) -> dict[str, Any]:
        process = self._process
        info: dict[str, Any] = {"pid": process.pid if process is not None else None, "nice": self.nice}
        if process is not None and process.poll() is not None:
            info["exit"] = _exit_text(process.returncode)
        return {**data, "process": info}


def _wait(process: subprocess.Popen[bytes], timeout: float) -> int | None:
    """The exit status, waiting up to ``timeout`` s for it; None while it still runs."""
    try:
        return process.wait(timeout)
    except subprocess.TimeoutExpired:
        return None


def _exit_text(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


# ---------------------------------------------------------------------- the child
class _Terminated(BaseException):
    """SIGTERM in the child while it waits for a call: stop serving and close the backend."""


def serve(
    conn: Connection, backend_class: type[Backend], options: dict[str, Any], nice: int, realtime: bool = False
) -> None:
    """The child's main: answer calls until ``close``, SIGTERM or the parent's end closing, then
    close the backend and send back its health, report, outputs and close error.

    A real-time backend's calls (a servo head's frames) are answered under real-time scheduling
    below the parent's clock (``HelperPriority``), so a busy machine cannot hold a frame back for
    longer than the parent's slot keeps it. A hardware backend's own threads (a servo head's
    supervisor, which polls the bus and waits for its replies) share it: a frame waits for the bus
    and the interpreter lock they hold, which at ordinary priority were preempted with both held.
    Others' (a live window's video encoder) get ordinary scheduling."""
    state = {"busy": False, "terminated": False}

    def terminate(_signum: int, _frame: Any) -> None:
        state["terminated"] = True
        if not state["busy"]:  # waiting for a call: stop now; in a call: after it, at the loop's top
            raise _Terminated

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, terminate)
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass
    backend = backend_class(options)
    signal.signal(signal.SIGUSR1, lambda _s, _f: backend.hurry())
    priority = HelperPriority(realtime, f"backend {backend.name}", inherit=backend.hardware)
    try:
        with priority:
            while not state["terminated"]:
                try:
                    method, args = conn.recv()
                except (EOFError, OSError):  # the parent is gone: finish the outputs anyway
                    break
                state["busy"] = True
                if method == "close":
                    break
                try:
                    answer: tuple[str, Any] = ("ok", getattr(backend, method)(*args))
                except UserError as exc:
                    answer = ("user", str(exc))
                except Exception as exc:
                    answer = ("error", error_line(exc))
                priority.tick()
                conn.send(answer)
                state["busy"] = False
    except _Terminated:
        pass
    finally:
        state["busy"] = True  # the outputs are being finished: a SIGTERM now waits for them
        close_error = None
        try:
            backend.close()
        except Exception as exc:
            close_error = error_line(exc)
        final = {
            "health": _safe(backend.health, "reason"),
            "report": _safe(backend.report, "error"),
            "outputs": [str(p) for p in _safe_list(backend.outputs)],
            "close_error": close_error,
        }
        try:
            conn.send(("closed", final))
        except OSError:
            pass
        conn.close()


def _safe(fn: Any, key: str) -> dict[str, Any]:
    try:
        return dict(fn())
    except Exception as exc:
        return {key: error_line(exc)}


def _safe_list(fn: Any) -> list[Any]:
    try:
        return list(fn())
    except Exception:
        return []
