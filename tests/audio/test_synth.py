"""Synthetic dialogues (espeak-ng) and the bundled sample made with them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio import synth
from convodrive.audio.synth import PARTNER, SELF, Turn, synthesize_dialogue
from convodrive.plumbing.errors import UserError
from convodrive.samples import bundled_dialogue


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


@pytest.mark.espeak
def test_turns_land_on_their_channels_at_their_times(tmp_path: Path) -> None:
    turns = [
        Turn(SELF, "one two three four", voice="en-us", pitch=30),
        Turn(PARTNER, "yes", voice="en-us+f3", pitch=75, gap=-0.4),  # overlaps the end of self
        Turn(PARTNER, "and then what", voice="en-us+f3", rate=200, start=3.0),
    ]
    info = synthesize_dialogue(turns, tmp_path / "d.wav", sample_rate=22050, seed=1)
    data, rate = sf.read(tmp_path / "d.wav")
    assert rate == 22050 and data.shape[1] == 2 and sf.info(tmp_path / "d.wav").subtype == "PCM_16"
    t0, t1, t2 = info.turns
    assert t1.start == pytest.approx(t0.end - 0.4) and t2.start == 3.0
    assert info.duration == pytest.approx(len(data) / rate)
    for t in info.turns:
        inside = data[int(t.start * rate) : int(t.end * rate)]
        assert rms(inside[:, t.speaker]) > 0.05
    lead = data[: int(0.4 * rate)]
    assert rms(lead[:, 0]) < 0.01 and rms(lead[:, 1]) < 0.01  # silence before the first turn
    pause = data[int((max(t0.end, t1.end) + 0.05) * rate) : int((t2.start - 0.05) * rate)]
    assert len(pause) > 0.5 * rate and rms(pause[:, 0]) < 0.01 and rms(pause[:, 1]) < 0.01


def test_missing_espeak_is_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(synth.shutil, "which", lambda name: None)
    with pytest.raises(UserError, match="espeak-ng is not installed"):
        synthesize_dialogue([Turn(SELF, "hi")], tmp_path / "d.wav")
    assert not (tmp_path / "d.wav").exists()


def test_bundled_dialogue() -> None:
    path = bundled_dialogue()
    info = sf.info(path)
    assert info.channels == 2 and info.subtype == "PCM_16" and info.samplerate in (16000, 22050)
    assert 15 <= info.duration <= 30
    sidecar = Path(__file__).resolve().parents[2] / "samples" / "dialogue.json"  # source tree only
    turns = json.loads(sidecar.read_text())["turns"]
    assert len(turns) >= 6 and {t["channel"] for t in turns} == {0, 1}
    changes = sum(a["channel"] != b["channel"] for a, b in zip(turns, turns[1:]))
    assert changes >= 5
    spans = [(t["start"], t["end"], t["channel"]) for t in turns]
    overlaps = [(a, b) for a in spans for b in spans if a[2] == 0 and b[2] == 1 and a[0] < b[1] and b[0] < a[1]]
    assert overlaps, "both must talk at once somewhere"
    ordered = sorted(spans)
    assert any(b[0] - max(e for _, e, _ in ordered[: i + 1]) > 0.2 for i, b in enumerate(ordered[1:])), "a pause"
    data, rate = sf.read(path)
    for start, end, channel in spans:
        assert rms(data[int(start * rate) : int(end * rate), channel]) > 0.03
