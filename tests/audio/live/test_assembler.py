"""The live assembler (``LiveAudio``) fed a scripted partner: 5 ms blocks captured on a simulated
monotonic clock and handed over some milliseconds later, as PulseAudio does; the assembler is the
real one, polled as the generator's thread polls it."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.audio.features import frame_edge
from convodrive.audio.live.assembler import LiveAudio
from convodrive.audio.live.capture import Captured, NoPartner, PartnerInput
from convodrive.audio.live.timeline import Timeline
from convodrive.audio.source import ANALYSIS_RATE

BLOCK = 80  # 5 ms
DELAY, GRACE, SELF_LEAD = 0.145, 0.010, 0.148  # what a live run with `procedural` starts with
SECONDS = 12.0
T0 = 1000.0  # the monotonic time the run's clock reads 0


class FakeClock:
    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> float:
        return self.now


class ScriptedPartner(PartnerInput):
    """Block i holds samples numbered from 1 (sample m is the value m + 1, so 0 is silence),
    captured from ``T0 + i * 5 ms`` and handed over ``age(i)`` seconds after that, in order."""

    def __init__(
        self, clock: FakeClock, age: list[float], lost_at: float | None = None, back_at: float | None = None
    ) -> None:
        self.clock = clock
        self.lost_at, self.back_at = lost_at, back_at
        arrival = T0 + np.arange(len(age)) * BLOCK / ANALYSIS_RATE + np.asarray(age)
        self.arrival = np.maximum.accumulate(arrival)  # a held block holds back those after it
        self.next = 0

    def start(self) -> None:
        pass

    def lost(self) -> str | None:
        gone = self.lost_at is not None and self.clock() >= T0 + self.lost_at
        back = self.back_at is not None and self.clock() >= T0 + self.back_at
        return "nothing for 0.5 s" if gone and not back else None

    def pull(self) -> list[Captured]:
        out = []
        while self.next < len(self.arrival) and self.arrival[self.next] <= self.clock():
            first = self.next * BLOCK
            out.append((np.arange(first + 1, first + BLOCK + 1, dtype=np.float32), T0 + first / ANALYSIS_RATE))
            self.next += 1
        return out


def run(
    age: list[float], lost_at: float | None = None, back_at: float | None = None
) -> tuple[LiveAudio, np.ndarray, dict[int, float]]:
    """Poll the assembler every millisecond of simulated time to ``SECONDS``; the partner's time
    line as the generator got it, and every frame's capture time."""
    clock = FakeClock()
    self_voice = Timeline()
    audio = LiveAudio(
        self_voice,
        lambda: None,
        ScriptedPartner(clock, age, lost_at, back_at),
        lambda mono: mono - T0,
        DELAY,
        GRACE,
        stop_at=SECONDS,
        monotonic=clock,
    )
    partner, captures = [], {}
    while True:
        clock.now += 0.001
        self_voice.fill_to(int((clock.now - T0 + SELF_LEAD) * ANALYSIS_RATE))  # queued ahead of the speaker
        chunk = audio.poll()
        captures.update(audio.frame_capture)
        if chunk is not None:
            assert chunk.start == sum(len(p) for p in partner)
            partner.append(chunk.other_voice)
            if chunk.final:
                break
    return audio, np.concatenate(partner), captures


def assert_in_place(line: np.ndarray, delay: float, since: float = 0.0) -> None:
    """Every captured sample sits exactly ``delay`` after its capture (from ``since`` seconds on)."""
    position = np.flatnonzero(line)
    position = position[position >= since * ANALYSIS_RATE]
    assert len(position) > 0.5 * (len(line) - since * ANALYSIS_RATE)
    captured = line[position].astype(np.int64) - 1
    assert np.array_equal(position - captured, np.full(len(position), round(delay * ANALYSIS_RATE)))


def test_late_blocks_are_filled_and_counted_without_raising_the_delay() -> None:
    """Blocks come 6 ms after capture, but every 80th is held 30 ms (with the ones behind it):
    the delay stays, the held spans become silence, their audio is dropped when it comes, and
    the report counts both. The old assembler raised the delay by 25 ms for good."""
    blocks = int(SECONDS * ANALYSIS_RATE / BLOCK) + 40
    age = [0.030 if i % 80 == 20 else 0.006 for i in range(blocks)]
    audio, line, captures = run(age)

    assert audio.partner_delay == pytest.approx(DELAY)
    assert audio.delay_changes == 0 and audio.resyncs == 0
    # Each hold (one every 400 ms) makes the held block and those stuck behind it late.
    holds = SECONDS / 0.4
    assert holds - 2 <= audio.late_blocks <= 4 * holds
    assert audio.late_samples > 0
    assert audio.late_dropped == audio.late_samples  # what was filled is what came too late
    report = audio.report()
    assert report["late_blocks"] == audio.late_blocks
    assert report["late_ms"] == pytest.approx(1000.0 * audio.late_samples / ANALYSIS_RATE, abs=0.1)
    # About 15 ms of each hold (30 ms minus the grace, minus the block that was in flight).
    assert 10.0 * holds <= report["late_ms"] <= 25.0 * holds

    # The rest of the partner is where it belongs: capture + delay, to the sample, and so is
    # every frame's capture time (what the capture-to-servo latency is measured from).
    assert_in_place(line, DELAY)
    silent = np.count_nonzero(line == 0) - round(DELAY * ANALYSIS_RATE)
    assert silent == audio.late_samples
    for k, captured in captures.items():
        if line[frame_edge(k)]:
            assert captured + DELAY == pytest.approx(T0 + frame_edge(k) / ANALYSIS_RATE, abs=1e-6)


