"""convodrive corpus make with speech the user has: recorded voices paired, two-channel
recordings taken as they are, each source's licence and hours in the manifest."""

from __future__ import annotations

import json
from pathlib import Path

import soundfile as sf

from tests.conftest import run_cli


def test_recorded_conversations_and_voices_join_the_corpus(real_dialogue, tmp_path: Path) -> None:  # noqa: ANN001
    d = real_dialogue
    convs = tmp_path / "calls"
    convs.mkdir()
    sf.write(convs / "call1.wav", d.dialogue.audio, 16000, subtype="PCM_16")
    sf.write(convs / "call2.wav", d.dialogue.audio[: 16000 * 10], 16000, subtype="PCM_16")
    turns = [{"speaker": "self", "start": a, "end": b} for a, b in d.truth.self_speech]
    (convs / "call1.json").write_text(json.dumps(turns))
    (convs / "source.json").write_text('{"licence": "CC0-1.0", "language": "en"}')
    voices = Path(d.voices)
    out = tmp_path / "corpus"
    args = ["corpus", "make", "--hours", "0", "--takes", "1", "--jobs", "1", "--out", str(out)]
    made = run_cli(*args, "--conversations", str(convs), "--voices", str(voices / "librivox"),
                   "--voices", str(voices / "asterisk-ru"), "--voice-hours", "0.005")  # fmt: skip
    assert made.returncode == 0, made.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    sources = {s["name"]: s for s in manifest["source"]["sources"]}
    assert set(sources) == {"calls", "librivox", "asterisk-ru"}
    assert sources["calls"]["licence"] == "CC0-1.0" and 0.008 < sources["calls"]["hours"] < 0.01
    assert "CC-BY-3.0" in sources["asterisk-ru"]["licence"] and "calls: CC0-1.0" in manifest["licence"]
    meta = {c["id"]: c["metadata"] for c in manifest["conversations"]}
    assert meta["rec00000-call1"]["turns_from"] == "segments file"
    assert meta["rec00000-call1"]["speech"]["self"] == [list(t) for t in d.truth.self_speech]
    assert meta["rec00001-call2"]["turns_from"] == "voice activity" and meta["rec00001-call2"]["speech"]["self"]
    pair = meta["pair00000"]["voices"]
    assert {pair["self"]["speaker"], pair["partner"]["speaker"]} == {"librivox/austen", "asterisk-ru/maxim"}
    (convs / "source.json").unlink()
    bad = run_cli(*args[:-1], str(tmp_path / "other"), "--conversations", str(convs))
    assert bad.returncode == 2 and "no source.json" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
