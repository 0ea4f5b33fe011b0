"""``convodrive corpus``: make a training corpus, import one, or check one.

convodrive corpus make --hours H --out DIR [--seed N] [--jobs N] [--voices DIR [--voice-hours H]] [--conversations DIR]
convodrive corpus import KIND SRC --out DIR [--seed N] [--mano FILE]
convodrive corpus info DIR
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from convodrive.cli.options import int_in, number_in
from convodrive.cli.progress import frame_progress
from convodrive.corpus.importers import KINDS as IMPORT_KINDS
from convodrive.corpus.manifest import SPLITS
from convodrive.corpus.reader import Corpus
from convodrive.plumbing.errors import UserError

if TYPE_CHECKING:
    from convodrive.corpus.maker import Recorded


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "corpus", help="make, import or check a training corpus", description="Make, import or check a training corpus."
    )
    sub = p.add_subparsers(dest="corpus_command", metavar="WHAT", parser_class=type(p))
    sub.required = True
    make = sub.add_parser(
        "make",
        help="make a training corpus (espeak-ng conversations and your recordings, procedural motion)",
        description="Make HOURS of dyadic espeak-ng conversations with K takes of procedural motion each "
        "(several languages, voices and speaker styles), in parallel, into a new folder DIR. Recorded speech "
        "joins them: --voices pairs single-voice recordings (a sub-folder of WAV/FLAC utterances per speaker) "
        "into dialogues timed like the espeak-ng ones; --conversations takes two-channel recordings (self, "
        "partner) as they are, turns from NAME.json/NAME.txt segments beside each or from voice activity. "
        'Each such folder holds a source.json naming its licence: {"licence": "...", "language": "en"}.',
    )
    make.add_argument(
        "--hours",
        type=number_in(0.0, 1000.0),
        default=None,
        metavar="H",
        help="hours of espeak-ng conversation (needed unless --voices or --conversations is given; 0: none)",
    )
    make.add_argument(
        "--voices", type=Path, action="append", default=[], metavar="DIR", help="recorded voices to pair (repeatable)"
    )
    make.add_argument(
        "--voice-hours",
        type=number_in(0.001, 1000.0),
        default=None,
        metavar="H",
        help="hours of dialogue paired from --voices (default: as long as their utterances together)",
    )
    make.add_argument(
        "--conversations",
        type=Path,
        action="append",
        default=[],
        metavar="DIR",
        help="two-channel recorded conversations to take as they are (repeatable)",
    )
    make.add_argument("--out", type=Path, required=True, metavar="DIR", help="new (or empty) corpus folder")
    make.add_argument("--seed", type=int_in(0, 2**31 - 1), default=0, help="the same seed makes the same corpus")
    make.add_argument(
        "--jobs", type=int_in(1, 256), default=None, metavar="N", help="worker processes (default: every core)"
    )
    make.add_argument("--takes", type=int_in(1, 16), default=4, metavar="K", help="motion takes per conversation (4)")
    make.set_defaults(func=run_make)
    imp = sub.add_parser(
        "import",
        help="import a corpus you have (BEAT2, SHOW, Seamless Interaction, your own recordings)",
        description="Import the corpus in SRC into a new corpus folder DIR. KIND: "
        + "; ".join(f"{k}: {where}" for k, (_, where) in IMPORT_KINDS.items()),
    )
    imp.add_argument("kind", choices=tuple(IMPORT_KINDS), metavar="KIND", help=", ".join(IMPORT_KINDS))
    imp.add_argument("src", type=Path, metavar="SRC", help="the folder the corpus is in")
    imp.add_argument("--out", type=Path, required=True, metavar="DIR", help="new (or empty) corpus folder")
    imp.add_argument("--seed", type=int_in(0, 2**31 - 1), default=0, help="seed of the train/val/test draw")
    imp.add_argument("--speaker", metavar="LABEL", help="speaker label for every conversation")
    imp.add_argument(
        "--mano",
        type=Path,
        metavar="FILE",
        help="show: hand PCA components (SMPL-X model .npz or TalkSHOW hand_component.json); without it hands are masked",
    )
    imp.set_defaults(func=run_import)
    info = sub.add_parser(
        "info",
        help="check a corpus and summarise it",
        description="Open DIR, check every shard, array and audio file, and print a summary (JSON with --json).",
    )
    info.add_argument("folder", type=Path, metavar="DIR", help="corpus folder (holds manifest.json)")
    info.add_argument("--json", action="store_true", help="print the summary as JSON")
    info.set_defaults(func=run_info)


def recorded_sources(args: argparse.Namespace) -> Recorded:
    """The recordings ``--voices`` and ``--conversations`` name, each checked (errors name the folder)."""
    from convodrive.corpus.maker import Recorded
    from convodrive.corpus.recordings import scan_conversations, scan_voices, segments_beside
    from convodrive.eval.segments import load_segments

    speakers = [s for folder in args.voices for s in scan_voices(folder)]
    conversations = []
    for folder in args.conversations:
        for conv in scan_conversations(folder):
            sidecar = segments_beside(conv.path)
            if sidecar is not None:
                seg = load_segments(sidecar)
                turns = {"self": [list(t) for t in seg.self_speech], "partner": [list(t) for t in seg.partner_speech]}
                conv = dataclasses.replace(conv, turns=turns)
            conversations.append(conv)
    hours = args.voice_hours if args.voice_hours is not None else sum(s.total for s in speakers) / 3600.0
    return Recorded(speakers, hours if speakers else 0.0, conversations)


def run_make(args: argparse.Namespace) -> int:
    from convodrive.corpus.maker import make_corpus
    from convodrive.generators.procedural import ProceduralGenerator

    if args.hours is None and not (args.voices or args.conversations):
        raise UserError("corpus make: give --hours (espeak-ng conversation), --voices or --conversations")
    recorded = recorded_sources(args)
    with frame_progress("making corpus (conversations)") as progress:
        report = make_corpus(
            args.hours or 0.0,
            args.out,
            ProceduralGenerator,
            seed=args.seed,
            jobs=args.jobs,
            takes=args.takes,
            progress=progress,
            recorded=recorded,
        )
    figures = report.to_json()
    print(
        f"{figures['corpus']}: {figures['hours']} h in {figures['conversations']} conversation(s), "
        f"{args.takes} takes each, made in {figures['seconds'] / 60:.1f} min with {figures['jobs']} jobs "
        f"({figures['minutes_per_corpus_hour']} min per corpus hour; load average "
        f"{figures['loadavg_before'][0]} before, {figures['loadavg_after'][0]} after)"
    )
    return 0


def run_import(args: argparse.Namespace) -> int:
    from convodrive.corpus.importers import import_corpus
    from convodrive.corpus.importers.options import ImportOptions

    options = ImportOptions(speaker=args.speaker, mano=args.mano)
    with frame_progress(f"importing {args.kind}") as progress:
        report = import_corpus(args.kind, args.src, args.out, seed=args.seed, options=options, progress=progress)
    corpus = Corpus.open(args.out)
    masked = sorted(
        {f"{len(c.missing_joints)} joints, {len(c.missing_face)} face channels" for c in corpus.conversations}
    )
    print(
        f"{args.out}: {report.kind} corpus, {report.hours:.3f} h in {report.conversations} conversation(s), "
        f"speakers {', '.join(corpus.speakers)}; masked: {'; '.join(masked)}"
    )
    for conv in corpus.conversations[:1]:
        for key in ("hands", "face"):
            if key in conv.metadata:
                print(f"  {key}: {conv.metadata[key]}")
    return 0


def summary(corpus: Corpus) -> dict:
    convs = corpus.conversations
    missing = Counter(
        f"{len(c.missing_joints)} joints, {len(c.missing_face)} face channels"
        for c in convs
        if c.missing_joints or c.missing_face
    )
    return {
        "corpus": str(corpus.folder),
        "source": corpus.manifest.get("source", {}).get("kind", "?"),
        "hours": round(corpus.hours, 3),
        "conversations": len(convs),
        "splits": {s: len(corpus.split(s)) for s in SPLITS},
        "hours_per_split": {s: round(sum(c.frames for c in corpus.split(s)) / 30 / 3600, 3) for s in SPLITS},
        "takes": dict(Counter(str(c.takes) for c in convs)),
        "speakers": dict(Counter(c.speaker for c in convs)),
        "shards": len(corpus.manifest["shards"]),
        "missing_channels": dict(missing),
    }


def run_info(args: argparse.Namespace) -> int:
    corpus = Corpus.open(args.folder)
    with frame_progress("checking") as progress:
        for i, _ in enumerate(corpus.check(), 1):
            if progress:
                progress(i, len(corpus.conversations))
    figures = summary(corpus)
    if args.json:
        print(json.dumps(figures, indent=2))
        return 0
    print(
        f"{figures['corpus']}: {figures['source']} corpus, {figures['hours']} h, {figures['conversations']} conversations"
    )
    print(
        "  splits: " + ", ".join(f"{s} {n} ({figures['hours_per_split'][s]} h)" for s, n in figures["splits"].items())
    )
    print("  takes per conversation: " + ", ".join(f"{k} x{n}" for k, n in sorted(figures["takes"].items())))
    print("  speakers: " + ", ".join(f"{k} ({n})" for k, n in sorted(figures["speakers"].items())))
    for what, n in figures["missing_channels"].items():
        print(f"  masked in {n} conversations: {what}")
    print("  ok: every shard, array and audio file checked")
    return 0
