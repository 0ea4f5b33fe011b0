"""``python -m convodrive.training MODEL --corpus DIR ...``: the same as ``convodrive train``, for
``torchrun --nproc_per_node N -m convodrive.training ...`` (DDP)."""

from __future__ import annotations

import sys

from convodrive.plumbing.errors import EXIT_USER_ERROR, OneLineParser, UserError
from convodrive.training.command import add_train_arguments, run_train


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(
        prog="python -m convodrive.training",
        description="Train a registered model (one process or DDP under torchrun).",
    )
    add_train_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_train(args)
    except UserError as exc:
        sys.stderr.write(f"convodrive: error: {exc}\n")
        return EXIT_USER_ERROR


if __name__ == "__main__":
    raise SystemExit(main())
