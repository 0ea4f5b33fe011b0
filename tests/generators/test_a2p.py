"""The a2p generator on a model folder of the tiny preset (fresh weights: these are contracts of
the runtime, which hold whatever the weights): streaming equals offline; K takes in one batch
equal K single takes; each window continues from its context; the guide carries across windows
and streams never share it; live mode keeps its look-ahead; each guidance scale reaches its own channels (the head, the
gaze, the lids), the students' by a pass a scale; options and mistakes are one line;
the shipped weights drive a run that loads no torch. (Constant memory: test_learned_memory.py.)"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from convodrive.generators.base import take_seed
from convodrive.motion import representation as rep
from convodrive.plumbing.errors import InputFileError, UserError
from tests.conftest import REPO, require, run_cli
from tests.corpora import dyadic_audio

pytestmark = [require("torch"), require("onnxruntime"), pytest.mark.timeout(900)]
"""The first test also pays for the session's model folder: twelve graphs exported, each checked for parity."""

from convodrive.generators.a2p.generator import BODY, FACE, GUIDE_TEMPERATURE, A2PGenerator  # noqa: E402
from convodrive.generators.a2p.guidance import (  # noqa: E402
    GAZE,
    GUIDANCE_EYES,
    GUIDANCE_FACE,
    HEAD,
    LIDS,
    STUDENT_GUIDANCE_LIDS,
)


@pytest.fixture
def model(a2p_model: Path) -> Path:
    """The session's tiny a2p folder (tests/generators/conftest.py)."""
    return a2p_model


def test_stream_equals_generate_and_takes_batch(model: Path) -> None:
    audio = dyadic_audio(5.3)
    gen = A2PGenerator({"model": str(model)})
    assert gen.plan.window == 60 and gen.plan.context == 30
    single = gen.generate(audio, seed=5)[0]
    for chunk in (160, 2345):  # however the audio comes, the same motion, to the bit
        frames = list(gen.stream(audio.chunks(chunk), seed=5))
        np.testing.assert_array_equal(np.stack([f.pose for f in frames]), single.pose)
        np.testing.assert_array_equal(np.stack([f.face for f in frames]), single.face)
    offline = gen.generate(audio, seed=5, num_samples=3)
    assert [c.num_frames for c in offline] == [159] * 3
    # in a batch of three, a take is the one made alone up to the rounding of batched kernels
    np.testing.assert_allclose(offline[0].pose, single.pose, atol=1e-4)
    alone = gen.generate(audio, seed=take_seed(5, 1))[0]
    np.testing.assert_allclose(alone.pose, offline[1].pose, atol=1e-4)
    np.testing.assert_allclose(alone.face, offline[1].face, atol=1e-4)
    assert np.abs(offline[0].pose - offline[1].pose).max() > 1e-3  # takes differ


def test_each_window_continues_from_its_context_and_the_guide_carries_on(model: Path) -> None:
    # blend 0: the stream is exactly what the windows return (the base's easing is tested apart)
    gen = A2PGenerator({"model": str(model), "sampler": "ddim", "steps": 3, "blend": 0})
    contexts: list[np.ndarray | None] = []
    outputs: list[np.ndarray] = []
    seconds: list[int] = []
    run = gen.run_window

    def spy(audio, context, rngs, state=None):  # type: ignore[no-untyped-def]
        out = run(audio, context, rngs, state=state)
        contexts.append(None if context is None else context.copy())
        outputs.append(out.copy())
        seconds.append(state.guide.next_second)
        if context is not None:  # the known frames are kept, face and body
            for part in (FACE, BODY):
                np.testing.assert_allclose(out[:, : context.shape[1], part], context[..., part], atol=1e-6)
        return out

    gen.run_window = spy  # type: ignore[method-assign]
    clip = gen.generate(dyadic_audio(5.3))[0]
    assert len(outputs) == gen.plan.windows_for(159) == 6 and contexts[0] is None
    for i in range(1, len(outputs)):
        np.testing.assert_array_equal(contexts[i], outputs[i - 1][:, 30:60])  # the previous window's last 30
    assert seconds == sorted(seconds) and seconds[-1] >= 5  # guide poses sampled second after second
    start = gen.plan.start(len(outputs) - 1)
    last = rep.decode(gen.stats.denormalise(outputs[-1][0, 30 : 159 - start]))
    np.testing.assert_allclose(clip.pose[start + 30 : 159], last.pose, atol=1e-5)


