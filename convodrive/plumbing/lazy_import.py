"""Heavy modules imported on first use, once, whichever thread gets there first.

``scipy.signal`` takes seconds to import, which listing plugins or ``--help`` should not pay, so
it is imported when a filter or resampler first runs. In a live run that first use can come from
two threads at once (the capture thread's resampler and the producer's motion filters), and
CPython's import of the same package from two threads raced there: one thread's import failed with
``KeyError: 'scipy'`` and stopped the run. The lock makes the second thread wait for the first
thread's import.

The lock only orders imports that go through it. A worker thread must not import anything else a
run's other threads may be importing: what it needs is imported before it starts (the stream
backend's avatar builder imports scipy.sparse on the opening thread for that reason; its first
import of scipy on its own thread raced the producer's and failed the same way).
"""

from __future__ import annotations

import importlib
import threading
from types import ModuleType

_LOCK = threading.Lock()
_SCIPY_SIGNAL: ModuleType | None = None


def scipy_signal() -> ModuleType:
    """``scipy.signal``, imported under a lock the first time (filters call this every chunk)."""
    global _SCIPY_SIGNAL
    if _SCIPY_SIGNAL is None:
        with _LOCK:
            if _SCIPY_SIGNAL is None:
                _SCIPY_SIGNAL = importlib.import_module("scipy.signal")
    return _SCIPY_SIGNAL
