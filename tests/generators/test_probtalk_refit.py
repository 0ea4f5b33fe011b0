"""A refiner retrained for exported probtalk weights whose torch checkpoints are gone: the vq stage
fits a new encoder to the folder's own decoder and codebooks (``vq_decoder_from``, read back from
the ONNX graph with its folded norms), a refiner learns on top, and ``export --onto --graphs``
puts its graph into the folder, keeping every other file to the bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from convodrive.generators.probtalk.generator import ProbTalkGenerator
from convodrive.motion import representation as rep
from convodrive.plumbing.errors import UserError
from convodrive.training.checkpoint import load_checkpoint
from convodrive.training.export import restore
from convodrive.training.loop import TrainRequest, train
from tests.conftest import cli_in_process, require
from tests.corpora import dyadic_audio

pytestmark = [require("torch"), require("onnxruntime"), pytest.mark.timeout(900)]


def _train(
    corpus: Path, stage: str, out: Path, init: Path | None = None, seed: int | None = None, **settings: object
) -> Path:
    request = TrainRequest(
        "probtalk", corpus, preset="tiny", stage=stage, out=out, device="cpu", progress=False, init=init,
        seed=seed, settings=dict(settings),
    )  # fmt: skip
    train(request)
    return out


def _weights(run: Path, prefix: str) -> dict[str, torch.Tensor]:
    ckpt = load_checkpoint(sorted((run / "checkpoints").iterdir())[-1])
    return {k: v for k, v in ckpt.model_weights().items() if k.startswith(prefix)}


def _assert_motion_projection_float(path: Path) -> None:
    """One activation scale over a window of normalised motion flattens the face's small movements:
    in an int8 refiner the product the motion meets first stays float, every other one is int8."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(path)).graph
    weights = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    made = {o: n for n in graph.node for o in n.output}
    floats = [n for n in graph.node if n.op_type == "MatMul" and n.input[1] in weights]
    assert len(floats) == 1 and weights[floats[0].input[1]].dtype == np.float32
    fed = made[floats[0].input[0]]  # the concatenation of the motion and the known mask
    assert fed.op_type == "Concat" and "motion" in fed.input
    assert sum(n.op_type == "MatMulInteger" for n in graph.node) >= 8


def test_an_encoder_fitted_to_a_folder_s_decoder_and_its_refiner_grafted_back(
    probtalk_stages: dict[str, Path], tiny_corpus: Path, tmp_path: Path
) -> None:
    from convodrive.neural.folder import load_model_folder
    from convodrive.training.recipes.probtalk_decoder import decoder_parity

    model = probtalk_stages["model"]
    vq = _train(tiny_corpus, "vq", tmp_path / "vq", vq_decoder_from=str(model))
    first, fitted = _weights(probtalk_stages["vq"], "vq."), _weights(vq, "vq.")
    # The decoder is the folder's (its norms folded: the tensors differ, what it decodes does not);
    # the codebooks are the folder's; the encoder learnt.
    assert torch.equal(fitted["vq.quantizer.codebooks"], first["vq.quantizer.codebooks"])
    net = restore(vq)[4].vq
    assert decoder_parity(load_model_folder(model).graph_path("vq_decoder"), net) < 1e-4  # after training too: frozen
    assert any(not torch.equal(fitted[k], first[k]) for k in fitted if k.startswith("vq.encoder."))

    predictor = _train(tiny_corpus, "predictor", tmp_path / "predictor", vq, steps=1)
    refiner = _train(tiny_corpus, "refiner", tmp_path / "refiner", predictor, refiner_fd=0.1, refiner_shut=1.0)

    out = tmp_path / "grafted"
    done = cli_in_process(
        "export", str(refiner), "--out", str(out), "--onto", str(model), "--graphs", "refiner", "--int8"
    )
    assert done.returncode == 0, done.stderr
    meta, base = (json.loads((p / "model.json").read_text()) for p in (out, model))
    for name, digest in base["files"].items():
        if name != base["graphs"]["refiner"]["file"]:
            assert meta["files"][name] == digest and (out / name).read_bytes() == (model / name).read_bytes()
    assert "refiner.onnx" not in meta["files"] and not (out / "refiner.onnx").exists()
    assert meta["graphs"]["refiner"]["file"] == "refiner.int8.onnx" and "refiner.int8.onnx" in meta["files"]
    _assert_motion_projection_float(out / "refiner.int8.onnx")
    assert meta["architecture"]["refiner_fd"] == 0.1 and meta["architecture"]["refiner_shut"] == 1.0
    assert meta["grafted"]["refiner"]["stage"] == "refiner"
    audio = dyadic_audio(seconds=3.0)
    moved = [rep.encode_clip(ProbTalkGenerator({"model": str(p)}).generate(audio, seed=0)[0]) for p in (model, out)]
    assert moved[0].shape == moved[1].shape and not np.allclose(moved[0], moved[1])


