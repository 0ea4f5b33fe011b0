"""The ``convodrive`` command. Subcommands live in sibling modules, each with ``register``.

User mistakes (``UserError``, bad arguments) print one line on stderr and exit with code 2; a
traceback means a bug in convodrive, never a user error.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from convodrive import __version__
from convodrive.plumbing.errors import UserError

# Each module defines ``register(subparsers)``, which adds its subcommand and sets ``func``.
COMMAND_MODULES: tuple[str, ...] = (
    "convodrive.cli.drive",
    "convodrive.cli.demo",
    "convodrive.cli.plugins",
    "convodrive.cli.eval",
    "convodrive.cli.render",
    "convodrive.cli.emulate",
    "convodrive.cli.servo",
    "convodrive.cli.corpus",
)

EXIT_USER_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse prints usage plus an error; we print the error alone, on one line."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(EXIT_USER_ERROR)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="convodrive",
        description="Conversation audio to embodied motion: avatar previews, MuJoCo humanoids, servo heads.",
    )
    parser.add_argument("--version", action="version", version=f"convodrive {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    subparsers.required = True
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        sys.stderr.write(f"convodrive: error: {exc}\n")
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        sys.stderr.write("convodrive: interrupted\n")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
