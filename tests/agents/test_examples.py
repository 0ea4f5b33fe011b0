"""The example agents (examples/) run offline for a few seconds: a user's line from a file, a
scripted reply spoken by espeak-ng and played by convodrive, into the recorder and the emulated
Dynamixel head. The mouth follows the played voice (jawOpen against the voice's envelope, frame
by frame), the head got goals, and it ends torque off."""

from __future__ import annotations

import importlib
import importlib.util

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.source import ANALYSIS_RATE
from convodrive.generators.base import Event
from tests.conftest import REPO, require
from tests.pipeline.session.helpers import voice

pytestmark = [require("espeak"), require("hardware")]
FPS = 30


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def envelope(samples: np.ndarray, rate: int, frames: np.ndarray) -> np.ndarray:
    """RMS of the voice over each motion frame's 1/30 s on the speaker's time line."""
    per = rate // FPS
    out = np.zeros(len(frames))
    for j, k in enumerate(frames):
        window = samples[k * per : (k + 1) * per]
        out[j] = np.sqrt(np.mean(window**2)) if len(window) else 0.0
    return out


def run_example(name: str, tmp_path) -> tuple:
    from convodrive.backends.servo.dynamixel_emulator import start_emulated_head

    user = np.concatenate([voice("When does the train leave?"), np.zeros(3 * ANALYSIS_RATE, np.int16)])
    wav = tmp_path / "user.wav"
    sf.write(wav, user, ANALYSIS_RATE)
    example = load_example(name)
    with start_emulated_head() as head:
        # The reply plays from about 3.8 s to 5.8 s; 8 s leaves room for a stalled machine, whose
        # speaker underruns and stretches the voice past a tighter end (seen in CI).
        argv = ["--partner", str(wav), "--channel", "0", "--seconds", "8", "--out", str(tmp_path / "out")]
        argv += ["--backend", "record,dynamixel", "-B", f"dynamixel.port={head.port}", "-B", "dynamixel.ease_s=0.2"]
        live = example.main(argv)
        goals = len(head.goals(1))
        torque = [head.servo(i).torque for i in range(1, 8)]
    return live, goals, torque


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ["pipecat_agent", "livekit_agent"])
def test_example_agent_moves_the_mouth_with_its_voice(name, tmp_path):
    framework = {"pipecat_agent": "pipecat", "livekit_agent": "livekit.agents"}[name]
    if importlib.util.find_spec(framework.split(".")[0]) is None:
        pytest.skip(f"needs {framework}: pip install 'convodrive[{framework.split('.')[0]}]'")
    live, goals, torque = run_example(name, tmp_path)
    kinds = [e.kind for _, e in live.events]
    assert Event.SPEAKING_START in kinds and kinds.index(Event.SPEAKING_START) > kinds.index(Event.THINKING_START)
    played = live.speaker.samples()
    heard = np.nonzero(np.abs(played) > 0.05)[0]
    assert len(heard) and heard[-1] - heard[0] > 0.8 * ANALYSIS_RATE  # the scripted reply was played
    frames = np.array([f[0] for f in live.frames])
    jaw = np.array([f[2] for f in live.frames])
    span = (frames >= heard[0] / ANALYSIS_RATE * FPS - 15) & (frames <= heard[-1] / ANALYSIS_RATE * FPS + 15)
    assert span.sum() > FPS, f"the session ended {span.sum()} frames into the reply"
    level = envelope(played, live.speaker.rate, frames[span])
    assert np.corrcoef(level, jaw[span])[0, 1] > 0.5  # 0.84-0.87 here
    assert goals > 60 and not any(torque)  # the head followed, and ended torque off
    assert (tmp_path / "out" / "voice.wav").exists()
