"""``convodrive eval compare``: run methods over a corpus split and score them with one suite.

This is the one place that knows both generators and the metrics: the baselines come from the
corpus (``eval.baselines``), any other name is a generator plugin run on each conversation's
audio; every method is then scored by ``eval.suite`` against take 0 of each conversation.

Generators are told whose motion they make, as the papers condition on speaker identity: a
generator whose options declare ``speaker`` gets the conversation's speaker label, and the generator
that taught a made corpus (its manifest's source) gets the style options the corpus recorded for
that conversation, so ``procedural`` is scored as the teacher it was, not with default settings.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.audio.source import DyadicAudio
from convodrive.corpus import ConversationInfo, Corpus
from convodrive.corpus.stats import feature_stats
from convodrive.eval.baselines import BASELINES, KNNIndex, ground_truth, random_motion
from convodrive.eval.fgd import FGDEmbedder
from convodrive.eval.suite import Case, score
from convodrive.eval.table import write_outputs
from convodrive.generators.base import Generator
from convodrive.motion import representation as rep
from convodrive.motion.clip import MotionClip
from convodrive.motion.representation import FeatureStats
from convodrive.plugins import GENERATOR_GROUP, load_plugin
from convodrive.plumbing.errors import UserError


@dataclasses.dataclass
class CompareRequest:
    corpus: Path
    generators: tuple[str, ...]
    out: Path
    split: str = "test"
    samples: int = 4
    seed: int = 0
    seeds: int = 1
    """Repeats at ``seed``, ``seed + 1``, ...: each figure is their mean, and compare.json keeps each
    seed's figures and their spread. One seed's FD_g body over 7 conversations x 4 takes moves by a
    third of a unit between seeds, as much as a model's distance to a 1.5x line."""
    max_conversations: int | None = None
    stratum: str | None = None
    """Score only conversations of this kind (``ConversationInfo.stratum``): a mixed corpus's test
    split pools kinds that score apart (synthesised voices and recorded ones)."""
    speakers: tuple[str, ...] = ()
    """Score only these speakers' conversations (empty: all). The styles score far apart: on
    corpus2hrv2's val split the expressive ones' takes are twice as far from each other as the quiet
    ones', and the learned models fall further behind them."""
    fgd_model: Path | None = None
    generator_options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class CompareResult:
    results: dict[str, dict[str, Any]]
    outputs: list[Path]
    seconds: dict[str, float]


def method_plugin(method: str) -> tuple[str, str]:
    """``LABEL=GENERATOR`` -> (label, generator); a bare name is its own label."""
    label, sep, plugin = (part.strip() for part in method.partition("="))
    return (label, plugin) if sep else (label, label)


def _check_names(request: CompareRequest) -> None:
    if not request.generators:
        raise UserError("--generators needs at least one name (e.g. ground-truth,procedural,knn,random)")
    labels = [method_plugin(m)[0] for m in request.generators]
    for method in request.generators:
        label, plugin = method_plugin(method)
        if not label or not plugin:
            raise UserError(f"--generators: '{method}' is not NAME or LABEL=GENERATOR")
        if labels.count(label) > 1:
            raise UserError(f"--generators: '{label}' is named twice (give one a label: LABEL={plugin})")
        if plugin in BASELINES and label != plugin:
            raise UserError(f"--generators: '{method}': baselines take no label")
        if plugin not in BASELINES:
            load_plugin(GENERATOR_GROUP, plugin)  # unknown or unloadable: one line, before any work
    for label in request.generator_options:
        if label not in labels or label in BASELINES:
            raise UserError(f"-G {label}.KEY=VALUE: '{label}' is not a generator in --generators")


def _conversations(corpus: Corpus, request: CompareRequest) -> list[ConversationInfo]:
    convs = corpus.split(request.split)
    if request.stratum is not None:
        kinds = sorted({c.stratum or "(none)" for c in convs})
        convs = [c for c in convs if c.stratum == request.stratum]
        if not convs:
            raise UserError(
                f"{request.corpus}: no conversation of kind '{request.stratum}' in the {request.split} split "
                f"(kinds there: {', '.join(kinds) or 'none'})"
            )
    if request.speakers:
        present = sorted({c.speaker for c in convs})
        convs = [c for c in convs if c.speaker in request.speakers]
        if not convs:
            raise UserError(
                f"{request.corpus}: no conversation of speaker {', '.join(request.speakers)} in the "
                f"{request.split} split{_stratum_words(request)} (speakers there: {', '.join(present) or 'none'})"
            )
    return convs[: request.max_conversations] if request.max_conversations else convs


def _stratum_words(request: CompareRequest) -> str:
    return f" ({request.stratum})" if request.stratum else ""


@dataclasses.dataclass
class _Scoring:
    """What every method's scoring shares: the conversations, their audio and references, the
    metrics' statistics and embedder, and the baselines' and generators' state across seeds."""

    request: CompareRequest
    corpus: Corpus
    convs: list[ConversationInfo]
    stats: FeatureStats
    embedder: FGDEmbedder
    audio: dict[str, DyadicAudio]
    references: dict[str, MotionClip]
    masks: dict[str, np.ndarray]
    knn: KNNIndex | None = None

    def cases(self, index: int, name: str, plugin: str, seed: int, generators: dict[str, Generator]) -> list[Case]:
        """Method ``index``'s samples of every conversation at ``seed`` (``generators``: those it
        loaded already, by their options)."""
        request, corpus = self.request, self.corpus
        rng = np.random.default_rng([seed, index])
        cases = []
        for conv in self.convs:
            samples: list[MotionClip] | None
            if name == "ground-truth":
                samples = ground_truth(corpus, conv, request.samples)
            elif name == "random":
                samples = random_motion(corpus, conv, request.samples, rng)
            elif name == "knn":
                self.knn = self.knn or KNNIndex(corpus)
                samples = self.knn.motion(conv, request.samples)
            else:
                options = {**conversation_options(plugin, corpus, conv), **request.generator_options.get(name, {})}
                key = json.dumps(options, sort_keys=True, default=str)
                if key not in generators:
                    generators[key] = load_plugin(GENERATOR_GROUP, plugin)(options)
                samples = generators[key].generate(self.audio[conv.id], seed=seed, num_samples=request.samples)
                samples = [_fit(s, conv.frames) for s in samples]
            if samples is not None:
                cases.append(Case(conv.id, self.references[conv.id], self.audio[conv.id], self.masks[conv.id], samples))
        if not cases:
            raise UserError(
                f"method '{name}' has nothing to score on the {request.split} split (ground-truth needs at least two takes)"
            )
        return cases


