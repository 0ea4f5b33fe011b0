"""What every recipe reads from a corpus: the opened corpus, its statistics, and facts for the card."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from convodrive.corpus import Corpus
from convodrive.corpus.stats import feature_stats
from convodrive.motion.representation import FeatureStats


def open_corpus(path: Path) -> Corpus:
    return Corpus.open(path)


def train_stats(corpus: Corpus) -> FeatureStats:
    """Normalisation statistics of the train split (every take, missing channels left out)."""
    return feature_stats(corpus, "train")


def corpus_facts(corpus: Corpus) -> dict[str, Any]:
    """The corpus a model learned from, as its model folder and card name it."""
    source = {k: Path(v).name if _is_path(v) else v for k, v in corpus.manifest.get("source", {}).items()}
    return {
        "name": corpus.folder.name,
        "hours": round(corpus.hours, 3),
        "conversations": len(corpus.conversations),
        "speakers": corpus.speakers,
        "source": source,
        "audio_features": corpus.mel_spec.to_dict(),
        "licence": corpus.manifest.get("licence") or source.get("licence") or "that of the corpus's source data",
    }


def _is_path(value: object) -> bool:
    """An imported corpus's source names the user's folders: a model folder keeps only their names."""
    return isinstance(value, str) and (value.startswith(("/", "~")) or "\\" in value)


def audio_stats(corpus: Corpus, split: str = "train") -> tuple[np.ndarray, np.ndarray]:
    """Per-band mean and spread (bands,) of both voices' log-mel over a split: what a network
    subtracts and divides by before it hears audio, so loud and quiet corpora look alike."""
    count = 0
    sums = squares = None
    for conv in corpus.split(split):
        mel = np.asarray(corpus.mel(conv.id), np.float64).reshape(-1, corpus.mel_spec.bands)
        sums = mel.sum(0) if sums is None else sums + mel.sum(0)
        squares = (mel**2).sum(0) if squares is None else squares + (mel**2).sum(0)
        count += len(mel)
    if sums is None or squares is None or count == 0:
        bands = corpus.mel_spec.bands
        return np.zeros(bands, np.float32), np.ones(bands, np.float32)
    mean = sums / count
    std = np.sqrt(np.maximum(squares / count - mean**2, 0.0))
    return mean.astype(np.float32), np.maximum(std, 1e-3).astype(np.float32)


def normalisation_arrays(stats: FeatureStats, corpus: Corpus) -> dict[str, np.ndarray]:
    """What a model folder's ``normalisation.npz`` holds: the motion statistics (with their counts,
    so the runtime knows which channels the data held constant) and the train split's audio ones."""
    audio_mean, audio_std = audio_stats(corpus, "train")
    return {
        "mean": stats.mean,
        "std": stats.std,
        "count": stats.count,
        "audio_mean": audio_mean,
        "audio_std": audio_std,
    }