def test_streams_do_not_share_state(model: Path) -> None:
    """Two streams of one generator interleaved give what each gives alone."""
    gen = A2PGenerator({"model": str(model)})
    a, b = dyadic_audio(4.0, seed=1), dyadic_audio(4.0, seed=2)
    alone_a = np.stack([f.pose for f in gen.stream(a.chunks(1600), seed=3)])
    alone_b = np.stack([f.pose for f in gen.stream(b.chunks(1600), seed=4)])
    both_a, both_b = [], []
    for fa, fb in zip(gen.stream(a.chunks(1600), seed=3), gen.stream(b.chunks(1600), seed=4)):
        both_a.append(fa.pose)
        both_b.append(fb.pose)
    np.testing.assert_array_equal(np.stack(both_a), alone_a)
    np.testing.assert_array_equal(np.stack(both_b), alone_b)


def test_live_mode_declares_its_lookahead_and_keeps_it(model: Path) -> None:
    gen = A2PGenerator({"model": str(model), "mode": "live"})
    assert gen.plan.window == 60 and gen.plan.hop == 12
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


def test_guidance_and_sampler_options_change_the_motion(model: Path) -> None:
    audio = dyadic_audio(2.5)
    base = A2PGenerator({"model": str(model), "sampler": "ddim", "steps": 2}).generate(audio)[0]
    guided = A2PGenerator({"model": str(model), "sampler": "ddim", "steps": 2, "guidance_body": 4.0}).generate(audio)[0]
    assert np.abs(base.pose - guided.pose).max() > 1e-5
    np.testing.assert_allclose(base.face, guided.face, atol=1e-6)  # the face's guidance is its own
    # Guidance on the audio alone (the default) or on the guide poses too: two different passes.
    every = {"model": str(model), "sampler": "ddim", "steps": 2, "guidance_body_on": "all"}
    on_all = A2PGenerator(every).generate(audio)[0]
    assert np.abs(base.pose - on_all.pose).max() > 1e-5
    unguided = A2PGenerator({**every, "guidance_body": 1.0}).generate(audio)[0]
    np.testing.assert_array_equal(
        unguided.pose,
        A2PGenerator({**every, "guidance_body": 1.0, "guidance_body_on": "audio"}).generate(audio)[0].pose,
    )  # at scale 1 there is no unconditional pass to differ
    distilled = A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 1}).generate(audio)[0]
    assert np.abs(base.pose - distilled.pose).max() > 1e-5
    # DPM-Solver++ runs the same teachers on other steps: another path, deterministic.
    dpm = {"model": str(model), "sampler": "dpm", "steps": 2}
    dpm_take = A2PGenerator(dpm).generate(audio)[0]
    assert np.abs(base.pose - dpm_take.pose).max() > 1e-5
    np.testing.assert_array_equal(dpm_take.face, A2PGenerator(dpm).generate(audio)[0].face)
    # The students' face may take its own number of steps; by default as many as the body.
    default = A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 2})
    assert default.report()["face_steps"] == 2 and default.report()["steps"] == 2
    two = A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 2, "face_steps": 2}).generate(audio)[0]
    np.testing.assert_array_equal(default.generate(audio)[0].face, two.face)
    one_face = A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 2, "face_steps": 1})
    assert np.abs(one_face.generate(audio)[0].face - two.face).max() > 1e-5
    assert one_face.report()["face_steps"] == 1


