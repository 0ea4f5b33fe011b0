"""Audio input: formats, resampling, channels, bad files, and constant memory on long files."""

from __future__ import annotations

import subprocess
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


def _encode(src: Path, dst: Path, *args: str) -> Path:
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(src), *args, str(dst)], check=True)
    return dst


def _bursts(rate: int) -> np.ndarray:
    """2 s of stereo: a noise burst on each channel at a known place, for alignment checks."""
    rng = np.random.default_rng(0)
    data = np.zeros((2 * rate, 2), np.float32)
    data[rate // 2 : rate // 2 + 4000, 0] = 0.5 * rng.standard_normal(4000)
    data[rate : rate + 4000, 1] = 0.5 * rng.standard_normal(4000)
    return data


def _burst_start(voice: np.ndarray, reference: np.ndarray) -> int:
    return int(np.argmax(np.correlate(voice, reference, "valid")))


@pytest.mark.parametrize(
    "name, encode",
    [
        ("libsndfile.mp3", lambda wav, dst: sf.write(dst, sf.read(wav)[0], 44100, format="MP3") or dst),
        ("lame.mp3", lambda wav, dst: _encode(wav, dst, "-c:a", "libmp3lame", "-b:a", "128k")),
        ("aac.m4a", lambda wav, dst: _encode(wav, dst, "-c:a", "aac", "-b:a", "128k")),
    ],
)
@pytest.mark.ffmpeg
def test_compressed_formats_keep_length_channels_and_timing(tmp_path: Path, name: str, encode) -> None:
    """MP3 through libsndfile, M4A through ffmpeg: the right channel on the right side, aligned to
    the sample where the bursts were (no encoder delay left in), and the file's exact length."""
    data = _bursts(44100)
    wav = tmp_path / "src.wav"
    sf.write(wav, data, 44100)
    path = encode(wav, tmp_path / name)
    source = AudioSource(path)
    assert source.info.decoder == ("ffmpeg" if name.endswith("m4a") else "libsndfile")
    audio = source.read_all()
    assert len(audio.self_voice) == 2 * ANALYSIS_RATE
    ref = AudioSource(wav).read_all()
    burst = ANALYSIS_RATE // 2
    assert abs(_burst_start(audio.self_voice, ref.self_voice[burst : burst + 1451]) - burst) <= 2
    assert abs(_burst_start(audio.other_voice, ref.other_voice[2 * burst : 2 * burst + 1451]) - 2 * burst) <= 2
    assert np.abs(audio.self_voice[2 * burst :]).max() < 0.05  # the partner's burst stays on its channel


@pytest.mark.ffmpeg
def test_raw_aac_streams_to_its_end(tmp_path: Path) -> None:
    """ADTS AAC states no length: the source reads until the decoder stops."""
    wav = tmp_path / "src.wav"
    sf.write(wav, _bursts(48000), 48000)
    source = AudioSource(_encode(wav, tmp_path / "a.aac", "-c:a", "aac"))
    assert source.info.format == "AAC" and not source.info.exact_frames
    chunks = list(source.chunks())
    assert chunks[-1].final and all(not c.final for c in chunks[:-1])
    assert abs(sum(len(c) for c in chunks) - 2 * ANALYSIS_RATE) < 0.1 * ANALYSIS_RATE


@pytest.mark.ffmpeg
def test_long_m4a_in_constant_memory(tmp_path: Path) -> None:
    """10 minutes of AAC decode through ffmpeg's pipe without holding the audio."""
    wav = tmp_path / "long.wav"
    with sf.SoundFile(wav, "w", ANALYSIS_RATE, 2, "PCM_16") as fh:
        block_data = tones(ANALYSIS_RATE, 30)
        for _ in range(20):
            fh.write(block_data)
    source = AudioSource(_encode(wav, tmp_path / "long.m4a", "-c:a", "aac", "-b:a", "48k"))
    decoded_bytes = source.info.frames * 2 * 4
    tracemalloc.start()
    try:
        total = sum(len(chunk) for chunk in source.chunks())
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert total == 10 * 60 * ANALYSIS_RATE
    assert peak < decoded_bytes / 20, f"peak {peak / 1e6:.1f} MB for {decoded_bytes / 1e6:.0f} MB of samples"


def _m4a_without_index(p: Path) -> None:
    wav = p.with_suffix(".src.wav")
    sf.write(wav, tones(44100, 2.0), 44100)
    data = _encode(wav, p.with_suffix(".whole.m4a"), "-c:a", "aac").read_bytes()
    p.write_bytes(data[: len(data) // 2])  # the moov atom is at the end: ffprobe cannot open it


def _m4a_video_only(p: Path) -> None:
    cmd = ["ffmpeg", "-v", "error", "-y", "-f", "lavfi", "-i", "color=c=red:s=32x32:d=1", "-c:v", "mpeg4", "-f", "mp4"]
    subprocess.run([*cmd, str(p)], check=True)


@pytest.mark.parametrize(
    "make, problem",
    [
        (_random_bytes, "not a readable audio file"),
        (_empty, "empty"),
        (_text, "not a readable audio file"),
        (_m4a_without_index, "not a readable audio file"),
        (_m4a_video_only, "not a readable audio file"),
    ],
)
@pytest.mark.ffmpeg
def test_bad_m4a_files_are_one_line_errors(tmp_path: Path, make, problem: str) -> None:
    path = tmp_path / "bad.m4a"
    make(path)
    with pytest.raises(InputFileError) as err:
        AudioSource(path)
    message = str(err.value)
    assert message.startswith(str(path)) and problem in message and "\n" not in message


@pytest.mark.ffmpeg
def test_m4a_without_ffmpeg_is_one_line(tmp_path: Path, monkeypatch) -> None:
    wav = tmp_path / "src.wav"
    sf.write(wav, tones(44100, 1.0), 44100)
    source = AudioSource(_encode(wav, tmp_path / "a.m4a", "-c:a", "aac"))
    monkeypatch.setattr("convodrive.audio.ffmpeg.shutil.which", lambda name: None)
    with pytest.raises(InputFileError, match="needs ffmpeg") as err:
        list(source.chunks())
    assert str(err.value).startswith(str(tmp_path / "a.m4a"))


@pytest.mark.ffmpeg
@pytest.mark.parametrize("name", ["a.m4a", "no_extension"])
def test_m4a_without_ffprobe_names_ffprobe(tmp_path: Path, monkeypatch, name: str) -> None:
    """Without ffprobe an M4A is not "format not recognised": the message names what is missing."""
    wav = tmp_path / "src.wav"
    sf.write(wav, tones(44100, 1.0), 44100)
    path = _encode(wav, tmp_path / "a.m4a", "-c:a", "aac").rename(tmp_path / name)
    monkeypatch.setattr("convodrive.audio.ffmpeg.shutil.which", lambda name: None)
    with pytest.raises(InputFileError, match="needs ffprobe and ffmpeg") as err:
        AudioSource(path)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


def test_flac_failing_part_way_yields_what_came_before(tmp_path: Path) -> None:
    """A FLAC cut in half fails to decode near 2.5 s of 5: the chunks before the failure come out
    and the error names the position reached, not 0 s."""
    whole = tmp_path / "whole.flac"
    sf.write(whole, tones(16000, 5.0), 16000)
    data = whole.read_bytes()
    path = tmp_path / "cut.flac"
    path.write_bytes(data[: len(data) // 2])
    received = 0
    with pytest.raises(InputFileError, match="cannot be decoded after") as err:
        for chunk in AudioSource(path).chunks():
            received += len(chunk.self_voice)
    seconds = float(str(err.value).split("after ")[1].split(" s")[0])
    assert 1.5 <= seconds <= 2.6 and received / ANALYSIS_RATE >= seconds - 0.2


@pytest.mark.ffmpeg
def test_damaged_m4a_stops_with_one_line_not_a_short_clip(tmp_path: Path) -> None:
    """AAC decoding skips what it cannot read and exits 0; the source compares what came out with
    the length the container states, so a damaged file is an error, not a silently shorter run."""
    wav = tmp_path / "src.wav"
    sf.write(wav, tones(44100, 6.0), 44100)
    data = bytearray(_encode(wav, tmp_path / "whole.m4a", "-c:a", "aac").read_bytes())
    data[2000 : len(data) // 2] = np.random.default_rng(1).integers(0, 256, len(data) // 2 - 2000, np.uint8).tobytes()
    path = tmp_path / "damaged.m4a"
    path.write_bytes(bytes(data))
    source = AudioSource(path)
    with pytest.raises(InputFileError, match="decoding stopped at") as err:
        list(source.chunks())
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)
