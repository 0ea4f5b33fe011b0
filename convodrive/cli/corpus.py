"""``convodrive corpus``: make a training corpus, import one, or check one.

convodrive corpus make --hours H --out DIR [--seed N] [--jobs N]
convodrive corpus import KIND SRC --out DIR [--seed N] [--mano FILE]
convodrive corpus info DIR
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

from convodrive.cli.progress import frame_progress
from convodrive.corpus.manifest import SPLITS
from convodrive.corpus.reader import Corpus


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "corpus", help="make, import or check a training corpus", description="Make, import or check a training corpus."
    )
    sub = p.add_subparsers(dest="corpus_command", metavar="WHAT", parser_class=type(p))
    sub.required = True
    info = sub.add_parser(
        "info",
        help="check a corpus and summarise it",
        description="Open DIR, check every shard, array and audio file, and print a summary (JSON with --json).",
    )
    info.add_argument("folder", type=Path, metavar="DIR", help="corpus folder (holds manifest.json)")
    info.add_argument("--json", action="store_true", help="print the summary as JSON")
    info.set_defaults(func=run_info)


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