def test_the_guide_temperature_moves_the_body_and_leaves_the_face(model: Path) -> None:
    """The guide poses' temperature reaches the body through its guide poses only: the face,
    sampled before the guide, is the same to the bit (the guide draws one uniform a code whatever
    the temperature), and the default is ``GUIDE_TEMPERATURE``."""
    audio = dyadic_audio(2.5)
    options = {"model": str(model), "steps": 2, "face_steps": 2}
    default = A2PGenerator(options)
    assert default.report()["guide_temperature"] == GUIDE_TEMPERATURE
    warm, cold = (
        A2PGenerator({**options, "guide_temperature": t}).generate(audio, seed=3)[0] for t in (GUIDE_TEMPERATURE, 0.2)
    )
    np.testing.assert_array_equal(default.generate(audio, seed=3)[0].pose, warm.pose)
    assert np.abs(warm.pose - cold.pose).max() > 1e-4
    np.testing.assert_array_equal(warm.face, cold.face)


def test_the_teachers_guide_the_head_harder_than_the_rest_of_the_body(model: Path) -> None:
    """The head and neck take their own guidance scale (4 by default, the rest of the body 2): in
    one DDIM step only their channels change with it (in the first window: the next continues from
    all of its frames). A body scale the user sets holds for the head too unless the head's is set
    as well."""
    audio = dyadic_audio(2.5)
    one_step = {"model": str(model), "sampler": "ddim", "steps": 1}
    plan = A2PGenerator(one_step).report()
    first = plan["window"] - plan["context"]

    def body(options: dict) -> np.ndarray:
        return rep.encode_clip(A2PGenerator({**one_step, **options}).generate(audio)[0])[:, BODY]

    default = body({})
    np.testing.assert_array_equal(default, body({"guidance_body": 2.0, "guidance_head": 4.0}))
    uniform = body({"guidance_body": 2.0})
    np.testing.assert_array_equal(uniform, body({"guidance_body": 2.0, "guidance_head": 2.0}))
    head = slice(HEAD.start - BODY.start, HEAD.stop - BODY.start)
    assert np.abs(default[:, head] - uniform[:, head]).max() > 1e-4
    rest = np.ones(default.shape[1], bool)
    rest[head] = False
    np.testing.assert_allclose(default[:first, rest], uniform[:first, rest], atol=1e-5)
    assert np.abs(default[first:, rest] - uniform[first:, rest]).max() > 1e-4


def test_the_teachers_guide_the_eyes_by_their_own_scale(model: Path) -> None:
    """The gaze and the lids take their own guidance scale (``GUIDANCE_EYES`` by default), the rest
    of the face the face's: in one DDIM step only the eyes' channels change with it (in the first
    window), and each group only with its own."""
    audio = dyadic_audio(2.5)
    one_step = {"model": str(model), "sampler": "ddim", "face_steps": 1, "steps": 1}
    plan = A2PGenerator(one_step).report()["guidance"]
    assert plan["gaze"] == plan["lids"] == GUIDANCE_EYES != GUIDANCE_FACE == plan["face"]
    first = A2PGenerator(one_step).report()["window"] - A2PGenerator(one_step).report()["context"]

    def face(options: dict) -> np.ndarray:
        return rep.encode_clip(A2PGenerator({**one_step, **options}).generate(audio)[0])[:first, FACE]

    default = face({})
    np.testing.assert_array_equal(default, face({"guidance_gaze": GUIDANCE_EYES, "guidance_lids": GUIDANCE_EYES}))
    uniform = face({"guidance_gaze": GUIDANCE_FACE, "guidance_lids": GUIDANCE_FACE})
    gaze_only = face({"guidance_lids": GUIDANCE_FACE})
    gaze, lids = GAZE - FACE.start, LIDS - FACE.start
    assert np.abs(default[:, gaze] - uniform[:, gaze]).max() > 1e-4
    assert np.abs(default[:, lids] - uniform[:, lids]).max() > 1e-4
    rest = np.ones(default.shape[1], bool)
    rest[np.concatenate([gaze, lids])] = False
    np.testing.assert_allclose(default[:, rest], uniform[:, rest], atol=1e-5)
    np.testing.assert_allclose(gaze_only[:, gaze], default[:, gaze], atol=1e-5)
    np.testing.assert_allclose(gaze_only[:, lids], uniform[:, lids], atol=1e-5)


