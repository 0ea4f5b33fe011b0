"""``convodrive live`` end to end against a real PulseAudio server with null sinks.

The speaker is a null sink; its monitor is a microphone beside it, so the run records what really
left the speaker and measures when the mouth opened against it.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.live.capture import LOST_SECONDS
from convodrive.audio.synth import speak
from convodrive.audio.voice_tracker import VoiceParams
from convodrive.eval.sync import HOP_SECONDS, level_db, mouth_onsets, pair_onsets, speech_onsets
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.npz import load_clip
from tests.conftest import run_cli
from tests.pulse import MIC, MONITOR, SPEAKER, PulseRig, dialogue_halves

pytestmark = [pytest.mark.pulseaudio, pytest.mark.live, pytest.mark.espeak]

JAW = BLENDSHAPE_INDEX["jawOpen"]
FRAME_MS = 1000.0 / 30


def _live(pulse, out: Path, *args: str, timeout: float = 120):
    done = run_cli("live", "--out", str(out), *args, env=pulse.env, timeout=timeout)
    report = json.loads((out / "run_report.json").read_text()) if (out / "run_report.json").exists() else None
    return done, report


@pytest.mark.parametrize("latency", ["0.1", "0.3"])
def test_mouth_opens_when_the_speaker_says_so(pulse, tmp_path: Path, latency: str) -> None:
    """The self voice is played, the speaker's monitor recorded; mouth openings follow the speech
    onsets heard within a frame, also with 300 ms of output latency (which a clock that did not
    read the playback position would show as a 300 ms offset)."""
    # 1.5 s of silence first: onsets in the stream's first second would test the audio server's
    # start-up more than the clock.
    self_wav, partner_wav = dialogue_halves(tmp_path / "in", seconds=10.0, lead_in=1.5)
    out = tmp_path / "out"
    done, report = _live(
        pulse,
        out,
        "--self", str(self_wav), "--partner", str(partner_wav),
        "--play", SPEAKER, "--monitor", MONITOR, "--play-latency", latency,
        "--backend", "record",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    live = report["live"]
    assert live["clock"] == "playback"
    assert live["playback"]["output_latency_ms"] >= 1000.0 * float(latency) - 20.0
    offset = live["audio_motion_offset"]
    assert offset["measured"] and offset["pairs"] >= 3, offset
    assert abs(offset["median_ms"]) <= FRAME_MS, offset
    assert offset["min_ms"] >= -45.0 and offset["max_ms"] <= 45.0, offset  # ITU-R BT.1359: unnoticed
    assert abs(live["sync_error_ms"]) <= 10.0, live

    # Again from the evidence the run saved, with this test's own arithmetic: each onset heard at
    # the monitor against the mouth opening sent, less what the generator does on purpose for that
    # onset (measured on the audio it was given, against frame times k/30), is the clock's error.
    evidence = np.load(out / "sync.npz")
    monitor = evidence["monitor"].astype(np.float32) / 32768.0
    rate = int(evidence["monitor_rate"])
    onset_samples = (speech_onsets(level_db(monitor, rate)) * rate).astype(int)
    heard = np.interp(onset_samples, evidence["monitor_index"], evidence["monitor_mono"])
    jaw = load_clip(out / "motion.npz").face[:, JAW]
    assert np.allclose(jaw[: len(evidence["jaw_open"])], evidence["jaw_open"], atol=1e-6)
    shown = evidence["frame_dispatch_mono"][mouth_onsets(evidence["jaw_open"])]
    live_pairs = pair_onsets(heard, shown)
    assert live_pairs.summary()["median_ms"] == pytest.approx(offset["median_ms"], abs=3.0)
    own = pair_onsets(speech_onsets(evidence["self_level_db"]), mouth_onsets(evidence["jaw_open"]) / 30)
    assert len(own.offsets_ms) == len(live_pairs.offsets_ms) >= 3
    clock_error = live_pairs.offsets_ms - own.offsets_ms
    # Typically within 12 ms; on a starved CPU one frame may go out late (counted as a late frame),
    # which must still stay inside what viewers notice.
    assert np.median(np.abs(clock_error)) <= 12.0 and np.all(np.abs(clock_error) <= 45.0), clock_error

    # The motion covers the whole voice, and the report carries the latency figures.
    latency_ms = live["latency_ms"]
    # The run ends when the partner's last sample has been heard: the partner delay after the file.
    assert report["frames"] == pytest.approx((11.5 + latency_ms["partner_delay"] / 1000) * 30, abs=10)
    assert latency_ms["self_lead"] > report["generator"]["lookahead_ms"] >= 115.0  # the voice is heard before it plays
    assert latency_ms["partner_delay"] >= report["generator"]["lookahead_ms"] + 10.0  # and the partner's block, too
    assert latency_ms["partner_capture_to_sent"]["record"]["count"] > 200
    assert report["backends"]["record"]["dispatch_to_sent_ms"]["count"] == report["frames"]
    assert "audio–motion offset at the monitor" in done.stdout


def _busy_port() -> tuple[socket.socket, int]:
    held = socket.socket()
    held.bind(("127.0.0.1", 0))
    held.listen(1)
    return held, held.getsockname()[1]


@pytest.mark.parametrize(
    "args, problem",
    [
        (["--play", "nosuch", "--self", "{self}"], "--play 'nosuch': no such output device"),
        (["--partner", "nosuch-mic"], "--partner 'nosuch-mic': no such input device"),
        (["--monitor", "nosuch"], "--monitor 'nosuch': no such input device"),
        (["--self", "{dir}/missing.wav"], "missing.wav: no such file"),
        (["--partner", "{dir}/missing.wav"], "missing.wav: no such file"),
        (["--self", "tcp://127.0.0.1:{busy}"], "cannot listen there (the port is busy)"),
        (["--self", "tcp://127.0.0.1"], "expected tcp://HOST:PORT"),
        (["--backend", "stream", "-B", "stream.port={busy}"], "backend stream: cannot listen on 127.0.0.1:"),
        (["--seconds", "-1"], "--seconds must be positive"),
        (["--seconds", "nan"], "--seconds must be positive and finite, got nan"),
        (["--seconds", "inf"], "--seconds must be positive and finite, got inf"),
        (["--self", "{nan}"], "nan.wav: audio holds NaN or infinite samples"),
        (["--partner", "{nan}"], "nan.wav: audio holds NaN or infinite samples"),
        (["--backend", "nosuch"], "nosuch"),
    ],
)
def test_bad_input_is_one_line(pulse, tmp_path: Path, args: list[str], problem: str) -> None:
    self_wav, _ = dialogue_halves(tmp_path / "in", seconds=2.0)
    voice, rate = sf.read(self_wav, dtype="float32")
    voice[rate // 2] = np.nan  # a self voice and a partner with NaN are refused alike, naming the file
    sf.write(tmp_path / "nan.wav", voice, rate, subtype="FLOAT")
    held, busy = _busy_port()
    try:
        args = [a.format(self=self_wav, dir=tmp_path, busy=busy, nan=tmp_path / "nan.wav") for a in args]
        done = run_cli(
            "live", "--partner", "none", "--seconds", "1", "--out", str(tmp_path / "out"), *args, env=pulse.env
        )
    finally:
        held.close()
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and problem in lines[0], done.stderr
    assert not (tmp_path / "out" / "run_report.json").exists()


@pytest.mark.parametrize("side", ["--partner", "--self"])
def test_a_file_that_stops_decoding_ends_the_run(pulse, tmp_path: Path, side: str) -> None:
    """A FLAC cut in half (5 s of speech, decodable for about 2.3 s): the run ends there, as a
    drive does, with the report saying why and exit code 2; no thread traceback, no endless run."""
    self_wav, _ = dialogue_halves(tmp_path / "in", seconds=5.0)
    voice, rate = sf.read(self_wav, dtype="float32")
    sf.write(tmp_path / "whole.flac", voice, rate)
    data = (tmp_path / "whole.flac").read_bytes()
    cut = tmp_path / "cut.flac"
    cut.write_bytes(data[: len(data) // 2])
    other = "--self" if side == "--partner" else "--partner"
    out = tmp_path / "out"
    done, report = _live(
        pulse, out, side, str(cut), other, "none", "--play", SPEAKER, "--backend", "record", timeout=60
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "cut.flac: the audio cannot be decoded" in last and "the run stopped there" in last, last
    assert "cut.flac: the audio cannot be decoded" in report["input_error"]
    assert report["frames"] < 5.0 * 30, "the run ended where the file failed, not at its length"
    assert "stopped early: " in (out / "run_report.txt").read_text()


def test_seconds_without_inputs_runs_that_long(pulse, tmp_path: Path) -> None:
    """``--partner none --self none --seconds 2`` (what the error without --seconds suggests)
    runs 2 seconds of frames, not the handful before the absent inputs 'ended'."""
    done, report = _live(pulse, tmp_path / "out", "--partner", "none", "--self", "none", "--seconds", "2")
    assert done.returncode == 0, done.stderr
    assert 2 * 30 - 2 <= report["frames"] <= 2 * 30 + 1, report["frames"]


def test_list_devices_names_the_sinks(pulse) -> None:
    done = run_cli("live", "--list-devices", env=pulse.env)
    assert done.returncode == 0, done.stderr
    for name in (SPEAKER, MONITOR, MIC):
        assert name in done.stdout


def _connect(port: int, timeout: float = 30.0) -> socket.socket:
    deadline = time.monotonic() + timeout
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=5)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_self_stream_that_stops_mid_sentence(pulse, tmp_path: Path) -> None:
    """An agent streams half a sentence over the socket, goes quiet with the connection open, then
    hangs up: the mouth closes soon after the voice stops, and the run goes on to its end."""
    voice = speak("Well, the thing about the robot head is that it", rate=150)
    sent = voice[: int(1.3 * 16000)]  # stops mid-word
    pcm = np.clip(sent * 32767, -32768, 32767).astype("<i2").tobytes()
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    out = tmp_path / "out"
    run = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "live", "--self", f"tcp://127.0.0.1:{port}",
         "--partner", "none", "--play", SPEAKER, "--monitor", MONITOR, "--seconds", "6",
         "--backend", "record", "--out", str(out)],
        env={**os.environ, **pulse.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        agent = _connect(port)
        time.sleep(1.0)
        step = 320 * 2  # 20 ms of s16le, at the pace a speech synthesiser streams
        for i in range(0, len(pcm), step):
            agent.sendall(pcm[i : i + step])
            time.sleep(0.02)
        time.sleep(2.0)  # quiet, connection still open
        agent.close()
        stdout, stderr = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, stderr
    report = json.loads((out / "run_report.json").read_text())
    events = [e["event"] for e in report["live"]["events"]]
    assert any("connected" in e for e in events) and "speaker hung up" in events, events
    assert any("voice ran out while its speaker is connected" in e for e in events), events
    assert report["frames"] == pytest.approx(6 * 30, abs=10)
    jaw = load_clip(out / "motion.npz").face[:, JAW]
    open_frames = np.flatnonzero(jaw > 0.1)
    assert len(open_frames) >= 10, "the streamed speech moved the mouth"
    spoken = (open_frames[-1] - open_frames[0]) / 30
    assert spoken <= 1.3 + 0.3, spoken  # the mouth stopped with the voice, not later
    assert np.all(jaw[open_frames[-1] + 1 :] < 0.1) and len(jaw) - open_frames[-1] > 60
    heard = np.load(out / "sync.npz")["monitor"].astype(np.float32) / 32768
    loud_sent, loud_heard = (np.sum(level_db(x, 16000) > -35) * HOP_SECONDS for x in (sent, heard))
    assert loud_heard == pytest.approx(loud_sent, abs=0.1), "the half sentence was played, and only once"


def _partner_on_the_mic(
    pulse: PulseRig, tmp_path: Path, words: np.ndarray, meanwhile: Callable[[subprocess.Popen], None]
) -> tuple[dict[str, Any], Path]:
    """Seven seconds of ``convodrive live`` (the dialogue's self half on the speaker, the record
    backend) with ``words`` said into the room's microphone from the start; ``meanwhile(run)``
    acts while it runs. The run's report and its output folder."""
    partner_wav = tmp_path / "partner_talks.wav"
    sf.write(partner_wav, np.concatenate([np.zeros(8000, np.float32), words, np.zeros(48000, np.float32)]), 16000)
    self_wav, _ = dialogue_halves(tmp_path / "in", seconds=7.0)
    out = tmp_path / "out"
    run = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "live", "--self", str(self_wav), "--partner", MIC,
         "--play", SPEAKER, "--seconds", "7", "--backend", "record", "--out", str(out)],
        env={**os.environ, **pulse.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    talking = None
    try:
        assert run.stderr is not None and "live at 30 fps" in run.stderr.readline()  # the run is listening
        talking = pulse.room.play(partner_wav, "room")
        meanwhile(run)
        stdout, stderr = run.communicate(timeout=60)
    finally:
        run.send_signal(signal.SIGCONT)
        if talking is not None:
            talking.kill()
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, stderr
    return json.loads((out / "run_report.json").read_text()), out


def _talk_through_the_run() -> np.ndarray:
    return speak(
        "Yes, I saw it yesterday, and it looked great. Then we walked home together along the river, "
        "talking about the weather, the long winter and the little boats on the water.",
        rate=150,
    )


def test_microphone_that_disappears(pulse: PulseRig, tmp_path: Path) -> None:
    """The partner talks into a microphone that is unplugged mid-run: one line in the report, the
    run goes on to its end with a silent partner."""

    def unplug(run: subprocess.Popen) -> None:
        time.sleep(4.0)
        pulse.room.stop()  # the microphone's server goes away, as an unplugged USB microphone does

    words = speak("Yes, I saw it yesterday, and it looked great.", voice="en-us+f3", rate=170)
    report, out = _partner_on_the_mic(pulse, tmp_path, words, unplug)
    partner = report["live"]["partner"]
    assert partner["lost"], partner
    assert partner["input_latency_ms"] <= 12.0, partner  # opened at 10 ms: PulseAudio calls back every 5 ms
    assert {"late_blocks", "late_ms", "late_dropped_ms"} <= partner.keys()
    lost = [e for e in report["live"]["events"] if e["event"].startswith("partner input lost")]
    assert len(lost) == 1, report["live"]["events"]
    assert report["frames"] == pytest.approx(7 * 30, abs=10), "the run went on to the end of the self voice"
    vad = load_clip(out / "motion.npz").vad[:, 1]
    lost_frame = int(lost[0]["time"] * 30)
    assert vad[:lost_frame].max() > 0.5, "the partner was heard while the microphone worked"
    # What was captured before the loss sits up to the partner delay after it on the time line (a
    # loaded machine raises that delay), and the voice activity holds on for its hangover after that.
    delay_frames = math.ceil(report["live"]["latency_ms"]["partner_delay"] / FRAME_MS)
    silent_from = lost_frame + delay_frames + VoiceParams().vad_hangover + 3  # 3: the feature frames' own reach
    assert len(vad) - silent_from >= 15, (lost, delay_frames, len(vad))  # half a second left to look at
    assert np.all(vad[silent_from:] == 0), "and is silent after it went away (delay and hangover aside)"


def test_microphone_whose_server_hangs_is_given_up_then_taken_back(pulse: PulseRig, tmp_path: Path) -> None:
    """The partner talks into a microphone whose audio server hangs for 3 s (SIGSTOP: it neither
    delivers nor answers): it is given up only after ``LOST_SECONDS`` of silence, taken back when
    the server answers, and the report shows the hang."""
    hang_at, hang_for = 1.0, 3.0

    def hang(run: subprocess.Popen) -> None:
        time.sleep(hang_at)
        pulse.room.process.send_signal(signal.SIGSTOP)
        time.sleep(hang_for)
        pulse.room.process.send_signal(signal.SIGCONT)

    report, _ = _partner_on_the_mic(pulse, tmp_path, _talk_through_the_run(), hang)
    partner, events = report["live"]["partner"], report["live"]["events"]
    said = [e for e in events if e["event"].startswith("partner input")]
    assert len(said) == 2 and "back" in said[1]["event"], events
    assert f"nothing for {LOST_SECONDS:g} s" in said[0]["event"], events
    assert partner["lost"] is None and partner["losses"] == 1, partner
    # Given up LOST_SECONDS into the hang, not sooner: back (as the server answers) the rest after.
    assert said[1]["time"] - said[0]["time"] <= hang_for - LOST_SECONDS + 0.5, events
    assert partner["longest_callback_gap_ms"] >= 1000 * (hang_for - 0.5), partner
    assert report["frames"] == pytest.approx(7 * 30, abs=10), "the run went on to the end of the self voice"


def test_a_stopped_run_keeps_its_microphone_and_speaker(pulse: PulseRig, tmp_path: Path) -> None:
    """The run itself is stopped for a second (SIGSTOP, as a process starved of CPU is) while the
    microphone and the speaker go on: no callbacks came, but the silence was the run's, not the
    devices', so neither is given up (a loaded CI machine once had the microphone lost at a run's
    very end; a stop of a second had the speaker given up for the rest of the run)."""

    def stop_for_a_second(run: subprocess.Popen) -> None:
        time.sleep(2.0)
        run.send_signal(signal.SIGSTOP)
        time.sleep(1.0)
        run.send_signal(signal.SIGCONT)

    report, out = _partner_on_the_mic(pulse, tmp_path, _talk_through_the_run(), stop_for_a_second)
    live = report["live"]
    partner = live["partner"]
    assert partner["lost"] is None and partner["losses"] == 0, live["events"]
    assert live["playback"]["stopped"] is None, live["events"]  # nor its speaker
    assert live["self_voice"]["unheard_ms"] == 0, live["self_voice"]
    vad = load_clip(out / "motion.npz").vad[:, 1]
    assert vad[-60:].max() > 0.5, "the partner is heard after the stop, to the end"


def test_speaker_whose_server_stops_answering(pulse, tmp_path: Path) -> None:
    """The speaker's audio server freezes mid-run (SIGSTOP: it neither plays nor answers, as a hung
    server does): the run gives the speaker up once it took under a quarter of the last 4 s, goes on
    by the clock with the mouth still following the voice, and ends by itself (it used to wait for
    the speaker for ever)."""
    words = speak(
        "So the head turns toward whoever is talking, the eyes follow, and the mouth keeps moving with "
        "every word it says, even when nobody is there to hear the voice at all, and it goes on talking "
        "about the weather and the long walk home.",
        rate=150,
    )
    self_wav = tmp_path / "self_talks.wav"
    sf.write(self_wav, np.pad(words, (0, max(0, 10 * 16000 - len(words))))[: 10 * 16000], 16000)  # speech to the end
    out = tmp_path / "out"
    run = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "live", "--self", str(self_wav), "--partner", "none",
         "--play", SPEAKER, "--backend", "record", "--out", str(out)],
        env={**os.environ, **pulse.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert run.stderr is not None and "live at 30 fps" in run.stderr.readline()
        time.sleep(1.5)
        pulse.desk.process.send_signal(signal.SIGSTOP)
        stdout, stderr = run.communicate(timeout=60)
    finally:
        pulse.desk.process.send_signal(signal.SIGCONT)
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, stderr
    report = json.loads((out / "run_report.json").read_text())
    live = report["live"]
    assert "stopped taking samples" in live["playback"]["stopped"], live["playback"]
    given_up = [e for e in live["events"] if "stopped taking samples" in e["event"]]
    assert len(given_up) == 1 and "goes on unheard" in given_up[0]["event"], live["events"]
    assert report["frames"] == pytest.approx(10 * 30, abs=10), "the run went on to the end of the self voice"
    assert live["self_voice"]["unheard_ms"] >= 3000.0, live["self_voice"]
    jaw = load_clip(out / "motion.npz").face[:, JAW]
    after = int((given_up[0]["time"] + 0.5) * 30)
    speaking = np.flatnonzero(level_db(words, 16000) > -35) * HOP_SECONDS * 30  # frames the voice is loud
    assert np.count_nonzero(speaking > after) >= 30, "the voice goes on well after the speaker is given up"
    assert np.count_nonzero(jaw[after:] > 0.1) >= 15, "the mouth still follows the unheard voice"


def test_ctrl_c_ends_a_run_that_listens_forever(pulse, tmp_path: Path) -> None:
    """A microphone never ends, so Ctrl-C does: every backend closes and the report is written."""
    out = tmp_path / "out"
    run = subprocess.Popen(
        [sys.executable, "-m", "convodrive.cli.main", "live", "--partner", MIC, "--self", "none",
         "--backend", "record", "--out", str(out)],
        env={**os.environ, **pulse.env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert run.stderr is not None and "live at 30 fps" in run.stderr.readline()
        time.sleep(2.0)
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=30)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 130, stderr
    report = json.loads((out / "run_report.json").read_text())
    assert report["interrupted"] and report["live"]["clock"] == "monotonic"
    assert report["frames"] >= 30 and (out / "motion.npz").exists()
