"""Speech and mouth onsets, and pairing them into an audio–motion offset."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.eval.sync import LevelMeter, level_db, mouth_onsets, pair_onsets, speech_onsets


def bursts(starts: list[float], rate: int = 16000, seconds: float = 10.0) -> np.ndarray:
    rng = np.random.default_rng(1)
    x = 0.001 * rng.standard_normal(int(seconds * rate))
    for s in starts:
        i = int(s * rate)
        x[i : i + int(0.6 * rate)] += 0.3 * np.sin(np.arange(int(0.6 * rate)) * 2 * np.pi * 200 / rate)
    return x.astype(np.float32)


def test_speech_onsets_found_to_a_hop() -> None:
    starts = [0.5, 2.013, 4.4, 7.25]
    onsets = speech_onsets(level_db(bursts(starts), 16000))
    assert onsets == pytest.approx(starts, abs=0.011)


def test_level_meter_equals_level_db_whatever_the_pieces() -> None:
    x = bursts([1.0])
    meter = LevelMeter(16000)
    for i in range(0, len(x), 777):
        meter.push(x[i : i + 777])
    np.testing.assert_allclose(meter.db, level_db(x, 16000))


def test_mouth_onsets_need_a_closed_mouth_before() -> None:
    jaw = np.zeros(100)
    jaw[10:20] = 0.5
    jaw[22:30] = 0.5  # 2 closed frames: the same opening, not a new one
    jaw[40:50] = 0.5
    assert list(mouth_onsets(jaw)) == [10, 40]


def test_pairing_and_drift() -> None:
    audio = np.arange(0.0, 600.0, 10.0)
    motion = audio + 0.010 + audio * 0.030 / 600  # 10 ms late, drifting to 40 ms over ten minutes
    figure = pair_onsets(audio, np.concatenate([motion, [1234.5]])).summary()
    assert figure["pairs"] == len(audio)
    assert figure["median_ms"] == pytest.approx(25.0, abs=0.5)
    assert figure["drift_ms_per_10min"] == pytest.approx(30.0, abs=0.5)
    assert pair_onsets(audio, audio + 0.5).summary()["pairs"] == 0, "too far apart to be one event"
