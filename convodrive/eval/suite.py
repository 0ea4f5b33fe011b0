"""The metric suite of ``eval compare``: every figure of one method over a set of conversations.

Each conversation brings its reference motion (take 0 of the corpus), its audio, the mask of the
channels its corpus has, and K generated samples. Distribution figures pool all conversations;
per-sequence figures are averaged. Rotations and channels enter the distribution metrics in the
normalised learning representation (train-split statistics), face and body apart, masked channels
left out; lip sync, beats and listening figures are measured on the canonical clips.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.eval import distribution as dist
from convodrive.eval.beats import audio_onsets, beat_consistency, motion_beats
from convodrive.eval.behaviour import behaviour_figures
from convodrive.eval.fgd import FGDEmbedder
from convodrive.motion import representation as rep
from convodrive.motion.clip import MotionClip
from convodrive.motion.representation import FeatureStats

# name, better ("low"/"high"/""), what it is
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("FD_g body", "low", "Fréchet distance of per-frame body features (a2p)"),
    ("FD_g face", "low", "Fréchet distance of per-frame face features (a2p)"),
    ("FD_k body", "low", "Fréchet distance of body velocities (a2p)"),
    ("FD_k face", "low", "Fréchet distance of face velocities (a2p)"),
    ("FGD holistic", "low", "Fréchet distance of autoencoder features, face and body (ProbTalk)"),
    ("FGD body", "low", "FGD of the body (ProbTalk)"),
    ("FGD face", "low", "FGD of the face (ProbTalk)"),
    ("Div_g", "high", "mean distance of 30 random frame pairs of a sequence (a2p)"),
    ("Div_k", "high", "temporal variance of a sequence (a2p)"),
    ("Div_sample", "high", "variance across the samples for one audio (a2p)"),
    ("Var body", "high", "variance across samples, body (ProbTalk)"),
    ("Var face", "high", "variance across samples, face (ProbTalk)"),
    ("BC", "high", "beat consistency of arm beats with speech onsets (ProbTalk)"),
    ("lip r", "high", "Pearson r of jawOpen with self's loudness envelope"),
    ("mouth shut", "high", "fraction of self-silent frames with the jaw closed"),
    ("head speak/listen", "", "head speed while speaking over while only listening"),
    ("blinks/min listening", "", "blink rate while only the partner speaks"),
)
SCORED_PARTS: tuple[str, ...] = ("head", "upper", "hands", "jaw", "eyes", "arkit")
"""The parts of the feature layout (``representation.PARTS``) whose FD_g ``score`` also gives,
each over its own channels: which part a group's distance comes from. They do not add up to the
group's figure (that one also counts how the parts move together)."""
PART_COLUMNS: tuple[str, ...] = tuple(f"FD_g {part}" for part in SCORED_PARTS)


@dataclasses.dataclass
class Case:
    """One test conversation: what it is scored against, and what a method made for it."""

    id: str
    reference: MotionClip
    audio: DyadicAudio
    mask: np.ndarray
    samples: list[MotionClip]


def _slices(mask: np.ndarray) -> dict[str, np.ndarray]:
    """The columns ``mask`` keeps of each group, of face and body together, and of each of ``SCORED_PARTS``."""

    def kept(span: slice) -> np.ndarray:
        columns = np.arange(span.start, span.stop)
        return columns[mask[columns]]

    out = {group: kept(rep.GROUPS[group]) for group in ("face", "body")}
    out["holistic"] = np.concatenate([out["face"], out["body"]])
    return {**out, **{part: kept(rep.PARTS[part]) for part in SCORED_PARTS}}


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(kept)) if kept else None


def score(cases: list[Case], stats: FeatureStats, embedder: FGDEmbedder | None, seed: int = 0) -> dict[str, Any]:
    """The figures of ``COLUMNS`` and ``PART_COLUMNS`` for one method over ``cases`` (None where undefined)."""
    rng = np.random.default_rng(seed)
    mask = np.logical_and.reduce([c.mask for c in cases])
    cols = _slices(mask)
    gen = [[stats.normalise(rep.encode_clip(s)) for s in c.samples] for c in cases]
    ref = [stats.normalise(rep.encode_clip(c.reference)) for c in cases]
    out: dict[str, Any] = {}
    for part in ("body", "face"):
        g = [x[:, cols[part]] for seqs in gen for x in seqs]
        r = [x[:, cols[part]] for x in ref]
        out[f"FD_g {part}"] = dist.fd_g(g, r)
        out[f"FD_k {part}"] = dist.fd_k(g, r)
    for part in SCORED_PARTS:
        if len(cols[part]):
            out[f"FD_g {part}"] = dist.fd_g(
                [x[:, cols[part]] for seqs in gen for x in seqs], [x[:, cols[part]] for x in ref]
            )
    hol = cols["holistic"]
    out["Div_g"] = _mean([dist.div_g(x[:, hol], rng) for seqs in gen for x in seqs])
    out["Div_k"] = _mean([dist.div_k(x[:, hol]) for seqs in gen for x in seqs])
    multi = [seqs for seqs in gen if len(seqs) > 1]
    out["Div_sample"] = _mean([dist.sample_variance(np.stack([x[:, hol] for x in seqs])) for seqs in multi])
    out["Var body"] = _mean([dist.sample_variance(np.stack([x[:, cols["body"]] for x in seqs])) for seqs in multi])
    out["Var face"] = _mean([dist.sample_variance(np.stack([x[:, cols["face"]] for x in seqs])) for seqs in multi])
    if embedder is not None:
        raw_gen = [rep.encode_clip(s) for c in cases for s in c.samples]
        gen_masks = [c.mask for c in cases for _ in c.samples]
        raw_ref = [rep.encode_clip(c.reference) for c in cases]
        for part in ("holistic", "body", "face"):
            a = embedder.embed(raw_gen, gen_masks, part)
            b = embedder.embed(raw_ref, [c.mask for c in cases], part)
            out[f"FGD {part}"] = dist.frechet_distance(a, b) if len(a) > 1 and len(b) > 1 else None
    bcs, lips, shut, ratio, blinks = [], [], [], [], []
    for c in cases:
        first = c.samples[0]
        bcs.append(beat_consistency(audio_onsets(c.audio.self_voice), motion_beats(first)))
        fig = behaviour_figures(first, c.audio)
        lips.append(fig["lip_sync"]["pearson_jaw_vs_self_envelope"])
        shut.append(fig["lip_sync"]["jaw_closed_when_self_silent"])
        ratio.append(fig["head"]["speaking_to_listening_ratio"])
        blinks.append(fig["blinks_per_minute"]["only_partner"])
    out.update(
        {
            "BC": _mean(bcs),
            "lip r": _mean(lips),
            "mouth shut": _mean(shut),
            "head speak/listen": _mean(ratio),
            "blinks/min listening": _mean(blinks),
        }
    )
    names = [name for name, _, _ in COLUMNS] + list(PART_COLUMNS)
    return {name: (None if out.get(name) is None else round(float(out[name]), 4)) for name in names}