def test_a_device_that_is_always_late_moves_the_delay_once() -> None:
    """Every block 23 ms after capture: that is how this device works, not a late block here
    and there, so the delay rises to cover it (a resync) and no audio is lost from then on."""
    blocks = int(SECONDS * ANALYSIS_RATE / BLOCK) + 40
    audio, line, _ = run([0.023] * blocks)

    assert audio.delay_changes == 1
    assert audio.grace == pytest.approx(0.025)
    assert audio.partner_delay == pytest.approx(DELAY + 0.015)
    assert_in_place(line, DELAY + 0.015, since=6.0)
    assert not np.any(line[int(6.0 * ANALYSIS_RATE) :] == 0)  # nothing late once it moved


def test_a_lost_microphone_is_silence_not_late_blocks() -> None:
    """Once the input is reported lost (a stall of half a second), what it still sends is not
    placed, nor counted as late: the partner is silent from there on, and the report says why."""
    blocks = int(SECONDS * ANALYSIS_RATE / BLOCK) + 40
    age = [0.006] * blocks
    age[1000] = 0.6  # at 5 s the device holds everything for 600 ms ...
    audio, line, _ = run(age, lost_at=5.5)  # ... and is declared lost, then delivers again

    assert audio.report()["lost"] == "nothing for 0.5 s"
    assert audio.delay_changes == 0 and audio.resyncs == 0
    assert audio.late_blocks == 0 and audio.late_dropped == 0
    assert audio.late_samples == pytest.approx(0.5 * ANALYSIS_RATE, abs=0.01 * ANALYSIS_RATE)
    assert_in_place(line[: int(5.0 * ANALYSIS_RATE)], DELAY)
    assert not np.any(line[int((5.5 + DELAY) * ANALYSIS_RATE) :])


def test_a_microphone_that_comes_back_is_heard_again_in_place() -> None:
    """A stall of 600 ms gets the input declared lost; once it delivers again it is taken back:
    its audio is placed exactly at capture + delay again, with one resync over the silence, and
    the report counts the loss and says it is over."""
    blocks = int(SECONDS * ANALYSIS_RATE / BLOCK) + 40
    age = [0.006] * blocks
    age[1000] = 0.6
    audio, line, _ = run(age, lost_at=5.5, back_at=5.62)

    report = audio.report()
    assert report["lost"] is None and report["losses"] == 1
    assert [e["event"].split(":")[0] for e in report["events"]] == ["partner input lost", "partner input back"]
    assert audio.delay_changes == 0 and audio.resyncs == 1
    assert_in_place(line[: int(5.0 * ANALYSIS_RATE)], DELAY)
    assert_in_place(line, DELAY, since=5.7 + DELAY)  # heard again, to the sample
    assert not np.any(line[int((5.5 + DELAY) * ANALYSIS_RATE) : int((5.6 + DELAY) * ANALYSIS_RATE)])


def test_a_voice_that_ends_where_the_generator_already_is_still_ends_the_run() -> None:
    """The generator took the self voice up to its last sample before the feeder knew it had
    ended (a voice paced by the clock is read just as fast as it is taken): the next poll is a
    final, empty chunk, so the generator finishes. It used to wait for audio for ever."""
    self_voice, ended = Timeline(), []
    audio = LiveAudio(
        self_voice, lambda: ended[0] if ended else None, NoPartner(), lambda mono: mono - T0, DELAY, GRACE
    )
    self_voice.append(np.ones(16000, np.float32))
    chunk = audio.poll()
    assert chunk is not None and chunk.start == 0 and len(chunk) == 16000 and not chunk.final
    assert audio.poll() is None  # nothing new, and no end yet
    ended.append(16000)
    chunk = audio.poll()
    assert chunk is not None and chunk.final and chunk.start == 16000 and len(chunk) == 0


def test_the_final_chunk_closes_the_partner_before_the_run_winds_down() -> None:
    """Nothing is pulled after the final chunk, so the assembler closes the partner as it hands it
    over: a microphone left open while the backends ease out overran its ring (a report counted
    296 overruns that were only the wind-down's)."""

    class Closing(NoPartner):
        closed_at: int | None = None

        def close(self) -> None:
            self.closed_at = len(taken)

    self_voice, partner, taken = Timeline(), Closing(), []
    audio = LiveAudio(self_voice, lambda: 32000, partner, lambda mono: mono - T0, DELAY, GRACE)
    self_voice.append(np.ones(16000, np.float32))
    for chunk in audio.chunks():
        assert partner.closed_at is None or chunk.final, "closed only with the final chunk"
        if partner.closed_at is None and not chunk.final:
            self_voice.append(np.ones(16000, np.float32))  # the rest of the voice comes
        taken.append(chunk)
    assert taken[-1].final and partner.closed_at == len(taken) - 1
    assert sum(len(c) for c in taken) == 32000
