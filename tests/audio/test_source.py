"""Audio input: formats, resampling, channels, bad files, and constant memory on long files."""

from __future__ import annotations

import tracemalloc
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from scipy.signal import resample_poly

from convodrive.audio.source import ANALYSIS_RATE, CHUNK_SAMPLES, AudioSource, ChannelMap
from convodrive.plumbing.errors import InputFileError


def tones(rate: int, seconds: float, freqs=(220.0, 330.0), amp: float = 0.4) -> np.ndarray:
    t = np.arange(int(rate * seconds)) / rate
    return np.stack([amp * np.sin(2 * np.pi * f * t) for f in freqs], axis=1).astype(np.float32)


def dominant_freq(x: np.ndarray, rate: int) -> float:
    spectrum = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    return float(np.fft.rfftfreq(len(x), 1 / rate)[np.argmax(spectrum)])


@pytest.mark.parametrize(
    "fmt, subtype, tol", [("WAV", "PCM_16", 1e-4), ("FLAC", "PCM_16", 1e-4), ("OGG", "VORBIS", None)]
)
def test_formats(tmp_path: Path, fmt: str, subtype: str, tol: float | None) -> None:
    data = tones(ANALYSIS_RATE, 1.5)
    path = tmp_path / f"a.{fmt.lower()}"
    sf.write(path, data, ANALYSIS_RATE, format=fmt, subtype=subtype)
    audio = AudioSource(path).read_all()
    assert len(audio.self_voice) == len(data)
    if tol is not None:
        np.testing.assert_allclose(audio.self_voice, data[:, 0], atol=tol)
        np.testing.assert_allclose(audio.other_voice, data[:, 1], atol=tol)
    else:  # lossy: the right tone on the right channel
        assert dominant_freq(audio.self_voice, ANALYSIS_RATE) == pytest.approx(220, abs=2)
        assert dominant_freq(audio.other_voice, ANALYSIS_RATE) == pytest.approx(330, abs=2)


@pytest.mark.parametrize("rate", [44100, 48000, 96000])
def test_resampling_matches_whole_file_polyphase(tmp_path: Path, rate: int) -> None:
    rng = np.random.default_rng(rate)
    data = (tones(rate, 5.3) + 0.05 * rng.standard_normal((int(rate * 5.3), 2))).astype(np.float32)
    path = tmp_path / "hi.wav"
    sf.write(path, data, rate, subtype="FLOAT")
    source = AudioSource(path)
    chunks = list(source.chunks())
    assert all(len(c) == CHUNK_SAMPLES for c in chunks[:-1]) and chunks[-1].final
    assert [c.start for c in chunks] == [i * CHUNK_SAMPLES for i in range(len(chunks))]
    got = np.stack(
        [np.concatenate([c.self_voice for c in chunks]), np.concatenate([c.other_voice for c in chunks])], axis=1
    )
    ratio = Fraction(ANALYSIS_RATE, rate)
    want = resample_poly(data.astype(np.float64), ratio.numerator, ratio.denominator, axis=0)
    assert abs(len(got) - len(want)) <= 1
    n = min(len(got), len(want))
    np.testing.assert_allclose(got[:n], want[:n], atol=1e-4)


def test_mono_means_a_silent_partner(tmp_path: Path) -> None:
    path = tmp_path / "mono.wav"
    sf.write(path, tones(ANALYSIS_RATE, 1.0)[:, 0], ANALYSIS_RATE)
    audio = AudioSource(path).read_all()
    assert np.abs(audio.self_voice).max() > 0.3
    assert not np.any(audio.other_voice) and len(audio.other_voice) == len(audio.self_voice)


def test_more_channels_need_a_choice(tmp_path: Path) -> None:
    path = tmp_path / "four.wav"
    sf.write(path, tones(ANALYSIS_RATE, 1.0, freqs=(200, 300, 400, 500)), ANALYSIS_RATE)
    with pytest.raises(InputFileError, match="--channels") as err:
        AudioSource(path)
    assert str(path) in str(err.value)
    audio = AudioSource(path, ChannelMap(2, 3)).read_all()
    assert dominant_freq(audio.self_voice, ANALYSIS_RATE) == pytest.approx(400, abs=2)
    assert dominant_freq(audio.other_voice, ANALYSIS_RATE) == pytest.approx(500, abs=2)
    with pytest.raises(InputFileError, match="no channel 4"):
        AudioSource(path, ChannelMap(0, 4))
    assert ChannelMap.parse("2,3") == ChannelMap(2, 3) and ChannelMap.parse("1,-") == ChannelMap(1, None)


def _random_bytes(p: Path) -> None:
    p.write_bytes(np.random.default_rng(0).bytes(4096))


def _truncated_header(p: Path) -> None:
    sf.write(p, tones(ANALYSIS_RATE, 0.5), ANALYSIS_RATE)
    p.write_bytes(p.read_bytes()[:30])


def _empty(p: Path) -> None:
    p.write_bytes(b"")


def _text(p: Path) -> None:
    p.write_text("this is not audio\n" * 50)


def _nan(p: Path) -> None:
    data = tones(ANALYSIS_RATE, 3.0)
    data[40000, 1] = np.nan
    sf.write(p, data, ANALYSIS_RATE, subtype="FLOAT")


def _header_only(p: Path) -> None:
    sf.write(p, np.zeros((0, 2), np.float32), ANALYSIS_RATE)


@pytest.mark.parametrize(
    "make, problem",
    [
        (_random_bytes, "not a readable audio file"),
        (_truncated_header, "not a readable audio file"),
        (_empty, "empty"),
        (_text, "not a readable audio file"),
        (_nan, "NaN"),
        (_header_only, "no samples"),
    ],
)
def test_bad_files_are_one_line_errors(tmp_path: Path, make, problem: str) -> None:
    path = tmp_path / "bad.wav"
    make(path)
    with pytest.raises(InputFileError) as err:
        AudioSource(path)
    message = str(err.value)
    assert message.startswith(str(path)) and problem in message and "\n" not in message


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="no such file") as err:
        AudioSource(tmp_path / "absent.wav")
    assert str(tmp_path / "absent.wav") in str(err.value)


def test_long_file_in_constant_memory(tmp_path: Path) -> None:
    """20 minutes of 16 kHz stereo (77 MB as 16-bit) stream through in a few MB."""
    path = tmp_path / "long.wav"
    minutes = 20
    with sf.SoundFile(path, "w", ANALYSIS_RATE, 2, "PCM_16") as fh:
        block_data = tones(ANALYSIS_RATE, 30)
        for _ in range(minutes * 2):
            fh.write(block_data)
    file_size = path.stat().st_size
    source = AudioSource(path)
    tracemalloc.start()
    try:
        total = 0
        for chunk in source.chunks():
            total += len(chunk)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert total == minutes * 60 * ANALYSIS_RATE
    assert peak < file_size / 10, f"peak {peak / 1e6:.1f} MB for a {file_size / 1e6:.0f} MB file"