def test_ddim_is_the_default_and_its_face_takes_more_steps_than_its_body(model: Path) -> None:
    """The face improves with every DDIM step up to 50 where the body stops at 10 (see
    ``DDIM_FACE_STEPS``); live mode keeps the face at 20 for its latency."""
    file = A2PGenerator({"model": str(model)}).report()
    assert (file["sampler"], file["steps"], file["face_steps"]) == ("ddim", 10, 50)
    assert file["guidance"] == {"face": 1.5, "gaze": GUIDANCE_EYES, "lids": GUIDANCE_EYES, "body": 2.0, "head": 4.0}
    assert file["body_guidance_on"] == "audio"
    students = A2PGenerator({"model": str(model), "sampler": "distilled"}).report()
    assert students["guidance"] == {"face": 1.5, "gaze": 1.5, "lids": 1.5, "body": 1.0, "head": 1.0}  # consistency
    assert students["body_guidance_on"] == "all"
    assert A2PGenerator({"model": str(model), "mode": "live"}).report()["face_steps"] == 20
    dpm = A2PGenerator({"model": str(model), "sampler": "dpm"}).report()
    assert (dpm["steps"], dpm["face_steps"], dpm["guidance"]["body"], dpm["guidance"]["head"]) == (4, 8, 2.0, 4.0)
    assert A2PGenerator({"model": str(model), "mode": "live", "face_steps": 7}).report()["face_steps"] == 7


def test_stochastic_ddim_is_another_draw_for_the_same_seed(model: Path) -> None:
    audio = dyadic_audio(2.5)
    options = {"model": str(model), "steps": 3, "face_steps": 3}
    deterministic = A2PGenerator(options).generate(audio, seed=4)[0]
    stochastic = A2PGenerator({**options, "eta": 1.0}).generate(audio, seed=4)[0]
    assert np.abs(deterministic.pose - stochastic.pose).max() > 1e-5
    assert np.abs(deterministic.face - stochastic.face).max() > 1e-5
    again = A2PGenerator({**options, "eta": 1.0}).generate(audio, seed=4)[0]
    np.testing.assert_array_equal(stochastic.pose, again.pose)  # the seed still decides


def test_a_model_may_name_its_own_face_student_steps(model: Path, tmp_path: Path) -> None:
    """The shipped students' face wants 1 step (the jaw shuts through silences), the body 4: the
    recipe writes the face's into model.json, the generator takes it unless told otherwise."""
    own = tmp_path / "own"
    shutil.copytree(model, own)
    meta = json.loads((own / "model.json").read_text())
    meta["architecture"]["face_student_steps"] = 1
    (own / "model.json").write_text(json.dumps(meta))
    students = {"model": str(own), "sampler": "distilled"}
    assert A2PGenerator(students).report()["face_steps"] == 1
    assert A2PGenerator({**students, "steps": 2}).report()["face_steps"] == 1
    assert A2PGenerator({**students, "face_steps": 3}).report()["face_steps"] == 3
    assert A2PGenerator({"model": str(own), "steps": 5}).report()["face_steps"] == 50  # the teachers' own (DDIM)
    audio = dyadic_audio(2.5)
    np.testing.assert_array_equal(
        A2PGenerator({**students, "steps": 2}).generate(audio)[0].face,
        A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 2, "face_steps": 1})
        .generate(audio)[0]
        .face,
    )