def _open(request: CompareRequest) -> _Scoring:
    _check_names(request)
    if request.samples < 1:
        raise UserError(f"--samples must be at least 1, got {request.samples}")
    if request.seeds < 1:
        raise UserError(f"--seeds must be at least 1, got {request.seeds}")
    corpus = Corpus.open(request.corpus)
    convs = _conversations(corpus, request)
    if not convs:
        raise UserError(f"{request.corpus}: the {request.split} split holds no conversation")
    return _Scoring(
        request,
        corpus,
        convs,
        feature_stats(corpus, "train"),
        FGDEmbedder(request.fgd_model),
        {c.id: corpus.audio(c.id) for c in convs},
        {c.id: corpus.window(c.id, 0, 0, c.frames).clip() for c in convs},
        {c.id: rep.feature_mask(c.joint_mask, c.face_mask) for c in convs},
    )


def compare(request: CompareRequest, on_method: Callable[[str], None] | None = None) -> CompareResult:
    scoring = _open(request)
    seeds = list(range(request.seed, request.seed + request.seeds))
    results: dict[str, dict[str, Any]] = {}
    per_seed: dict[str, list[dict[str, Any]]] = {}
    seconds: dict[str, float] = {}
    for index, method in enumerate(request.generators):
        name, plugin = method_plugin(method)
        if on_method is not None:
            on_method(name)
        started, scored = time.monotonic(), 0.0
        generators: dict[str, Generator] = {}
        per_seed[name] = []
        for seed in seeds:
            cases = scoring.cases(index, name, plugin, seed, generators)
            generated = time.monotonic()
            per_seed[name].append(score(cases, scoring.stats, scoring.embedder, seed=seed))
            scored += time.monotonic() - generated
        results[name] = mean_figures(per_seed[name])
        seconds[name] = round(time.monotonic() - started, 2)
        seconds[f"{name} (metrics)"] = round(scored, 2)
    convs = scoring.convs
    context: dict[str, Any] = {
        "corpus": str(request.corpus),
        "split": request.split,
        "stratum": request.stratum,
        "speakers": list(request.speakers) or None,
        "conversations": len(convs),
        "hours": round(sum(c.frames for c in convs) / 30 / 3600, 3),
        "samples": request.samples,
        "seed": request.seed,
        "seeds": seeds,
        "fgd_model": str(scoring.embedder.folder.path),
        "fgd_files": scoring.embedder.folder.spec["files"],
        "seconds": seconds,
    }
    if len(seeds) > 1:
        context["per_seed"] = per_seed
        context["sd_over_seeds"] = {name: spread_figures(runs) for name, runs in per_seed.items()}
    split = f"{request.split} split" + _stratum_words(request)
    if request.speakers:
        split += f", speakers {', '.join(request.speakers)}"
    title = f"{Path(request.corpus).name}, {split}: {len(convs)} conversations, {request.samples} samples each"
    if len(seeds) > 1:
        title += f", the mean of seeds {seeds[0]}-{seeds[-1]}"
    outputs = write_outputs(results, Path(request.out), title, context)
    return CompareResult(results, outputs, seconds)


def _defined(runs: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Each figure's values over the runs that define it."""
    return {name: [run[name] for run in runs if run[name] is not None] for name in runs[0]}


def mean_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Each figure's mean over the runs that define it (None where none does)."""
    return {name: round(float(np.mean(v)), 4) if v else None for name, v in _defined(runs).items()}


def spread_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Each figure's standard deviation over the runs (ddof 1: a handful of seeds is a sample;
    None where fewer than two runs define it)."""
    return {name: round(float(np.std(v, ddof=1)), 4) if len(v) > 1 else None for name, v in _defined(runs).items()}


def conversation_options(name: str, corpus: Corpus, conv: ConversationInfo) -> dict[str, Any]:
    """What generator ``name`` is told about the conversation's speaker (see the module doc)."""
    declared = getattr(load_plugin(GENERATOR_GROUP, name), "Options", None)
    fields = {f.name for f in dataclasses.fields(declared)} if dataclasses.is_dataclass(declared) else set()
    options: dict[str, Any] = {}
    if "speaker" in fields:
        options["speaker"] = conv.speaker
    style = conv.metadata.get("style")
    if corpus.manifest.get("source", {}).get("generator") == name and isinstance(style, dict):
        options.update({k: v for k, v in style.items() if k in fields})
    return options


def _fit(clip: MotionClip, frames: int) -> MotionClip:
    """A generated clip cut (or its last frame held) to the reference's length."""
    if clip.num_frames == frames:
        return clip
    idx = np.minimum(np.arange(frames), clip.num_frames - 1)
    return MotionClip(clip.pose[idx], clip.translation[idx], clip.face[idx], clip.vad[idx], clip.state[idx], clip.fps)
