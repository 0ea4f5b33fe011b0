"""``convodrive demo``: the main job on embedded defaults.

The bundled two-speaker dialogue through the procedural generator into every body we ship: the
recorder (motion .npz, BVH, Live Link CSV), the avatar preview video, the MuJoCo humanoid video,
and an emulated Dynamixel servo head driven through the real SDK over a pseudo-terminal. A body
whose extra is not installed is skipped with a note, never an error.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from convodrive.cli.drive import print_result
from convodrive.cli.progress import frame_progress
from convodrive.pipeline import DEFAULT_GENERATOR, DriveRequest, drive
from convodrive.plugins import BACKEND_GROUP, load_plugin
from convodrive.plumbing.errors import UserError

DEMO_BACKENDS = ("record", "render", "mujoco", "dynamixel")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="run the bundled dialogue through every body (no setup needed)",
        description="Drive the bundled two-speaker dialogue into the recorder, the avatar preview, "
        "the MuJoCo humanoid and an emulated servo head, and print where the outputs are.",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("convodrive-demo"),
        metavar="DIR",
        help="output folder (default: ./convodrive-demo)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument(
        "--only",
        default=",".join(DEMO_BACKENDS),
        metavar="NAME[,NAME]",
        help=f"backends to include (default: {','.join(DEMO_BACKENDS)})",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from convodrive.samples import bundled_dialogue

    wanted = [n.strip() for n in args.only.split(",") if n.strip()]
    backends: list[str] = []
    for name in wanted:
        try:
            load_plugin(BACKEND_GROUP, name)
            backends.append(name)
        except UserError as exc:
            print(f"demo: skipping {name}: {exc}")
    if not backends:
        raise UserError("demo: no backend is available")
    with contextlib.ExitStack() as stack:
        backend_options: dict[str, dict[str, Any]] = {"render": {"camera": "upper"}} if "render" in backends else {}
        if "dynamixel" in backends:
            backend_options["dynamixel"] = stack.enter_context(_emulated_servo_head())
        request = DriveRequest(
            audio=bundled_dialogue(),
            generator=DEFAULT_GENERATOR,
            backends=tuple(backends),
            out_dir=args.out,
            seed=args.seed,
            backend_options=backend_options,
        )
        with frame_progress("demo") as progress:
            result = drive(request, on_frame=progress)
    print_result(result)
    return 0


@contextlib.contextmanager
def _emulated_servo_head() -> Iterator[dict[str, Any]]:
    """Start the stateful Dynamixel emulator on a pty and yield the backend options to reach it."""
    from convodrive.backends.servo.dynamixel_emulator import start_emulated_head

    with start_emulated_head() as head:
        # The emulator answers from a thread of this busy process (the renderer and MuJoCo share
        # the GIL), so allow its status packets more time than a real bus would need.
        yield {"port": head.port, "latency_ms": 40}
