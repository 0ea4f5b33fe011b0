"""``convodrive demo``: the main job on embedded defaults.

The bundled two-speaker dialogue through the procedural generator into every body we ship: the
recorder (motion .npz, BVH, Live Link CSV), the avatar preview video, the MuJoCo humanoid video,
and an emulated Dynamixel servo head driven through the real SDK over a pseudo-terminal. A body
whose extra is not installed is skipped with a note, never an error. With the renderer, it then
films the dialogue through ``procedural``, ``probtalk`` and ``a2p`` side by side, so a user sees the
default and the two papers' models at once. ``--audio`` runs a conversation of the user's own
instead of the bundled one.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from convodrive.cli.drive import exit_code, print_result
from convodrive.cli.progress import drain_progress, frame_progress
from convodrive.pipeline import drive
from convodrive.pipeline.demo import DEMO_BACKENDS, SIDE_BY_SIDE_GENERATORS, demo_request, side_by_side
from convodrive.plugins import BACKEND_GROUP, load_plugin
from convodrive.plumbing.errors import UserError


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
    p.add_argument(
        "--audio",
        type=Path,
        metavar="AUDIO",
        help="a conversation of your own (channel 0 = self, 1 = partner) instead of the bundled dialogue",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    p.add_argument(
        "--only",
        default=",".join(DEMO_BACKENDS),
        metavar="NAME[,NAME]",
        help=f"backends to include (default: {','.join(DEMO_BACKENDS)})",
    )
    p.add_argument(
        "--no-side-by-side",
        dest="side_by_side",
        action="store_false",
        help=f"skip the video of {', '.join(SIDE_BY_SIDE_GENERATORS)} side by side",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
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
    with demo_request(args.out, backends, args.seed, args.audio) as request, frame_progress("demo") as progress:
        result = drive(request, on_frame=progress, on_drain=drain_progress(progress, "demo"))
    print_result(result)
    if args.side_by_side and "render" in backends and not result.report.get("interrupted"):
        print(f"demo: filming {', '.join(SIDE_BY_SIDE_GENERATORS)} side by side")
        films = side_by_side(args.out, seed=args.seed, audio=args.audio)
        for name, reason in films.skipped.items():
            print(f"demo: side by side without {name}: {reason}")
        if films.video is not None:
            print(f"wrote {films.video} ({', '.join(films.generators)} side by side)")
    return exit_code(result)