def test_guidance_distilled_students_are_sampled_as_the_teachers_are(model: Path, tmp_path: Path) -> None:
    """Students that learned by guidance distillation (model.json's ``distillation``) run by
    DPM-Solver++ on the teachers' steps, guided on the audio as the teachers are by default; in one
    step that is the student's x0 at the last step, the consistency sampler's first call too."""
    own = tmp_path / "guidance"
    shutil.copytree(model, own)
    meta = json.loads((own / "model.json").read_text())
    meta["architecture"].update(distillation="guidance", face_student_steps=3)
    (own / "model.json").write_text(json.dumps(meta))
    students = {"model": str(own), "sampler": "distilled"}
    report = A2PGenerator(students).report()
    assert (report["steps"], report["face_steps"], report["guidance"]["body"]) == (4, 3, 3.0)
    assert report["body_guidance_on"] == "audio"
    audio = dyadic_audio(2.5)
    one = {"steps": 1, "face_steps": 1, "guidance_body": 2.0}
    guidance = A2PGenerator({**students, **one}).generate(audio)[0]
    consistency = A2PGenerator({"model": str(model), "sampler": "distilled", **one}).generate(audio)[0]
    body = [
        rep.encode_clip(clip)[:, BODY] for clip in (guidance, consistency)
    ]  # the pose's jaw and eyes are the face's
    np.testing.assert_allclose(body[0], body[1], atol=1e-5)
    assert np.abs(guidance.face - consistency.face).max() > 1e-5  # the face's one step is in log-SNR
    two = A2PGenerator({**students, "steps": 2, "face_steps": 2}).generate(audio)[0]
    again = A2PGenerator({**students, "steps": 2, "face_steps": 2}).generate(audio, seed=0)[0]
    np.testing.assert_array_equal(two.pose, again.pose)
    assert np.abs(two.pose - guidance.pose).max() > 1e-5
    # The consistency grid's limit does not bind them: the teachers' schedule does.
    assert A2PGenerator({**students, "steps": 20}).report()["steps"] == 20


def test_guidance_distilled_students_take_the_lids_scale_by_a_second_pass(model: Path, tmp_path: Path) -> None:
    """Guidance-distilled students learned one face scale, an input: the lids' own scale
    (``STUDENT_GUIDANCE_LIDS`` by default; their gaze keeps the face's) is a second pass of the face
    in the same call. In one face step (the first window) the lids are what the student gives at
    the lids' scale everywhere, the rest of the face what it gives at the face's. Consistency
    students learned no scale: the lids keep the face's."""
    own = _students_that_hear_their_scale(model, tmp_path / "guidance")
    one = {"model": str(own), "sampler": "distilled", "steps": 1, "face_steps": 1}
    plan = A2PGenerator(one).report()
    assert plan["guidance"]["lids"] == STUDENT_GUIDANCE_LIDS and plan["guidance"]["gaze"] == plan["guidance"]["face"]
    first = plan["window"] - plan["context"]
    audio = dyadic_audio(2.5)

    def face(face: float, lids: float) -> np.ndarray:
        options = {**one, "guidance_face": face, "guidance_gaze": face, "guidance_lids": lids}
        return rep.encode_clip(A2PGenerator(options).generate(audio)[0])[:first, FACE]

    both, at_face, at_lids = face(1.5, 3.0), face(1.5, 1.5), face(3.0, 3.0)
    lids = LIDS - FACE.start
    rest = np.ones(both.shape[1], bool)
    rest[lids] = False
    np.testing.assert_allclose(both[:, lids], at_lids[:, lids], atol=1e-5)
    np.testing.assert_allclose(both[:, rest], at_face[:, rest], atol=1e-5)
    assert np.abs(at_lids[:, lids] - at_face[:, lids]).max() > 1e-4
    consistency = A2PGenerator({"model": str(model), "sampler": "distilled", "guidance_lids": 3.0}).report()
    assert consistency["guidance"]["lids"] == consistency["guidance"]["face"]


