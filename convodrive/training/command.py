"""The arguments of ``convodrive train`` and ``python -m convodrive.training`` (torchrun), defined once."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from convodrive.plumbing.errors import UserError


def add_train_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="a registered model (e.g. fgd)")
    p.add_argument("--corpus", required=True, type=Path, help="corpus folder (convodrive corpus make / import)")
    p.add_argument("--preset", default=None, help="hyper-parameter preset of the model (default: the model's own)")
    p.add_argument("--stage", default=None, help="training stage, for models trained in stages")
    p.add_argument("--steps", type=int, default=None, help="optimiser steps in all (a resumed run continues to this)")
    p.add_argument("--batch-size", type=int, default=None, help="global batch size (split across DDP processes)")
    p.add_argument("--seed", type=int, default=None, help="seed of initialisation and batch order")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="run folder (default runs/MODEL-PRESET-STAGE); resumed if it holds checkpoints",
    )
    p.add_argument(
        "--device", default="auto", choices=("auto", "cpu", "cuda"), help="where to train (auto: CUDA when present)"
    )
    p.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one model or training setting (JSON value), repeatable",
    )
    p.add_argument(
        "--init",
        type=Path,
        action="append",
        default=None,
        metavar="RUN",
        help="start from the weights of another run or checkpoint of the model (e.g. its previous stage); "
        "repeatable, for a stage that builds on several runs",
    )
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads per process (default 1)")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes that assemble the next batches ahead (default: none on the CPU, up to 6 on CUDA)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def parse_settings(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise UserError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = json.loads(text)
        except json.JSONDecodeError:
            out[key.strip()] = text
    return out


def run_train(args: argparse.Namespace) -> int:
    from convodrive.training.loop import TrainRequest, train

    result = train(
        TrainRequest(
            model=args.model,
            corpus=args.corpus,
            preset=args.preset,
            stage=args.stage,
            out=args.out,
            steps=args.steps,
            batch_size=args.batch_size,
            seed=args.seed,
            device=args.device,
            threads=args.threads,
            workers=args.workers,
            init=args.init,
            progress=not args.no_progress,
            settings=parse_settings(args.settings),
        )
    )
    if result.checkpoint is not None and int(__import__("os").environ.get("RANK", "0")) == 0:
        figures = ", ".join(f"{k} {v:.4g}" for k, v in result.validation.items())
        print(
            f"trained {args.model} to step {result.step} ({result.steps_per_second:.2f} steps/s): {result.checkpoint}",
            file=sys.stdout,
        )
        if figures:
            print(f"validation: {figures}")
    return 0
