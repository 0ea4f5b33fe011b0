"""What every recipe reads from a corpus: the opened corpus, its statistics, and facts for the card."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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
    source = corpus.manifest.get("source", {})
    return {
        "path": str(corpus.folder),
        "name": corpus.folder.name,
        "hours": round(corpus.hours, 3),
        "conversations": len(corpus.conversations),
        "speakers": corpus.speakers,
        "source": source,
        "audio_features": corpus.mel_spec.to_dict(),
        "licence": corpus.manifest.get("licence") or source.get("licence") or "that of the corpus's source data",
    }
