"""A damaged corpus is one line on stderr naming the file, exit code 2, through the CLI."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import soundfile as sf

from convodrive.corpus import Corpus, Recording
from tests.conftest import cli_in_process, run_cli


def _fails_with(folder: Path, *fragments: str) -> str:
    result = cli_in_process("corpus", "info", str(folder))
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def test_a_sound_corpus_passes_info(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, _ = small_corpus
    result = run_cli("corpus", "info", str(folder))
    assert result.returncode == 0, result.stderr
    assert "6 conversations" in result.stdout and "ok: every shard" in result.stdout
    assert "calm (3)" in result.stdout and "lively (3)" in result.stdout


def test_missing_shard(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, _ = small_corpus
    (folder / "shards" / "shard-00001.npz").unlink()
    _fails_with(folder, "shard-00001.npz", "shard missing")


def test_truncated_shard(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, _ = small_corpus
    shard = folder / "shards" / "shard-00000.npz"
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    _fails_with(folder, "shard-00000.npz", "truncated", f"the manifest says {len(data)}")


def test_shard_with_its_end_overwritten_keeps_its_size_but_is_caught(
    small_corpus: tuple[Path, list[Recording]],
) -> None:
    folder, _ = small_corpus
    shard = folder / "shards" / "shard-00000.npz"
    data = bytearray(shard.read_bytes())
    data[-200:] = bytes(200)  # the zip directory at the end is gone; the size is unchanged
    shard.write_bytes(bytes(data))
    _fails_with(folder, "shard-00000.npz", "truncated or corrupt shard")


def test_audio_whose_length_disagrees_with_its_motion(small_corpus: tuple[Path, list[Recording]]) -> None:
    folder, _ = small_corpus
    wav = folder / "audio" / "c2.wav"
    audio, rate = sf.read(wav, dtype="int16")
    sf.write(wav, audio[: len(audio) - 8000], rate, subtype="PCM_16")
    _fails_with(folder, "c2.wav", "audio lasts 5.600 s (168 motion frames) but its motion has 183")


def test_missing_manifest_and_missing_folder(small_corpus: tuple[Path, list[Recording]], tmp_path: Path) -> None:
    folder, _ = small_corpus
    (folder / "manifest.json").unlink()
    _fails_with(folder, "no manifest.json", "did not finish")
    _fails_with(tmp_path / "nowhere", "no such corpus folder")


def test_reading_never_writes(small_corpus: tuple[Path, list[Recording]], tmp_path: Path) -> None:
    folder, _ = small_corpus
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    before = {p: p.stat().st_mtime_ns for p in copy.rglob("*")}
    corpus = Corpus.open(copy)
    list(corpus.check())
    corpus.sample_windows("train", 30, 5, np.random.default_rng(0))
    assert {p: p.stat().st_mtime_ns for p in copy.rglob("*")} == before
