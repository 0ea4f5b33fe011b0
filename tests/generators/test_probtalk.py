"""probtalk end to end on a tiny corpus: three stages trained (once per test run,
tests/generators/conftest.py), exported with parity, and driven. The runtime's MaskGIT loop over
the exported graphs samples the codes the torch networks sample; streaming equals offline; K takes
in one batch equal K single takes; windows continue from their context; the partner's voice moves
the predictor; options and mistakes, and the CLI's refusals of stages out of order. (Constant
memory: test_learned_memory.py.)"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from convodrive.audio.source import DyadicAudio
from convodrive.generators.probtalk.generator import ProbTalkGenerator
from convodrive.motion import representation as rep
from convodrive.neural.maskgit import draw_uniforms
from convodrive.neural.maskgit import maskgit_sample as numpy_maskgit_sample
from tests.conftest import REPO, cli_in_process, require, run_cli
from tests.corpora import dyadic_audio

pytestmark = [require("torch"), require("onnxruntime"), pytest.mark.timeout(900)]
"""The first test also pays for the session's three runs and their export, unless another test did."""

TINY = ["--preset", "tiny", "--device", "cpu", "--no-progress"]


@pytest.fixture
def stages(probtalk_stages: dict[str, Path]) -> dict[str, Path]:
    """The session's three tiny probtalk runs and their export (tests/generators/conftest.py)."""
    return probtalk_stages


def test_the_export_holds_every_stage_with_parity(stages: dict[str, Path]) -> None:
    meta = json.loads((stages["model"] / "model.json").read_text())
    assert set(meta["graphs"]) == {"vq_decoder", "predictor_memory", "predictor_step", "refiner"}
    for graph, errors in meta["parity"]["max_abs_err"].items():
        assert len(errors) >= 3 and max(errors.values()) <= 1e-4, graph
    assert meta["features"]["speakers"] == ["calm", "lively"]
    state = json.loads(next((stages["refiner"] / "checkpoints").iterdir()).joinpath("state.json").read_text())
    assert state["init"]["stage"] == "predictor"
    card = (stages["model"] / "MODEL_CARD.md").read_text()
    assert "ProbTalk" in card and "Speakers: calm, lively" in card


def test_later_stages_need_the_earlier_one(stages: dict[str, Path], tiny_corpus: Path, tmp_path: Path) -> None:
    alone = cli_in_process(
        "train", "probtalk", "--stage", "refiner", "--corpus", str(tiny_corpus), *TINY, "--out", str(tmp_path / "r")
    )
    assert alone.returncode == 2 and "--init RUN" in alone.stderr and len(alone.stderr.splitlines()) == 1
    assert not (tmp_path / "r").exists()
    skipped = cli_in_process(
        "train", "probtalk", "--stage", "refiner", "--corpus", str(tiny_corpus), *TINY, "--out", str(tmp_path / "s"),
        "--init", str(stages["vq"]),
    )  # fmt: skip
    assert skipped.returncode == 2 and "holds no predictor network" in skipped.stderr
    other = cli_in_process("train", "probtalk", "--stage", "predictor", "--corpus", str(tiny_corpus), *TINY,
                    "--set", "codes=8", "--out", str(tmp_path / "o"), "--init", str(stages["vq"]))  # fmt: skip
    assert other.returncode == 2 and "holds no vq network of these settings" in other.stderr


def test_runtime_maskgit_samples_the_codes_torch_samples(stages: dict[str, Path], tiny_corpus: Path) -> None:
    from convodrive.models.probtalk_predictor import maskgit_sample
    from convodrive.training.export import restore

    _, _, config, _, net = restore(stages["refiner"])
    gen = ProbTalkGenerator({"model": str(stages["model"])})
    rng = np.random.default_rng(0)
    frames, takes, iterations = 48, 3, 8
    audio = (rng.standard_normal((takes, frames, 2, 80)) * 3 - 8).astype(np.float32)
    known = rng.standard_normal((takes, frames, rep.FEATURE_DIM)).astype(np.float32)
    known_mask = np.zeros((takes, frames, 1), np.float32)
    known_mask[:, :12] = 1
    speaker = np.array([0, 1, 0])
    memory = gen.memory(audio=audio, known=known, known_mask=known_mask, speaker=speaker)
    length = frames // 8 * config.groups
    seeds = [np.random.default_rng([3, k]) for k in range(takes)]
    ours = numpy_maskgit_sample(
        lambda t: gen.step(tokens=t, **memory)["logits"], length, config.codes, iterations, seeds
    )
    with torch.no_grad():
        kv = net.predictor.memory(
            net.audio_norm(torch.from_numpy(audio)), torch.from_numpy(known), torch.from_numpy(known_mask),
            torch.from_numpy(speaker),
        )  # fmt: skip
        uniforms = torch.from_numpy(
            draw_uniforms([np.random.default_rng([3, k]) for k in range(takes)], iterations, length)
        )
        theirs = maskgit_sample(lambda t: net.predictor.logits(t, *kv), takes, length, config, iterations, uniforms)
    assert (ours == theirs.numpy()).mean() >= 0.98


