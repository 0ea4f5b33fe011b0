"""The procedural generator's speaking and listening figures (issue 10's "Must show"), as JSON.

For the bundled dialogue (samples/dialogue.wav with its turns in samples/dialogue.json) and the
espeak-ng dialogues of the tests (tests/procedural_dialogues.py, graded against the turns they
were made from), K takes each: lip sync and mouth closure; while listening, blinks and nods per
minute (pooled over the takes' listening time), the share of nods within 600 ms after a partner
pause, head speed, and the speaking-to-listening head speed ratio; then the same dialogues with
the partner leaking into self's channel and self into the partner's at -12 dB (``add_bleed``):
self's voice activity wrong on partner-only frames and the jaw shut there. Each figure is checked
against its target in ``targets``. ``--real N``: instead, N one-minute dialogues of two real
recorded speakers held out of every corpus (tests/real_voices.py), with their true turns. No
timings: the load average is printed for completeness only.

Usage: .venv/bin/python bench/bench_listening.py [--takes K] [--seed N] [--bleed-db DB] [--real N]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from convodrive.audio.source import AudioSource, DyadicAudio  # noqa: E402
from convodrive.eval.behaviour import behaviour_figures  # noqa: E402
from convodrive.eval.segments import Segments, load_segments  # noqa: E402
from convodrive.generators.procedural import ProceduralGenerator  # noqa: E402
from tests.procedural_dialogues import DIALOGUES, make, reference, with_bleed  # noqa: E402

MIN_LISTENING_S = 5.0
"""Listening rates are judged where a take listens at least this long (a 1.5 s stretch holds one
blink or none: 0 or 40 a minute)."""


def summarise(figures: list[dict[str, Any]]) -> dict[str, Any]:
    listening_min = sum(f["activity"]["listening_frames"] for f in figures) / 30 / 60
    speaking_min = sum(f["activity"]["self_speaking_frames"] for f in figures) / 30 / 60

    def pooled(section: str, key: str, minutes_key: str) -> float | None:
        weighted = [f[section][key] * f["activity"][minutes_key] / 1800 for f in figures if f[section][key] is not None]
        minutes = listening_min if minutes_key == "listening_frames" else speaking_min
        return round(sum(weighted) / minutes, 2) if weighted and minutes else None

    def values(section: str, key: str) -> list[float]:
        return [f[section][key] for f in figures if f[section][key] is not None]

    def mean(section: str, key: str) -> float | None:
        v = values(section, key)
        return round(float(np.mean(v)), 3) if v else None

    def lowest(section: str, key: str) -> float | None:
        v = values(section, key)
        return round(float(np.min(v)), 3) if v else None

    nods = sum(f["nods"]["listening_nods"] for f in figures)
    timed = sum(
        (f["nods"]["listening_share_within_600ms_after_partner_pause"] or 0) * f["nods"]["listening_nods"]
        for f in figures
    )
    ratios = values("head", "speaking_to_listening_ratio")
    return {
        "listening_s_per_take": round(listening_min * 60 / len(figures), 1),
        "jaw_envelope_r_lowest": lowest("lip_sync", "pearson_jaw_vs_self_envelope"),
        "mouth_shut_self_silent_lowest": lowest("lip_sync", "jaw_closed_when_self_silent"),
        "blinks_per_min_listening": pooled("blinks_per_minute", "listening", "listening_frames"),
        "blinks_per_min_speaking": pooled("blinks_per_minute", "self_speaking", "self_speaking_frames"),
        "nods_per_min_listening": round(nods / listening_min, 2) if listening_min else None,
        "nods_within_600ms_after_partner_pause": round(timed / nods, 3) if nods else None,
        "head_speed_listening_deg_s_lowest": lowest("head", "mean_angular_speed_listening_deg_s"),
        "head_speed_speaking_deg_s": mean("head", "mean_angular_speed_self_speaking_deg_s"),
        "speaking_to_listening_ratio": round(float(np.mean(ratios)), 3) if ratios else None,
        "speaking_to_listening_ratio_range": [round(min(ratios), 2), round(max(ratios), 2)] if ratios else None,
        "smile_share_listening": mean("smiles", "share_listening"),
        "gaze_at_partner_speaking": mean("gaze", "at_partner_share_self_speaking"),
        "gaze_at_partner_listening": mean("gaze", "at_partner_share_listening"),
        "posture_shifts_per_min": mean("posture", "shifts_per_minute"),
    }


def bleed_summary(figures: list[dict[str, Any]]) -> dict[str, Any]:
    def worst(section: str, key: str, high: bool) -> float | None:
        v = [f[section][key] for f in figures if f[section][key] is not None]
        return (max(v) if high else min(v)) if v else None

    return {
        "self_vad_wrong_only_partner_worst": worst("voice_activity", "self_on_when_only_partner_speaks", True),
        "jaw_shut_only_partner_lowest": worst("lip_sync", "jaw_closed_when_only_partner_speaks", False),
        "partner_vad_wrong_only_self_worst": worst("voice_activity", "partner_on_when_only_self_speaks", True),
        "self_vad_heard_self_lowest": worst("voice_activity", "self_on_when_self_speaks", False),
    }


def check(results: dict[str, Any]) -> dict[str, Any]:
    """Each target: the dialogues where it was measured and whether every one meets it."""
    rules = {
        "jaw_envelope_r >= 0.8": ("clean", "jaw_envelope_r_lowest", lambda v: v >= 0.8, False),
        "mouth_shut_self_silent >= 0.97": ("clean", "mouth_shut_self_silent_lowest", lambda v: v >= 0.97, False),
        "blinks_listening 10..20/min": ("clean", "blinks_per_min_listening", lambda v: 10 <= v <= 20, True),
        "nods_listening >= 4/min": ("clean", "nods_per_min_listening", lambda v: v >= 4, True),
        "nods_after_pause_share >= 0.5": ("clean", "nods_within_600ms_after_partner_pause", lambda v: v >= 0.5, True),
        "head_speed_listening >= 3 deg/s": ("clean", "head_speed_listening_deg_s_lowest", lambda v: v >= 3, True),
        "speaking_to_listening_ratio 2..5": ("clean", "speaking_to_listening_ratio", lambda v: 2 <= v <= 5, False),
        "bleed: self_vad_wrong <= 0.05": ("bleed", "self_vad_wrong_only_partner_worst", lambda v: v <= 0.05, False),
        "bleed: jaw_shut >= 0.95": ("bleed", "jaw_shut_only_partner_lowest", lambda v: v >= 0.95, False),
    }
    out = {}
    for name, (kind, key, ok, needs_listening) in rules.items():
        measured = {
            d: r[kind][key]
            for d, r in results.items()
            if r[kind].get(key) is not None
            and (not needs_listening or r["clean"]["listening_s_per_take"] >= MIN_LISTENING_S)
        }
        out[name] = {"met": all(ok(v) for v in measured.values()), "dialogues": measured}
    return out


def espeak_sets() -> dict[str, tuple[DyadicAudio, Segments]]:
    """The bundled dialogue and the tests' espeak-ng dialogues, each with its turns."""
    sets = {
        "bundled": (
            AudioSource(REPO / "samples/dialogue.wav").read_all(),
            load_segments(REPO / "samples/dialogue.json"),
        )
    }
    with tempfile.TemporaryDirectory() as tmp:
        for name in DIALOGUES:
            path, audio = make(name, Path(tmp))
            sets[name] = (audio, reference(path))
    return sets


