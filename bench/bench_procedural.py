"""Benchmark of the procedural generator: declared and measured look-ahead, real-time factor.

Runs on one core (thread pools limited to one thread, the process pinned to one CPU where the OS
allows) on the bundled dialogue (samples/dialogue.wav), or on a synthesised one if it is missing.
Real-time factors are audio duration over wall time, best and median of ``--repeats`` runs (the
machine may be shared: the best run is the one least disturbed), and over CPU time (``cpu_best``,
which a loaded machine disturbs less), with the load average at the start. Prints JSON.

``--phone-accuracy`` instead scores the visemes the streaming analysis takes from recognised
phones, per 30 fps frame, against a forced alignment (pocketsphinx's full English model and
dictionary, told the words) of espeak-ng sentences, for the phone decoder as configured and for
the former one (all 42 phones with 128 Gaussians each, phone trigram).

Usage: .venv/bin/python bench/bench_procedural.py [AUDIO] [--repeats N] [--phone-accuracy]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def bundled_or_synthesised() -> Path:
    path = REPO / "samples" / "dialogue.wav"
    if path.exists():
        return path
    from convodrive.audio.synth import PARTNER, SELF, Turn, synthesize_dialogue

    out = Path(tempfile.mkdtemp()) / "dialogue.wav"
    synthesize_dialogue(
        [
            Turn(SELF, "Hi there. Did you get a chance to look at the robot head yesterday?"),
            Turn(PARTNER, "I did. It was moving its eyes really smoothly.", "en-us+f3", 175),
            Turn(SELF, "Great. The jaw follows the voice now, but the lips are still a bit stiff."),
            Turn(PARTNER, "Maybe we can use the visemes from the speech recogniser.", "en-us+f3", 175),
        ],
        out,
    )
    return out


def run_times(fn, repeats: int) -> list[tuple[float, float]]:
    """(wall, CPU) seconds of each run."""
    times = []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    return times


def realtime(duration: float, times: list[tuple[float, float]]) -> dict[str, float]:
    """Wall-time factors, and the best by CPU time: on a loaded machine the wall time also counts
    the time other processes held the core, the CPU time only this one's work."""
    wall = [w for w, _ in times]
    return {
        "best": round(duration / min(wall), 1),
        "median": round(duration / statistics.median(wall), 1),
        "cpu_best": round(duration / min(c for _, c in times), 1),
    }


SENTENCES = (
    "hi there did you get a chance to look at the robot head yesterday",
    "great the jaw follows the voice now but the lips are still a bit stiff",
    "the quick brown fox jumps over the lazy dog",
    "please call stella and ask her to bring these things with her from the store",
    "we should meet again on thursday morning to review the whole plan",
    "that sounds wonderful although i am not sure about the budget",
    "could you show me how the motors move when you speak slowly",
    "the birch canoe slid on the smooth planks",
    "glue the sheet to the dark blue background",
    "it is easy to tell the depth of a well",
    "rice is often served in round bowls",
    "the box was thrown beside the parked truck",
    "a rod is used to catch pink salmon",
    "kick the ball straight and follow through",
    "a pot of tea helps to pass the evening",
    "the salt breeze came across from the sea",
    "press the pants and sew a button on the vest",
    "her purse was full of useless trash",
    "my mother made maple muffins for the picnic",
    "please pass me the paper plates",
)
VOICES = (("en-us", 165, 50), ("en-us+f3", 175, 60), ("en-us+m3", 150, 40), ("en", 190, 50), ("en-gb+f2", 160, 55))


