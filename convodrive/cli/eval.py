"""``convodrive eval behaviour MOTION.npz AUDIO``: behaviour figures of a motion clip as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from convodrive.audio.source import AudioSource, ChannelMap
from convodrive.cli.options import name_list, scoped_key_value
from convodrive.eval.segments import load_segments
from convodrive.motion.npz import load_clip
from convodrive.plumbing.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("eval", help="evaluate generated motion", description="Evaluate generated motion.")
    sub = p.add_subparsers(dest="eval_command", metavar="WHAT", parser_class=type(p))
    sub.required = True
    b = sub.add_parser(
        "behaviour",
        help="lip sync, mouth closure, speaking and listening behaviour (JSON)",
        description=(
            "Print behaviour figures of MOTION (a convodrive .npz) against the AUDIO it was made from, as JSON: "
            "lip sync and mouth closure, the clip's voice activity, and head motion, blinks, nods, smiles, posture "
            "and gaze while speaking and while listening."
        ),
    )
    b.add_argument("motion", help="motion clip (.npz written by convodrive)")
    b.add_argument("audio", help="the conversation audio (channel 0 self, 1 partner unless --channels)")
    b.add_argument(
        "--channels", default=None, help="SELF,OTHER channel numbers of the audio (e.g. 0,1; OTHER may be -)"
    )
    b.add_argument(
        "--segments",
        default=None,
        metavar="FILE",
        help="who really spoke when: JSON (a list of {start, end, speaker}, or the turns sidecar of "
        "samples/dialogue.json) or Audacity labels (START<TAB>END<TAB>self|partner); without it, "
        "speech is found from each channel's level, which hears microphone bleed as speech",
    )
    b.set_defaults(func=run_behaviour)
    c = sub.add_parser(
        "compare",
        help="score generators and baselines on a corpus split (table, JSON, plot)",
        description="Run each method over a corpus split and score it against take 0 of each conversation with the "
        "papers' metrics (FD_g, FD_k, Div_*, FGD, Var, BC, lip sync, listening). Methods: ground-truth, random, knn, "
        "or any generator plugin (e.g. procedural). Writes compare.md, compare.json and compare.png.",
    )
    c.add_argument("--corpus", required=True, type=Path, help="corpus folder")
    c.add_argument("--split", default="test", choices=("train", "val", "test"), help="which split to score on")
    c.add_argument(
        "--generators",
        required=True,
        help="comma-separated methods, e.g. ground-truth,procedural,knn,random; LABEL=GENERATOR scores a generator "
        "under a label of its own (e.g. probtalk-T1=probtalk), so one generator can run with several settings",
    )
    c.add_argument(
        "-G",
        "--generator-option",
        type=scoped_key_value("METHOD", "probtalk-T1.iterations=1"),
        action="append",
        default=[],
        metavar="METHOD.KEY=VALUE",
        help="option of one compared generator (by its name or label), repeatable",
    )
    c.add_argument("--out", required=True, type=Path, help="folder for compare.md, compare.json, compare.png")
    c.add_argument("--samples", type=int, default=4, help="samples per conversation (Div_sample, Var)")
    c.add_argument("--seed", type=int, default=0, help="seed of generators and of the random baseline")
    c.add_argument(
        "--seeds",
        type=int,
        default=1,
        metavar="N",
        help="repeat at seeds SEED..SEED+N-1: each figure is their mean, with their spread (default: 1)",
    )
    c.add_argument("--max-conversations", type=int, default=None, help="score only the first N conversations")
    c.add_argument(
        "--stratum",
        default=None,
        metavar="KIND",
        help="score only conversations of one kind (synthesised, paired, recorded: corpus make's)",
    )
    c.add_argument(
        "--speakers",
        type=name_list,
        default=(),
        metavar="NAME[,NAME]",
        help="score only these speakers' conversations (the corpus's speaker styles; default: all)",
    )
    c.add_argument("--fgd-model", type=Path, default=None, help="FGD embedder model folder (default: the shipped one)")
    c.set_defaults(func=run_compare)


def run_compare(args: argparse.Namespace) -> int:
    from convodrive.eval.table import markdown
    from convodrive.pipeline.compare import CompareRequest, compare

    names = tuple(n.strip() for n in args.generators.split(",") if n.strip())
    options: dict[str, dict[str, Any]] = {}
    for method, key, value in args.generator_option:
        options.setdefault(method, {})[key] = value
    result = compare(
        CompareRequest(
            corpus=args.corpus,
            generators=names,
            out=args.out,
            split=args.split,
            samples=args.samples,
            seed=args.seed,
            seeds=args.seeds,
            max_conversations=args.max_conversations,
            stratum=args.stratum,
            speakers=args.speakers,
            fgd_model=args.fgd_model,
            generator_options=options,
        ),
        on_method=lambda name: print(f"scoring {name} ...", file=sys.stderr, flush=True),
    )
    print(markdown(result.results, f"eval compare: {args.corpus}").split("\n\n")[1])
    print("wrote " + ", ".join(str(p) for p in result.outputs))
    return 0


def run_behaviour(args: argparse.Namespace) -> int:
    from convodrive.eval.behaviour import behaviour_figures

    try:
        channels = ChannelMap.parse(args.channels) if args.channels else None
    except ValueError as exc:
        raise UserError(str(exc)) from None
    clip = load_clip(args.motion)
    source = AudioSource(args.audio, channels)
    audio = source.read_all()
    reference = None
    if args.segments:
        mapping = source.channel_map
        reference = load_segments(args.segments, mapping.self_channel, mapping.other_channel)
    try:
        figures = behaviour_figures(clip, audio, reference)
    except UserError as exc:
        raise UserError(f"{args.motion}: {exc}") from None
    print(json.dumps({"motion": str(args.motion), "audio": str(args.audio), **figures}, indent=2))
    return 0
