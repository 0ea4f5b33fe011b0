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