def aligned_speech() -> list:
    """(speech, viseme per 10 ms) for each sentence in two voices, by forced alignment: the full
    English model and dictionary told the words (sentences it cannot align are skipped)."""
    import numpy as np
    from pocketsphinx import Decoder, get_model_path

    from convodrive.audio.synth import speak
    from convodrive.audio.visemes import phone_viseme

    aligner = Decoder(
        hmm=get_model_path("en-us/en-us"), dict=get_model_path("en-us/cmudict-en-us.dict"), loglevel="FATAL"
    )
    data = []
    for i, text in enumerate(SENTENCES):
        for voice in (VOICES[i % 5], VOICES[(i + 2) % 5]):
            x = speak(text, *voice)
            x = np.concatenate(
                [np.zeros(3200, np.float32), 0.6 * x / max(float(np.abs(x).max()), 1e-9), np.zeros(3200, np.float32)]
            )
            x += np.random.default_rng(i).normal(0, 1e-3, len(x)).astype(np.float32)
            pcm = (np.clip(x, -1, 1) * 32767).astype(np.int16).tobytes()
            try:
                aligner.set_align_text(text)
                for second in (False, True):  # words, then the phones within them
                    if second:
                        aligner.set_alignment()
                    aligner.start_utt()
                    aligner.process_raw(pcm, False, True)
                    aligner.end_utt()
            except RuntimeError:
                continue
            ref = np.zeros(len(x) // 160, np.int64)
            for ph in aligner.get_alignment().phones():
                ref[ph.start : ph.start + ph.duration] = phone_viseme(ph.name)
            data.append((x, ref))
    return data


def phone_accuracy() -> dict:
    """Visemes of the streaming analysis per 30 fps frame (where they come from phones) against
    forced alignment, for the decoder as configured and for the former one."""
    import numpy as np
    from pocketsphinx import Decoder, get_model_path

    from convodrive.audio import phones
    from convodrive.audio.analysis import DyadicAnalyzer, FrameBatch
    from convodrive.audio.features import frame_centre
    from convodrive.audio.visemes import VISEME_INDEX

    data = aligned_speech()
    result: dict = {"utterances": len(data), "seconds": round(sum(len(r) for _, r in data) / 100, 1)}

    old = Decoder(
        hmm=get_model_path("en-us/en-us"),
        allphone=get_model_path("en-us/en-us-phone.lm.bin"),
        loglevel="FATAL",
        lw=2.0,
        pip=0.3,
        beam=1e-10,
        pbeam=1e-10,
        ds=2,
        topn=2,
    )

    def former():
        phones._POOL.clear()  # the tracker hands its decoder back to the pool; reuse this one
        old.reinit_feat()
        return old

    current = phones._acquire_decoder
    pp = VISEME_INDEX["PP"]
    for label, acquire in (("current", current), ("former_42_phones_trigram", former)):
        phones._acquire_decoder = acquire
        right = frames = pp_found = pp_true = pp_said = 0
        cpu = 0.0
        for x, ref in data:
            t0 = time.process_time()
            analyzer = DyadicAnalyzer(phones=True)
            silent = np.zeros_like(x)
            parts = [analyzer.push(x, silent), analyzer.finish(int(round(len(x) / 16000 * 30)))]
            cpu += time.process_time() - t0
            batch = FrameBatch.concat([b for b in parts if b is not None])
            said = batch.visemes.argmax(axis=1)[batch.from_phones]
            truth = ref[np.minimum(frame_centre(np.arange(len(batch))) // 160, len(ref) - 1)][batch.from_phones]
            right += int((said == truth).sum())
            frames += len(said)
            pp_found += int(((said == pp) & (truth == pp)).sum())
            pp_true += int((truth == pp).sum())
            pp_said += int((said == pp).sum())
        result[label] = {
            "viseme_frames_right": round(right / frames, 3),
            "PP_recall": round(pp_found / max(pp_true, 1), 3),
            "PP_precision": round(pp_found / max(pp_said, 1), 3),
            "analysis_realtime_factor_cpu": round(result["seconds"] / cpu, 1),
        }
    phones._acquire_decoder = current
    phones._POOL.clear()
    result["current"]["settings"] = dict(
        phones.DECODER_SETTINGS, densities=phones.DENSITIES, phones=" ".join(phones.VISEME_PHONES)
    )
    return result


def measured_latency_ms(gen, audio) -> float:
    """Black-box look-ahead: for each frame, how much audio past the frame's end had been pulled
    from the source when the stream yielded it (10 ms chunks; the final flush is excluded)."""
    from convodrive.audio.source import ANALYSIS_RATE

    chunks = list(audio.chunks(160))
    pulled = [0]

    def source():
        for chunk in chunks:
            pulled[0] += len(chunk)
            yield chunk

    total = sum(len(c) for c in chunks)
    worst = 0.0
    for k, _frame in enumerate(gen.stream(source(), seed=0)):
        if pulled[0] < total:
            worst = max(worst, pulled[0] / ANALYSIS_RATE - (k + 1) / 30.0)
    return 1000.0 * worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("audio", nargs="?", help="dialogue audio (default: samples/dialogue.wav)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--phone-accuracy", action="store_true", help="score the phone decoder's visemes instead")
    args = parser.parse_args()
    pinned = False
    if hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
            pinned = True
        except OSError:
            pass

    if args.phone_accuracy:
        print(json.dumps(phone_accuracy(), indent=2))
        return 0
    from convodrive.audio.phones import pocketsphinx_available
    from convodrive.audio.source import AudioSource
    from convodrive.generators.procedural import ProceduralGenerator

    path = Path(args.audio) if args.audio else bundled_or_synthesised()
    audio = AudioSource(path).read_all()
    result: dict = {
        "audio": str(path.relative_to(REPO) if path.is_relative_to(REPO) else path),
        "duration_s": round(audio.duration, 3),
        "one_core": {"threads": 1, "pinned_to_one_cpu": pinned},
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }
    configs = {"phones": {"phones": True}, "spectral_only": {"phones": False}}
    if not pocketsphinx_available():
        configs.pop("phones")
    for label, options in configs.items():
        gen = ProceduralGenerator(options)
        gen.generate(audio, seed=0)  # warm up: loads the phone model once per process
        offline = run_times(lambda g=gen: g.generate(audio, seed=0), args.repeats)
        streamed = run_times(lambda g=gen: sum(1 for _ in g.stream(audio.chunks(), seed=0)), args.repeats)
        takes = run_times(lambda g=gen: g.generate(audio, seed=0, num_samples=4), max(1, args.repeats // 2))
        result[label] = {
            "options": options,
            "lookahead_frames": gen.lookahead_frames,
            "lookahead_ms": round(1000.0 * gen.lookahead_frames / 30.0, 1),
            "measured_max_latency_ms": round(measured_latency_ms(gen, audio), 1),
            "generate_realtime_factor": realtime(audio.duration, offline),
            "stream_100ms_chunks_realtime_factor": realtime(audio.duration, streamed),
            "generate_4_takes_realtime_factor": realtime(audio.duration, takes),
        }
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