def test_stream_equals_generate_and_takes_batch(stages: dict[str, Path]) -> None:
    audio = dyadic_audio(5.3)
    gen = ProbTalkGenerator({"model": str(stages["model"]), "window": 40, "context": 16})
    assert gen.plan.window == 40 and gen.plan.context == 16
    offline = gen.generate(audio, seed=5, num_samples=3)
    assert [c.num_frames for c in offline] == [audio.num_frames] * 3 == [159] * 3  # seven windows
    for chunk in (160, 2345):
        frames = list(gen.stream(audio.chunks(chunk), seed=5))
        np.testing.assert_array_equal(np.stack([f.pose for f in frames]), offline[0].pose)
        np.testing.assert_array_equal(np.stack([f.face for f in frames]), offline[0].face)
    alone = gen.generate(audio, seed=5 + 7919)[0]  # take 1's seed, run by itself
    np.testing.assert_allclose(alone.pose, offline[1].pose, atol=1e-5)
    assert np.abs(offline[0].pose - offline[1].pose).max() > 1e-3  # takes differ


def test_each_window_continues_from_its_context(stages: dict[str, Path]) -> None:
    # blend 0, smooth 0: the stream is exactly what the windows return (easing and smoothing are tested apart)
    gen = ProbTalkGenerator({"model": str(stages["model"]), "window": 40, "context": 16, "blend": 0, "smooth": 0})
    contexts: list[np.ndarray | None] = []
    outputs: list[np.ndarray] = []
    run = gen.run_window

    def spy(audio, context, rngs):  # type: ignore[no-untyped-def]
        out = run(audio, context, rngs)
        contexts.append(None if context is None else context.copy())
        outputs.append(out.copy())
        if context is not None:
            np.testing.assert_array_equal(out[:, : context.shape[1]], context)  # known frames kept
        return out

    gen.run_window = spy  # type: ignore[method-assign]
    clip = gen.generate(dyadic_audio(5.3))[0]
    assert len(outputs) == 7 == gen.plan.windows_for(159) and contexts[0] is None
    for i in range(1, 7):
        np.testing.assert_array_equal(contexts[i], outputs[i - 1][:, 24:40])  # the previous window's last 16
    last = rep.decode(gen.stats.denormalise(outputs[6][0, 16 : 159 - 128]))  # window 6 starts at frame 128
    np.testing.assert_allclose(clip.pose[144:159], last.pose, atol=1e-5)  # the stream is the windows' output


def test_smoothing_calms_the_body_and_leaves_the_first_window_s_face(stages: dict[str, Path]) -> None:
    audio = dyadic_audio(5.3)
    options = {"model": str(stages["model"]), "window": 40, "context": 16}
    raw = ProbTalkGenerator({**options, "smooth": 0}).generate(audio, seed=3)[0]
    smooth = ProbTalkGenerator({**options, "smooth": 2}).generate(audio, seed=3)[0]
    np.testing.assert_allclose(smooth.face[:24], raw.face[:24], atol=1e-6)  # window 0's new frames: face untouched
    acceleration = lambda clip: np.abs(np.diff(clip.pose, 2, axis=0)).mean()  # noqa: E731
    assert acceleration(smooth) < 0.7 * acceleration(raw), (acceleration(smooth), acceleration(raw))


