"""``convodrive train MODEL --corpus DIR [--preset NAME] [--steps N] [--out DIR]``.

torch is imported only when the command runs, so the CLI a drive loads stays torch-free.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from convodrive.training.command import add_train_arguments

    p = subparsers.add_parser(
        "train",
        help="train a learned model on a corpus (torch; resumable; DDP under torchrun)",
        description="Train a registered model on a corpus. Many processes: torchrun --nproc_per_node N -m convodrive.training MODEL ...",
    )
    add_train_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from convodrive.training.command import run_train

    return run_train(args)
