"""The learned generators stream in constant memory: a minute of audio peaks no higher than ten
seconds, five 2-second windows (windows, guides and caches are dropped as the stream moves on)."""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterator
from typing import Any

import pytest

from convodrive.audio.source import AudioChunk
from convodrive.plugins import GENERATOR_GROUP, load_plugin
from tests.conftest import require
from tests.corpora import turn_taking_audio

pytestmark = [require("torch"), require("onnxruntime"), pytest.mark.timeout(900)]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "options"),
    [("a2p", {}), ("probtalk", {"window": 48, "context": 8})],
)
def test_memory_stays_constant_on_long_audio(
    name: str, options: dict[str, Any], request: pytest.FixtureRequest
) -> None:
    model = request.getfixturevalue(f"{name}_model")  # tests/generators/conftest.py
    gen = load_plugin(GENERATOR_GROUP, name)({"model": str(model), **options})
    tone = turn_taking_audio(2.0, seed=1)

    def chunks(seconds: float) -> Iterator[AudioChunk]:
        for i in range(int(seconds / 2)):
            yield AudioChunk(i * len(tone), tone[:, 0], tone[:, 1])

    def peak(seconds: float) -> int:
        tracemalloc.start()
        for _ in gen.stream(chunks(seconds)):
            pass
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    short, long = peak(10), peak(60)
    assert long < short * 1.3 + 200_000, (short, long)
