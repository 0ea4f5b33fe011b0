"""User-facing errors.

A ``UserError`` is a mistake the user can fix (a bad file, a bad option). The CLI prints its
message as one line on stderr and exits with code 2; it never shows a traceback for one. The
message must name the file or option and the problem.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

EXIT_USER_ERROR = 2


class UserError(Exception):
    """A problem with the user's input, reported as one line, never as a traceback."""


class InputFileError(UserError):
    """A file given by the user cannot be used. The message starts with the file's path."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


def os_reason(exc: OSError) -> str:
    """``permission denied`` rather than ``[Errno 13] Permission denied: '/x'``, for one-line messages."""
    reason = exc.strerror or exc.__class__.__name__
    return reason[:1].lower() + reason[1:]


class RemoteError(Exception):
    """An exception raised in another process (a backend's own), known by its one-line text."""


def error_line(exc: BaseException, limit: int = 300) -> str:
    """``"OSError: port vanished"`` on one line; an error from another process reads as it did there."""
    text = " ".join(str(exc).split())
    line = text if isinstance(exc, RemoteError) else f"{exc.__class__.__name__}: {text}"
    return line if len(line) <= limit else line[: limit - 1] + "…"


class OneLineParser(argparse.ArgumentParser):
    """argparse prints usage plus an error; we print the error alone, on one line, exit code 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(EXIT_USER_ERROR)
