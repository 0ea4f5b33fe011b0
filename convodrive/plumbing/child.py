"""Child Python processes that run one function and talk to their parent over a pipe.

multiprocessing's ``spawn`` imports the parent's ``__main__`` again in every child, so a user's
script that calls ``drive`` without an ``if __name__ == "__main__"`` guard would start its whole
run again in each child. A child here is a fresh interpreter on this module instead: it receives
the function to run (by module and name) and its arguments over the pipe, and never sees the
parent's main. It is a plain ``subprocess.Popen``, so its exit status reads as usual (negative:
killed by that signal).
"""

from __future__ import annotations

import importlib
import socket
import subprocess
import sys
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any


def start_child(function: Callable[..., Any], *args: Any) -> tuple[subprocess.Popen[bytes], Connection]:
    """Run ``function(connection, *args)`` in a new interpreter; return the process and our end.

    ``function`` must be importable by module and name, and ``args`` picklable. The child shares
    this process's stdout and stderr, so a crash there still shows its traceback.
    """
    ours, theirs = socket.socketpair()
    fd = theirs.fileno()
    try:
        process = subprocess.Popen([sys.executable, "-m", __name__, str(fd)], pass_fds=(fd,), stdin=subprocess.DEVNULL)
    finally:
        theirs.close()
    conn = Connection(ours.detach())
    conn.send((function.__module__, function.__qualname__, args))
    return process, conn


def _run(fd: int) -> None:
    conn = Connection(fd)
    module, name, args = conn.recv()
    function = getattr(importlib.import_module(module), name)
    function(conn, *args)


if __name__ == "__main__":
    _run(int(sys.argv[1]))
