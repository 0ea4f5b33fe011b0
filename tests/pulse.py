"""A real PulseAudio setup for live-audio tests: two private servers with null sinks, reached
through ALSA's pulse plugin under names PortAudio lists.

- the *desk* server has the robot's speaker (a null sink, ``speaker``); its monitor is what a
  microphone beside the speaker would hear;
- the *room* server has a null sink ``room`` into which a test plays the partner's voice; its
  monitor is the partner's microphone. Stopping the room server unplugs that microphone.

Each server is our own child process with its own runtime folder, so tests never touch a daemon
that was already running and leave nothing behind. Clients find the devices through an
``.asoundrc`` in a private ``HOME`` (``env``): ``convodrive_speaker``, ``convodrive_monitor`` and
``convodrive_mic``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.samples import bundled_dialogue

SPEAKER = "convodrive_speaker"
MONITOR = "convodrive_monitor"
MIC = "convodrive_mic"


class PulseServer:
    """One private ``pulseaudio`` with the given null sinks, stopped by ``stop``."""

    def __init__(self, root: Path, name: str, sinks: tuple[str, ...]) -> None:
        self.runtime = root / name
        self.runtime.mkdir(parents=True)
        self.runtime.chmod(0o700)
        self.socket = self.runtime / "native"
        args = [
            "pulseaudio",
            "-n",
            "--daemonize=no",
            "--exit-idle-time=-1",
            "--use-pid-file=no",
            "--disable-shm=yes",
            "--log-target=stderr",
            "--log-level=error",
            "-L",
            f"module-native-protocol-unix socket={self.socket} auth-anonymous=1",
        ]
        for sink in sinks:
            args += ["-L", f"module-null-sink sink_name={sink} rate=48000"]
        env = {**os.environ, "XDG_RUNTIME_DIR": str(self.runtime), "HOME": str(self.runtime)}
        self.log = open(self.runtime / "log.txt", "wb")
        self.process = subprocess.Popen(args, env=env, stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 10.0
        while not self._answers():
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"pulseaudio did not start: {(self.runtime / 'log.txt').read_text()[-500:]}")
            time.sleep(0.05)

    @property
    def server(self) -> str:
        return f"unix:{self.socket}"

    def _answers(self) -> bool:
        done = subprocess.run(["pactl", "--server", self.server, "info"], capture_output=True)
        return done.returncode == 0

    def play(self, path: Path, sink: str) -> subprocess.Popen:
        """Play a file into ``sink`` in real time (the partner talking into the room)."""
        return subprocess.Popen(
            ["paplay", "--server", self.server, "--device", sink, str(path)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.close()


class PulseRig:
    """The desk and room servers, and the client environment that names their devices."""

    def __init__(self, root: Path) -> None:
        for tool in ("pulseaudio", "pactl", "paplay"):
            if shutil.which(tool) is None:
                pytest.fail(f"{tool} is missing: scripts/setup.sh --dev installs PulseAudio")
        self.desk = PulseServer(root, "desk", ("speaker",))
        try:
            self.room = PulseServer(root, "room", ("room",))
        except BaseException:
            self.desk.stop()
            raise
        home = root / "home"
        home.mkdir()
        (home / ".asoundrc").write_text(
            f'pcm.{SPEAKER} {{ type pulse; server "{self.desk.server}"; device "speaker" }}\n'
            f'pcm.{MONITOR} {{ type pulse; server "{self.desk.server}"; device "speaker.monitor" }}\n'
            f'pcm.{MIC} {{ type pulse; server "{self.room.server}"; device "room.monitor" }}\n'
            f'pcm.!default {{ type pulse; server "{self.desk.server}"; device "speaker" }}\n'
        )
        self.env = {"HOME": str(home), "PULSE_SERVER": self.desk.server}
        """Environment for a client process (a convodrive run)."""

    def stop(self) -> None:
        self.room.stop()
        self.desk.stop()


@pytest.fixture
def pulse(tmp_path: Path) -> Iterator[PulseRig]:
    rig = PulseRig(tmp_path / "pulse")
    try:
        yield rig
    finally:
        rig.stop()


def dialogue_halves(out: Path, seconds: float | None = None, lead_in: float = 0.0) -> tuple[Path, Path]:
    """The bundled dialogue's self and partner channels as two mono files (optionally cut, and
    after ``lead_in`` seconds of silence)."""
    data, rate = sf.read(bundled_dialogue(), dtype="float32")
    if seconds is not None:
        data = data[: int(seconds * rate)]
    data = np.concatenate([np.zeros((int(lead_in * rate), 2), np.float32), data])
    out.mkdir(parents=True, exist_ok=True)
    paths = out / "SELF.wav", out / "PARTNER.wav"
    for channel, path in enumerate(paths):
        sf.write(path, np.ascontiguousarray(data[:, channel]), rate, subtype="PCM_16")
    return paths
