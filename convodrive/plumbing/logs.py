"""Logging for the command line: one stderr line per event as it happens, and an optional log file.

Every module logs through ``logging.getLogger(__name__)``; this sets up the ``convodrive`` logger
once per command. On stderr: warnings and errors by default, ``-v`` adds progress (info),
``-vv`` debugging detail, ``-q`` errors only, each as ``convodrive: LEVEL: message``. A log file
(``--log-file``) takes info and up (debug with ``-vv``) with time stamps, plus what is only meant
for it: the one-line user errors the CLI prints itself, and the run's summary.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from convodrive.plumbing.errors import UserError

LOGGER = "convodrive"
FILE_ONLY = {"console": False}
"""``extra=`` for a record the console shows in another form already (a printed error or summary)."""


class _Console(logging.Handler):
    """Writes to whatever ``sys.stderr`` is at the time, so a progress bar that redirects it
    (rich) prints the line above itself, and pytest's capture sees it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:
            self.handleError(record)


class _Format(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"convodrive: {record.levelname.lower()}: {record.getMessage()}"


def _console_wanted(record: logging.LogRecord) -> bool:
    return getattr(record, "console", True)


def console_level(verbose: int, quiet: bool) -> int:
    if quiet:
        return logging.ERROR
    return {0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG)


def configure_logging(verbose: int = 0, quiet: bool = False, log_file: str | os.PathLike[str] | None = None) -> None:
    """(Re)configure the ``convodrive`` logger for one command; calling it again replaces the setup."""
    logger = logging.getLogger(LOGGER)
    for handler in [h for h in logger.handlers if getattr(h, "_convodrive", False)]:
        logger.removeHandler(handler)
        handler.close()
    console = _Console()
    console.setLevel(console_level(verbose, quiet))
    console.setFormatter(_Format())
    console.addFilter(_console_wanted)
    _install(logger, console)
    if log_file is not None:
        path = Path(log_file)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            file_handler = logging.FileHandler(path, mode="a", encoding="utf-8")
        except OSError as exc:
            raise UserError(f"--log-file {path}: cannot write ({(exc.strerror or str(exc)).lower()})") from None
        file_handler.setLevel(logging.DEBUG if verbose >= 2 else logging.INFO)
        file_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
        _install(logger, file_handler)


def _install(logger: logging.Logger, handler: logging.Handler) -> None:
    handler._convodrive = True  # type: ignore[attr-defined]
    logger.addHandler(handler)
    logger.setLevel(min(h.level for h in logger.handlers))
