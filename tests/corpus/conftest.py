"""Small recordings and corpora for the corpus tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.source import motion_frames_for
from convodrive.corpus import CorpusWriter, Recording
from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionClip


def fake_recording(
    rec_id: str, seconds: float, takes: int = 2, speaker: str = "calm", group: str | None = None, seed: int = 0
) -> Recording:
    """Noise-like audio and random motion of the right lengths: enough to test storage exactly."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 16000)
    t = np.arange(n) / 16000
    audio = np.stack([0.3 * np.sin(2 * np.pi * 150 * t) * (np.sin(2 * np.pi * t) > 0), rng.normal(0, 0.05, n)], 1)
    frames = motion_frames_for(n / 16000)
    clips = []
    for _ in range(takes):
        vad = (rng.random((frames, 2)) > 0.5).astype(np.float32)
        clips.append(
            MotionClip(
                pose=rng.normal(scale=0.4, size=(frames, 55, 3)).astype(np.float32),
                translation=rng.normal(scale=0.01, size=(frames, 3)).astype(np.float32),
                face=rng.random((frames, 52)).astype(np.float32),
                vad=vad,
                state=np.array([ConversationState.from_activity(bool(a), bool(b)) for a, b in vad], np.int8),
            )
        )
    return Recording(rec_id, audio.astype(np.float32), clips, speaker, group=group, metadata={"language": "en"})


@pytest.fixture
def small_corpus(tmp_path: Path) -> tuple[Path, list[Recording]]:
    """Six conversations in five groups (one dyad), two speakers, a small shard size so there are several shards."""
    recs = [
        fake_recording("c0", 3.0, speaker="calm", seed=1),
        fake_recording("c1", 2.5, speaker="lively", seed=2),
        fake_recording("d0-a", 4.0, speaker="calm", group="d0", seed=3),
        fake_recording("d0-b", 4.0, speaker="lively", group="d0", seed=4, takes=1),
        fake_recording("c2", 6.1, speaker="lively", seed=5),
        fake_recording("c3", 2.0, speaker="calm", seed=6),
    ]
    out = tmp_path / "corpus"
    with CorpusWriter(out, {"kind": "test"}, seed=3, shard_bytes=400_000) as writer:
        for rec in recs:
            writer.add(rec)
    return out, recs