def _students_that_hear_their_scale(model: Path, folder: Path) -> Path:
    """A copy of ``model`` whose face student learned by guidance distillation and hears its scale:
    a fresh student's scale embedding starts at zero, so it is drawn here (and the file's hash
    recomputed)."""
    import onnx
    from onnx import numpy_helper

    shutil.copytree(model, folder)
    meta = json.loads((folder / "model.json").read_text())
    meta["architecture"].update(distillation="guidance")
    graph = folder / meta["graphs"]["face_student_step"]["file"]
    proto = onnx.load(str(graph))
    (weight,) = [w for w in proto.graph.initializer if w.name.endswith("guidance.weight")]
    drawn = np.random.default_rng(0).normal(0.0, 0.5, numpy_helper.to_array(weight).shape).astype(np.float32)
    weight.CopyFrom(numpy_helper.from_array(drawn, weight.name))
    onnx.save(proto, str(graph))
    meta["files"][graph.name] = hashlib.sha256(graph.read_bytes()).hexdigest()
    (folder / "model.json").write_text(json.dumps(meta))
    return folder


def test_bad_options_and_folders_are_one_line(model: Path, tmp_path: Path) -> None:
    wav = str(REPO / "samples" / "dialogue.wav")
    out = run_cli("drive", wav, "--generator", "a2p", "-G", f"model={model}", "-G", "speaker=nobody",
                  "--backend", "record", "--out", str(tmp_path / "o"))  # fmt: skip
    assert out.returncode == 2 and "not one the model learned (calm, lively)" in out.stderr, out.stderr
    assert len(out.stderr.splitlines()) == 1
    with pytest.raises(UserError, match="steps must be at most 10 with the distilled sampler"):
        A2PGenerator({"model": str(model), "sampler": "distilled", "steps": 11})  # the tiny grid: 1000 steps / 100
    with pytest.raises(UserError, match="face_steps must be at most 10"):
        A2PGenerator({"model": str(model), "sampler": "distilled", "face_steps": 11})
    with pytest.raises(UserError, match="face_steps 60 is too many for the dpm sampler"):
        A2PGenerator({"model": str(model), "sampler": "dpm", "face_steps": 60})
    with pytest.raises(UserError, match="mode"):
        A2PGenerator({"model": str(model), "mode": "batch"})
    meta = json.loads((model / "model.json").read_text())
    students = [g for g in meta["graphs"] if "student" in g]
    teacher_only = tmp_path / "teacher_only"
    teacher_only.mkdir()
    for item in model.iterdir():
        if item.stem not in students:
            (teacher_only / item.name).write_bytes(item.read_bytes())
    meta["graphs"] = {k: v for k, v in meta["graphs"].items() if k not in students}
    meta["files"] = {k: v for k, v in meta["files"].items() if Path(k).stem not in students}
    (teacher_only / "model.json").write_text(json.dumps(meta))
    with pytest.raises(InputFileError, match="export the distill stage"):
        A2PGenerator({"model": str(teacher_only), "sampler": "distilled"})
    A2PGenerator({"model": str(teacher_only)})  # the teachers alone run DDIM, the default
    A2PGenerator({"model": str(teacher_only), "sampler": "dpm"})  # and DPM-Solver++


PROBE = """
import json, sys
from convodrive.cli.main import main
rc = main(sys.argv[1:])
loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))
print(json.dumps({"rc": rc, "torch": loaded}))
"""


@pytest.mark.skipif(not (A2PGenerator.shipped_model / "model.json").exists(), reason="no shipped a2p weights")
def test_the_shipped_weights_drive_a_run_that_loads_no_torch(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-c", PROBE, "drive", str(REPO / "samples" / "dialogue.wav"), "--generator", "a2p",
         "--backend", "record", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    probe = json.loads(result.stdout.strip().splitlines()[-1])
    assert probe == {"rc": 0, "torch": []}
    assert (tmp_path / "motion.npz").exists()
