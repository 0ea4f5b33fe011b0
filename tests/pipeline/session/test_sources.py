"""A session fed by sources instead of a framework: what ``convodrive live`` runs (here on the
virtual speaker, so no audio server is needed; tests/pipeline/test_live.py runs it on PulseAudio)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.eval.sync import level_db
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.npz import load_clip
from convodrive.pipeline.session import LiveSession, SessionRequest
from convodrive.plumbing.errors import UserError
from tests.pulse import dialogue_halves


def test_file_voice_and_file_partner_run_to_their_end(tmp_path):
    """The voice from a file plays on the virtual speaker and is the clock; the partner from a
    file is placed its delay after capture; the run ends by itself when both have been heard,
    the speaker has played the whole voice, and the mouth moved while it spoke."""
    self_wav, partner_wav = dialogue_halves(tmp_path / "in", seconds=4.0)
    out = tmp_path / "out"
    session = LiveSession(
        SessionRequest(voice=str(self_wav), partner=str(partner_wav), out_dir=out, generator_options={"phones": False})
    )
    started = []
    result = session.run(on_start=lambda: started.append(True))
    assert started == [True]
    report = json.loads(result.report_path.read_text())
    live = report["live"]
    assert live["clock"] == "playback" and live["playback"]["device"] == "virtual"
    assert live["self_voice"]["voice_seconds"] == pytest.approx(4.0, abs=0.05)
    assert live["partner"]["delivered_seconds"] == pytest.approx(4.0, abs=0.05)
    delay = live["latency_ms"]["partner_delay"] / 1000
    assert report["frames"] == pytest.approx((4.0 + delay) * 30, abs=6)
    assert live["latency_ms"]["partner_capture_to_sent"]["record"]["count"] >= 30
    assert not live["audio_motion_offset"]["measured"] and live["generator_offset"]["pairs"] >= 1
    assert any(line.startswith("live: the clock is the speaker 'virtual'") for line in report["summary_lines"])
    # The speaker played the voice, and the motion file's mouth opened where it was loud.
    voice, _ = sf.read(self_wav, dtype="float32")
    played = session.speaker.samples()
    loud = lambda x: np.count_nonzero(level_db(x, ANALYSIS_RATE) > -35)  # noqa: E731
    assert loud(played) == pytest.approx(loud(voice), rel=0.05)
    jaw = load_clip(out / "motion.npz").face[:, BLENDSHAPE_INDEX["jawOpen"]]
    assert jaw.max() > 0.3


@pytest.mark.parametrize(
    "request_, problem",
    [
        (SessionRequest(voice="none", partner="none"), "voice none and partner none: nothing to listen to"),
        (SessionRequest(mode="follower", voice="x.wav"), "follower mode: the framework plays the voice"),
        (SessionRequest(seconds=float("nan")), "seconds must be positive and finite, got nan"),
        (SessionRequest(partner="{dir}/missing.wav"), "missing.wav: no such file (partner takes an audio file"),
        (SessionRequest(voice="tcp://127.0.0.1"), "expected tcp://HOST:PORT"),
    ],
)
def test_a_bad_source_is_a_user_error_naming_it(tmp_path, request_: SessionRequest, problem: str) -> None:
    if request_.partner:
        request_.partner = request_.partner.format(dir=tmp_path)
    request_.out_dir = tmp_path / "out"
    with pytest.raises(UserError, match=None) as caught:
        LiveSession(request_).run()
    assert problem in str(caught.value)
    assert not (tmp_path / "out" / "run_report.json").exists()
