"""Log-mel features: streaming equals offline for any chunking, frame alignment, declared look-ahead."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from convodrive.audio.features import frame_edge
from convodrive.audio.logmel import DEFAULT_SPEC, LogMelStream, MelSpec, dyadic_log_mel, log_mel
from convodrive.audio.source import DyadicAudio


def _speechlike(seconds: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(seconds * 16000)
    t = np.arange(n) / 16000
    voiced = 0.3 * np.sin(2 * np.pi * (140 + 30 * np.sin(2 * np.pi * 0.7 * t)) * t) * (np.sin(2 * np.pi * 3 * t) > 0)
    return np.stack([voiced + rng.normal(0, 0.01, n), rng.normal(0, 0.05, n) * (t > seconds / 2)], axis=1)


AUDIO = _speechlike(2.3)
OFFLINE = log_mel(AUDIO)


def _streamed(audio: np.ndarray, sizes: list[int]) -> np.ndarray:
    stream = LogMelStream(channels=audio.shape[1])
    parts, pos, i = [], 0, 0
    while pos < len(audio):
        size = sizes[i % len(sizes)]
        parts.append(stream.push(audio[pos : pos + size]))
        pos, i = pos + size, i + 1
    parts.append(stream.finish(len(OFFLINE)))
    return np.concatenate(parts)


@given(st.lists(st.integers(min_value=1, max_value=5000), min_size=1, max_size=12))
@settings(max_examples=60, deadline=None)
def test_streaming_is_bit_identical_to_offline_for_any_chunking(sizes: list[int]) -> None:
    np.testing.assert_array_equal(_streamed(AUDIO, sizes), OFFLINE)


@pytest.mark.parametrize("size", [1, 7, 160, 533, 534, 1600, 16000, 10**6])
def test_fixed_chunk_sizes(size: int) -> None:
    np.testing.assert_array_equal(_streamed(AUDIO, [size]), OFFLINE)


def test_shape_frame_count_and_dyadic_order() -> None:
    assert OFFLINE.shape == (69, 2, DEFAULT_SPEC.bands) and OFFLINE.dtype == np.float32  # 2.3 s -> 69 frames
    audio = DyadicAudio(AUDIO[:, 0].astype(np.float32), AUDIO[:, 1].astype(np.float32))
    both = dyadic_log_mel(audio)
    np.testing.assert_allclose(both, OFFLINE, atol=1e-4)  # float32 input rounding only
    # The partner is silent in the first half: its energy there is far below self's.
    assert both[:20, 1].mean() < both[:20, 0].mean() - 5


def test_a_burst_lands_in_its_own_frame_and_band() -> None:
    k = 40
    audio = np.zeros(int(2 * 16000))
    lo, hi = int(frame_edge(k)), int(frame_edge(k + 1))
    t = np.arange(hi - lo) / 16000
    audio[lo:hi] = 0.5 * np.sin(2 * np.pi * 1000 * t)
    mel = log_mel(audio)[:, 0]
    energy = mel.max(axis=1)
    assert int(np.argmax(energy)) == k
    assert energy[k - 2] < energy[k] - 10 and energy[k + 2] < energy[k] - 10
    centres = np.linspace(2595 * np.log10(1 + 60 / 700), 2595 * np.log10(1 + 7600 / 700), 82)[1:-1]
    centre_hz = 700 * (10 ** (centres / 2595) - 1)
    assert abs(centre_hz[int(np.argmax(mel[k]))] - 1000) < 60


def test_frames_become_final_exactly_at_the_declared_lookahead() -> None:
    spec = DEFAULT_SPEC
    past_end = [spec.samples_needed(k + 1) - int(frame_edge(k + 1)) for k in range(60)]
    assert max(past_end) == spec.lookahead_samples and 0 < spec.lookahead_samples < 200  # about 8 ms
    for k in range(12):
        stream = LogMelStream(channels=1)
        stream.push(np.zeros(spec.samples_needed(k + 1) - 1))
        assert stream.frames_done == k  # frame k waits for the last sample of its window ...
        stream.push(np.zeros(1))
        assert stream.frames_done == k + 1  # ... and not a sample longer


def test_spec_round_trips_and_rejects_bad_values() -> None:
    assert MelSpec.from_dict(DEFAULT_SPEC.to_dict()) == DEFAULT_SPEC
    with pytest.raises(ValueError):
        MelSpec(window=801)
    with pytest.raises(ValueError):
        MelSpec(fmax=9000)
    small = MelSpec(bands=40, window=400, n_fft=512)
    assert log_mel(AUDIO, spec=small).shape == (69, 2, 40)