def real_sets(count: int) -> dict[str, tuple[DyadicAudio, Segments]]:
    """``count`` one-minute dialogues of two real speakers no shipped model heard."""
    from tests.real_voices import fetch, real_dialogue

    voices, why = fetch()
    if voices is None:
        raise SystemExit(f"bench_listening: no real voices: {why}")
    dialogues = (real_dialogue(voices, seed=seed, seconds=60.0) for seed in range(count))
    return {f"real-{i}": (d.audio, d.truth) for i, d in enumerate(dialogues)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--takes", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--bleed-db", type=float, default=-12.0)
    parser.add_argument(
        "--real", type=int, default=0, metavar="N",
        help="instead: N one-minute dialogues of the real held-out voices (tests/real_voices.py)",
    )  # fmt: skip
    args = parser.parse_args()
    gen = ProceduralGenerator()
    sets = real_sets(args.real) if args.real else espeak_sets()
    results = {}
    for name, (audio, ref) in sets.items():
        clean = [behaviour_figures(c, audio, ref) for c in gen.generate(audio, args.seed, args.takes)]
        bled_audio = with_bleed(audio, args.bleed_db)
        bled = [behaviour_figures(c, bled_audio, ref) for c in gen.generate(bled_audio, args.seed, args.takes)]
        results[name] = {"clean": summarise(clean), "bleed": bleed_summary(bled)}
    report = {
        "dialogues_from": f"{args.real} real" if args.real else "espeak-ng and bundled",
        "takes": args.takes,
        "seed": args.seed,
        "bleed_db": args.bleed_db,
        "loadavg": [round(x, 2) for x in os.getloadavg()],
        "dialogues": results,
        "targets": check(results),
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