def test_graft_mistakes_are_one_line(probtalk_stages: dict[str, Path], tiny_corpus: Path, tmp_path: Path) -> None:
    model, refiner = probtalk_stages["model"], probtalk_stages["refiner"]
    other = _train(tiny_corpus, "refiner", tmp_path / "other", probtalk_stages["predictor"], steps=1, dropout=0.2)
    for args, text in (
        (["--graphs", "refiner"], "needs --onto"),
        (["--onto", str(model), "--graphs", "mixer"], "mixer: not a graph of"),
        (["--onto", str(tmp_path), "--graphs", "refiner"], "not a convodrive model folder"),
    ):
        done = cli_in_process("export", str(refiner), "--out", str(tmp_path / "o"), *args)
        assert done.returncode == 2 and text in done.stderr and len(done.stderr.splitlines()) == 1, done.stderr
    done = cli_in_process(
        "export", str(other), "--out", str(tmp_path / "o"), "--onto", str(model), "--graphs", "refiner"
    )
    assert done.returncode == 2 and "other settings than the replaced graphs' (dropout)" in done.stderr, done.stderr
    assert not (tmp_path / "o").exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    with pytest.raises(UserError, match="model.json: missing: not a convodrive model folder"):
        _train(tiny_corpus, "vq", tmp_path / "wrong", steps=1, vq_decoder_from=str(tmp_path))


def test_a_teacher_s_refiner_gives_the_body_s_target(
    probtalk_stages: dict[str, Path], tiny_corpus: Path, tmp_path: Path
) -> None:
    """With ``refiner_teacher``, the body's target in the free frames is the folder's refiner's
    output on the same input; the face's and every known frame's stay the truth. A student taught
    so lands nearer the teacher's body than one taught by the truth from the same start."""
    from convodrive.models.probtalk_config import REFINER_GROUPS
    from convodrive.neural.folder import load_model_folder
    from convodrive.neural.session import Graph
    from convodrive.training.recipes.probtalk_teacher import taught_target

    model = probtalk_stages["model"]
    rng = np.random.default_rng(0)
    shape = (2, 48, rep.FEATURE_DIM)
    combined, motion = (torch.from_numpy(rng.standard_normal(shape).astype(np.float32)) for _ in range(2))
    audio = torch.from_numpy((rng.standard_normal((2, 48, 2, 80)) * 3 - 8).astype(np.float32))
    known = torch.zeros(2, 48, 1)
    known[:, :8] = 1.0
    speaker = torch.zeros(2, dtype=torch.int64)
    target = taught_target(str(model), ("body",), combined, audio, known, speaker, motion).numpy()
    teacher = Graph(load_model_folder(model).graph_path("refiner"))
    refined = teacher(motion=combined.numpy(), audio=audio.numpy(), known_mask=known.numpy(), speaker=speaker.numpy())
    body, face = rep.GROUPS["body"], rep.GROUPS["face"]
    assert np.array_equal(target[:, 8:, body], refined["refined"][:, 8:, body])
    assert np.array_equal(target[:, :8], motion.numpy()[:, :8]) and np.array_equal(
        target[..., face], motion.numpy()[..., face]
    )
    rest = taught_target(str(model), ("body_but_spine",), combined, audio, known, speaker, motion).numpy()
    spine, others = REFINER_GROUPS["spine"], REFINER_GROUPS["body_but_spine"]
    assert np.array_equal(rest[..., spine], motion.numpy()[..., spine]), "the spine keeps the truth"
    assert np.array_equal(rest[:, 8:, others], refined["refined"][:, 8:, others])

    start = probtalk_stages["predictor"]
    taught = _train(tiny_corpus, "refiner", tmp_path / "taught", start, seed=1, refiner_teacher=str(model))
    truth = _train(tiny_corpus, "refiner", tmp_path / "truth", start, seed=1)
    assert json.loads((taught / "run.json").read_text())["model_config"]["refiner_teacher"] == str(model)
    grafted = tmp_path / "grafted"
    done = cli_in_process("export", str(taught), "--out", str(grafted), "--onto", str(model), "--graphs", "refiner")
    assert done.returncode == 0, done.stderr
    meta = json.loads((grafted / "model.json").read_text())
    assert meta["architecture"]["refiner_teacher"] == model.name, "a folder's name, not a path of this machine"
    batch = [torch.from_numpy(a) for a in (combined.numpy(), audio.numpy(), known.numpy())]
    gaps = []
    for run in (taught, truth):
        net = restore(run)[4]
        net.eval()
        with torch.no_grad():
            mine = net.refiner(batch[0], net.audio_norm(batch[1]), batch[2], speaker).numpy()
        gaps.append(float(np.abs(mine[:, 8:, body] - refined["refined"][:, 8:, body]).mean()))
    assert gaps[0] < 0.8 * gaps[1], gaps


def test_a_teacher_of_other_data_is_one_line(
    probtalk_stages: dict[str, Path], tiny_corpus: Path, tmp_path: Path
) -> None:
    vq_only = tmp_path / "vq_model"
    done = cli_in_process("export", str(probtalk_stages["vq"]), "--out", str(vq_only))
    assert done.returncode == 0, done.stderr
    with pytest.raises(UserError, match=r"refiner_teacher=.*: the folder has no refiner graph$"):
        _train(
            tiny_corpus, "refiner", tmp_path / "r", probtalk_stages["predictor"], steps=1, refiner_teacher=str(vq_only)
        )