def test_a_hotter_face_draw_replaces_the_face_and_keeps_the_body(stages: dict[str, Path]) -> None:
    """``face_temperature``: a second draw of the codes, at that temperature, gives the face; the
    first draw (at ``temperature``) still gives the body, so one window's body is unchanged (before
    the refiner, which reads the whole frame: off here)."""
    audio = dyadic_audio(1.2)  # one 40-frame window
    options = {"model": str(stages["model"]), "window": 40, "context": 16, "blend": 0, "smooth": 0, "refine": False}
    one = ProbTalkGenerator({**options, "face_temperature": 0}).generate(audio, seed=4, num_samples=2)
    same = ProbTalkGenerator({**options, "face_temperature": 1.0}).generate(audio, seed=4, num_samples=2)
    hot = ProbTalkGenerator({**options, "face_temperature": 3.0}).generate(audio, seed=4, num_samples=2)
    body, face = rep.GROUPS["body"], rep.GROUPS["face"]  # the pose holds the jaw and eyes: compare features
    for a, b, c in zip(one, same, hot):
        np.testing.assert_array_equal(a.face, b.face)  # equal to temperature: one draw
        first, hotter = rep.encode_clip(a), rep.encode_clip(c)
        np.testing.assert_allclose(hotter[:, body], first[:, body], atol=1e-4)
        assert np.abs(hotter[:, face] - first[:, face]).max() > 1e-3
    alone = ProbTalkGenerator({**options, "face_temperature": 3.0}).generate(audio, seed=4 + 7919)[0]
    np.testing.assert_allclose(alone.face, hot[1].face, atol=1e-5)  # a take's face draw is its own


def test_live_mode_declares_its_lookahead_and_keeps_it(stages: dict[str, Path]) -> None:
    gen = ProbTalkGenerator({"model": str(stages["model"]), "mode": "live"})
    assert gen.plan.window == 48 and gen.plan.context == 36
    assert gen.lookahead_frames / 30 <= 0.5
    audio = dyadic_audio(4.0)
    received = 0

    def chunks():  # type: ignore[no-untyped-def]
        nonlocal received
        for chunk in audio.chunks(400):
            received += len(chunk)
            yield chunk

    for k, _ in enumerate(gen.stream(chunks(), seed=0)):
        if received < len(audio.self_voice):  # before the end, frame k may only need audio to k + look-ahead
            assert received <= (k + gen.lookahead_frames + 1) / 30 * 16000 + 400


def _first_logits(gen: ProbTalkGenerator, audio: DyadicAudio) -> np.ndarray:
    """The predictor's logits at the first MaskGIT step of the first window, where every code is
    still masked: what the model heard moves them continuously, whatever codes a draw then picks."""
    step = gen.step
    seen: list[np.ndarray] = []

    def spy(**feed: np.ndarray) -> dict[str, np.ndarray]:
        out = step(**feed)
        seen.append(out["logits"])
        return out

    gen.step = spy  # type: ignore[assignment]
    try:
        gen.generate(audio)
    finally:
        gen.step = step  # type: ignore[method-assign]
    return seen[0]


def test_dyadic_and_refine_options(stages: dict[str, Path]) -> None:
    audio = dyadic_audio(3.0)
    other = DyadicAudio(audio.self_voice, audio.other_voice[::-1].copy())
    model = str(stages["model"])
    heard = ProbTalkGenerator({"model": model})
    deaf = ProbTalkGenerator({"model": model, "dyadic": False})
    # A tiny model's sampled codes may not change with the partner's voice (a CPU's rounding
    # decides near-ties); the logits they are drawn from must.
    assert np.abs(_first_logits(heard, audio) - _first_logits(heard, other)).max() > 1e-3
    np.testing.assert_array_equal(_first_logits(deaf, audio), _first_logits(deaf, other))
    np.testing.assert_array_equal(deaf.generate(audio)[0].pose, deaf.generate(other)[0].pose)
    coarse = ProbTalkGenerator({"model": model, "refine": False})
    assert heard.refiner is not None and coarse.refiner is None  # on unless switched off
    assert np.abs(heard.generate(audio)[0].pose - coarse.generate(audio)[0].pose).max() > 1e-5


def test_bad_options_and_folders_are_one_line(stages: dict[str, Path], tmp_path: Path) -> None:
    wav = str(REPO / "samples" / "dialogue.wav")
    for option, text in (
        ("speaker=nobody", "not one the model learned (calm, lively)"),
        ("context=200", "context must be below window"),
        ("iterations=0", "iterations"),
        ("mode=batch", "mode"),
    ):
        out = cli_in_process("drive", wav, "--generator", "probtalk", "-G", f"model={stages['model']}", "-G", option,
                             "--backend", "record", "--out", str(tmp_path / "o"))  # fmt: skip
        assert out.returncode == 2 and text in out.stderr and len(out.stderr.splitlines()) == 1, out.stderr
    vq_only = tmp_path / "vq_model"
    assert run_cli("export", str(stages["vq"]), "--out", str(vq_only)).returncode == 0
    out = cli_in_process("drive", wav, "--generator", "probtalk", "-G", f"model={vq_only}", "--backend", "record",
                         "--out", str(tmp_path / "o"))  # fmt: skip
    assert out.returncode == 2 and "'vq' stage export" in out.stderr and len(out.stderr.splitlines()) == 1
