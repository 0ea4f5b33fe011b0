"""scipy.signal imported on first use from many threads at once, as a live run's capture and
producer threads do: every thread gets the module, and none pays the import at load time."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import REPO

_PROGRAM = """
import sys, threading
import convodrive.audio.resample, convodrive.generators.procedural.signals
assert "scipy.signal" not in sys.modules, "imported at load"
from convodrive.plumbing.lazy_import import scipy_signal
start, got, errors = threading.Barrier(8), [], []
def use():
    start.wait()
    try:
        got.append(scipy_signal().lfilter)
    except Exception as exc:
        errors.append(repr(exc))
threads = [threading.Thread(target=use) for _ in range(8)]
for t in threads: t.start()
for t in threads: t.join()
assert not errors, errors
assert len(got) == 8 and len(set(map(id, got))) == 1
print("ok")
"""


def test_first_use_from_many_threads_at_once_gets_one_module() -> None:
    done = subprocess.run([sys.executable, "-c", _PROGRAM], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


_AVATAR_PROGRAM = """
import builtins, importlib.util, sys, threading
from convodrive.backends.stream import _Avatar
imported_off_main = []
plain_import = builtins.__import__
def watched(name, globals=None, locals=None, fromlist=(), level=0):
    full = importlib.util.resolve_name("." * level + name, (globals or {}).get("__package__")) if level else name
    if threading.current_thread() is not threading.main_thread() and full not in sys.modules:
        imported_off_main.append(full)
    return plain_import(name, globals, locals, fromlist, level)
builtins.__import__ = watched
avatar = _Avatar()
avatar.start()
assert avatar.future.result(timeout=120)[:4] == b"glTF"
assert not imported_off_main, imported_off_main
print("ok")
"""


def test_stream_avatar_builder_thread_imports_nothing() -> None:
    """The builder's modules (scipy among them) are imported before its thread starts, so that
    thread cannot race the producer's first import of scipy.signal."""
    done = subprocess.run(
        [sys.executable, "-c", _AVATAR_PROGRAM], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]
