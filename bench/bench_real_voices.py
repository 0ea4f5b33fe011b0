"""Every generator on real two-voice dialogues of speakers no shipped model heard (issue 32's first
must-show), as JSON.

N one-minute dialogues of the held-out real speakers (tests/real_voices.py), with their true turns,
clean and with each voice leaking into the other's microphone at ``--bleed-db`` (``add_bleed``).
Per generator and dialogue: jaw-envelope correlation, the jaw shut where self is silent and where
only the partner speaks, and head speed talking over listening; then the worst dialogue against
the targets. Any output gate stays off (the generators' defaults have none). ``--model NAME=DIR``
runs a generator from another folder, under its own name (``new=probtalk:DIR``), to set a
retrained model beside the shipped one; ``--variant NAME=GENERATOR:KEY=VALUE,...`` one with other
options (``a2p-dpm=a2p:sampler=dpm``). No timings: the load average is printed for completeness.

Usage: .venv/bin/python bench/bench_real_voices.py [--real N] [--generators procedural,probtalk,a2p]
       [--model NAME=GENERATOR:DIR ...] [--variant NAME=GENERATOR:KEY=VALUE,... ...] [--bleed-db DB] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.bench_listening import real_sets  # noqa: E402
from convodrive.audio.source import DyadicAudio  # noqa: E402
from convodrive.audio.synth import add_bleed  # noqa: E402
from convodrive.eval.behaviour import behaviour_figures  # noqa: E402
from convodrive.plugins import GENERATOR_GROUP, load_plugin  # noqa: E402
from convodrive.plumbing.safe_yaml import parse_scalar  # noqa: E402

TARGETS = {"jaw_r": 0.7, "shut_self_silent": 0.95, "shut_only_partner": 0.97, "head_talk_listen": 2.0}
"""Each figure's lowest acceptable value, clean and with bleed alike."""


def figures(generator: Any, audio: DyadicAudio, truth: Any, seed: int) -> dict[str, float]:
    """The first must-show's four figures of one take (tests/eval/test_real_voices.py asserts them)."""
    clip = generator.generate(audio, seed=seed)[0]
    f = behaviour_figures(clip, audio, truth)
    return {
        "jaw_r": f["lip_sync"]["pearson_jaw_vs_self_envelope"],
        "shut_self_silent": f["lip_sync"]["jaw_closed_when_self_silent"],
        "shut_only_partner": f["lip_sync"]["jaw_closed_when_only_partner_speaks"],
        "head_talk_listen": f["head"]["speaking_to_listening_ratio"],
    }


def worst(per_dialogue: dict[str, dict[str, dict[str, float]]]) -> dict[str, dict[str, Any]]:
    """Per condition (clean, bleed): each figure's lowest over the dialogues, and whether it meets its target."""
    out: dict[str, dict[str, Any]] = {}
    for condition in ("clean", "bleed"):
        lowest = {k: min(d[condition][k] for d in per_dialogue.values()) for k in TARGETS}
        out[condition] = {"lowest": lowest, "met": {k: lowest[k] >= bound for k, bound in TARGETS.items()}}
    return out


def named_generators(names: str, models: Sequence[str], variants: Sequence[str] = ()) -> dict[str, Any]:
    """``procedural,probtalk,a2p`` with their defaults, plus each ``NAME=GENERATOR:DIR`` and each
    ``NAME=GENERATOR:KEY=VALUE,...`` (options)."""
    made = {name: load_plugin(GENERATOR_GROUP, name)({}) for name in names.split(",") if name}
    for flag, specs, form in (("--model", models, "DIR"), ("--variant", variants, "KEY=VALUE,...")):
        for spec in specs:
            name, _, rest = spec.partition("=")
            kind, _, value = rest.partition(":")
            pairs = [pair.partition("=") for pair in value.split(",")]
            if not (name and kind and value) or (flag == "--variant" and not all(k and eq for k, eq, _ in pairs)):
                raise SystemExit(f"bench_real_voices: {flag} {spec}: expected NAME=GENERATOR:{form}")
            options = {k: parse_scalar(v) for k, _, v in pairs} if flag == "--variant" else {"model": value}
            made[name] = load_plugin(GENERATOR_GROUP, kind)(options)
    return made


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--real", type=int, default=4, metavar="N", help="one-minute dialogues (default 4)")
    parser.add_argument("--generators", default="procedural,probtalk,a2p")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=GENERATOR:DIR")
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=GENERATOR:KEY=VALUE,...",
        help="a generator with options",
    )
    parser.add_argument("--bleed-db", type=float, default=-12.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    generators = named_generators(args.generators, args.model, args.variant)
    sets = real_sets(args.real)
    results: dict[str, Any] = {}
    for name, generator in generators.items():
        per_dialogue = {}
        for label, (audio, truth) in sets.items():
            bled = DyadicAudio(*add_bleed(audio.self_voice, audio.other_voice, args.bleed_db))
            per_dialogue[label] = {
                condition: {k: round(v, 3) for k, v in figures(generator, heard, truth, args.seed).items()}
                for condition, heard in (("clean", audio), ("bleed", bled))
            }
        results[name] = {"dialogues": per_dialogue, "worst": worst(per_dialogue)}
    report = {
        "dialogues": f"{args.real} real, one minute each, held-out speakers",
        "bleed_db": args.bleed_db,
        "seed": args.seed,
        "targets": TARGETS,
        "loadavg": [round(x, 2) for x in os.getloadavg()],
        "generators": results,
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
