"""The ``convodrive`` command. Subcommands live in sibling modules, each with ``register``.

User mistakes (``UserError``, bad arguments) print one line on stderr and exit with code 2; a
traceback means a bug in convodrive, never a user error. Events during a run (hardware faults,
backend health, warnings) are logged as they happen (``convodrive.plumbing.logs``): ``-v``,
``-q`` and ``--log-file`` go before or after the subcommand.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from convodrive import __version__
from convodrive.plumbing.errors import EXIT_USER_ERROR, OneLineParser, UserError
from convodrive.plumbing.logs import FILE_ONLY, configure_logging

log = logging.getLogger("convodrive.cli")

# Each module defines ``register(subparsers)``, which adds its subcommand and sets ``func``.
COMMAND_MODULES: tuple[str, ...] = (
    "convodrive.cli.drive",
    "convodrive.cli.live",
    "convodrive.cli.demo",
    "convodrive.cli.plugins",
    "convodrive.cli.eval",
    "convodrive.cli.render",
    "convodrive.cli.avatar",
    "convodrive.cli.emulate",
    "convodrive.cli.servo",
    "convodrive.cli.corpus",
    "convodrive.cli.train",
    "convodrive.cli.export",
)


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
    _add_logging_options(parser)
    return parser


def _add_logging_options(parser: argparse.ArgumentParser, nested: bool = False) -> None:
    """``-v``/``-q``/``--log-file`` on the command and on every subcommand, so they go anywhere on
    the line (a subcommand's copy leaves the value unset unless given there)."""
    unset = argparse.SUPPRESS
    group = parser.add_argument_group("logging")
    group.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=unset if nested else 0,
        help="also log progress (-vv: debugging detail) on stderr",
    )
    group.add_argument("-q", "--quiet", action="store_true", default=unset if nested else False, help="log errors only")
    group.add_argument(
        "--log-file",
        type=Path,
        metavar="FILE",
        default=unset if nested else None,
        help="append the run's log, with time stamps, to FILE",
    )
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases share one parser
                _add_logging_options(sub, nested=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        configure_logging(args.verbose, args.quiet, args.log_file)
        log.debug("convodrive %s: %s", __version__, " ".join(sys.argv[1:] if argv is None else argv))
        return int(args.func(args) or 0)
    except UserError as exc:
        sys.stderr.write(f"convodrive: error: {exc}\n")
        log.error("%s", exc, extra=FILE_ONLY)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        sys.stderr.write("convodrive: interrupted\n")
        log.warning("interrupted", extra=FILE_ONLY)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
