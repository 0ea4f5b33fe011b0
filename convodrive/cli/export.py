"""``convodrive export CHECKPOINT --out MODEL_DIR [--int8 [--float GRAPH,...]]``: ONNX graphs, model.json, model card."""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from convodrive.plumbing.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export",
        help="export a training checkpoint to an ONNX model folder (parity-checked)",
        description="Export CHECKPOINT (a checkpoint folder, or a run folder: its latest) to an ONNX model folder.",
    )
    p.add_argument("checkpoint", type=Path, help="checkpoint folder (runs/.../checkpoints/step-N) or run folder")
    p.add_argument("--out", type=Path, required=True, help="model folder to write (replaced if it is one)")
    p.add_argument("--int8", action="store_true", help="quantise MatMuls to int8 (dynamic) and record the cost")
    p.add_argument(
        "--float",
        dest="keep_float",
        metavar="GRAPH[,GRAPH...]",
        default="",
        help="with --int8: keep these graphs float (where int8 costs most, e.g. a denoiser's step)",
    )
    p.add_argument(
        "--onto",
        type=Path,
        metavar="MODEL_DIR",
        help="write MODEL_DIR with only --graphs exported anew from this run (its other graphs kept to the bit)",
    )
    p.add_argument("--graphs", default="", metavar="NAME[,NAME...]", help="with --onto: the graphs to replace")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from convodrive.training.export import export_model

    keep_float = [name for name in args.keep_float.split(",") if name]
    if args.graphs and args.onto is None:
        raise UserError("--graphs names the graphs --onto replaces: it needs --onto MODEL_DIR")
    if args.onto is not None:
        return _graft(args, keep_float)
    result = export_model(args.checkpoint, args.out, int8=args.int8, keep_float=keep_float)
    worst = max(e for errs in result.parity.values() for e in errs.values())
    print(f"exported {len(result.parity)} graph(s) to {result.folder} (parity max abs err {worst:.2g})")
    if result.int8:
        for name, cost in result.int8.items():
            print(f"  int8 {name}: max abs {cost['max_abs_err']:.3g}, relative RMS {cost['relative_rms_err']:.3g}")
    return 0


def _graft(args: argparse.Namespace, keep_float: list[str]) -> int:
    from convodrive.training.export import export_model
    from convodrive.training.graft import check_onto, graft

    names = [name for name in args.graphs.split(",") if name]
    check_onto(args.onto, names)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{args.out.name}.export.", dir=args.out.parent))
    try:
        result = export_model(args.checkpoint, scratch / "run", int8=args.int8, keep_float=keep_float)
        graft(result.folder, args.onto, names, args.out)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    print(f"wrote {args.out}: {args.onto} with {', '.join(names)} exported from {args.checkpoint}")
    return 0
