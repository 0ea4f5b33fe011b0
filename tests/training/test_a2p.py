"""The a2p recipe: six stages train on a corpus, each from the runs it builds on (two for
distillation), the mistakes of ordering them are one line; its ONNX graphs match torch, and the
guide sampled through the exported step graph with its cache passed in and out equals sampling
by re-running the torch model over the whole prefix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import built_once, cli_in_process, require

pytestmark = [require("torch"), require("onnxruntime")]

import torch  # noqa: E402

from convodrive.models.a2p import A2P  # noqa: E402
from convodrive.neural.autoregressive import KVCache, sample_tokens, top_p  # noqa: E402
from convodrive.neural.session import Graph, SessionOptions  # noqa: E402
from convodrive.training.export import export_graph, parity, restore  # noqa: E402
from convodrive.training.recipes.a2p_export import export_graphs  # noqa: E402

TINY = ["--preset", "tiny", "--device", "cpu", "--no-progress", "--steps", "2"]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Conversations long enough for a body example (7 s of VQ history and a 2 s window)."""
    from tests.corpora import write_tiny_corpus

    return (
        built_once(
            tmp_path_factory,
            "a2p-corpus",
            lambda folder: write_tiny_corpus(folder / "corpus", conversations=4, seconds=12.0),
        )
        / "corpus"
    )


@pytest.fixture(scope="module")
def runs(corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The six stages, in process (the CLI's own path is under test below, in the mistakes)."""
    from convodrive.training.loop import TrainRequest, train

    def build(root: Path) -> None:
        for stage, inits in (
            ("lip", []),
            ("face", ["lip"]),
            ("vq", []),
            ("guide", ["vq"]),
            ("body", ["guide"]),
            ("distill", ["face", "body"]),
        ):
            request = TrainRequest(
                "a2p", corpus, preset="tiny", stage=stage, out=root / stage, steps=2, device="cpu", progress=False,
                init=[root / i for i in inits] or None,
            )  # fmt: skip
            assert train(request).step == 2

    return built_once(tmp_path_factory, "a2p-runs", build)


def test_distillation_starts_from_both_sides_with_students_as_copies(runs: Path) -> None:
    _, _, _, _, net = restore(runs / "distill")
    assert isinstance(net, A2P) and net.face_student is not None and net.face is not None
    _, _, _, _, face_run = restore(runs / "face")
    assert isinstance(face_run, A2P) and face_run.face is not None
    for a, b in zip(net.face.parameters(), face_run.face.parameters()):
        assert torch.equal(a, b)  # the teacher is the face run's, untouched
    moved = [
        float((a - b).detach().abs().max())
        for a, b in zip(net.face_student.layers.parameters(), net.face.layers.parameters())
    ]
    assert 0 < max(moved) < 0.1  # a copy of the teacher, moved by two steps


def test_stages_out_of_order_are_one_line(corpus: Path, runs: Path, tmp_path: Path) -> None:
    no_init = cli_in_process(
        "train", "a2p", "--stage", "face", "--corpus", str(corpus), *TINY, "--out", str(tmp_path / "f")
    )
    assert no_init.returncode == 2 and "--init" in no_init.stderr and "Traceback" not in no_init.stderr
    one_side = cli_in_process(
        "train", "a2p", "--stage", "distill", "--corpus", str(corpus), *TINY, "--out", str(tmp_path / "d"),
        "--init", str(runs / "face"),
    )  # fmt: skip
    assert one_side.returncode == 2 and "vq" in one_side.stderr and "Traceback" not in one_side.stderr
    wrong = cli_in_process(
        "train", "a2p", "--stage", "guide", "--corpus", str(corpus), *TINY, "--out", str(tmp_path / "g"),
        "--init", str(runs / "lip"),
    )  # fmt: skip
    assert wrong.returncode == 2 and "holds no vq network of these settings" in wrong.stderr
    assert not (tmp_path / "f" / "checkpoints").exists()


def test_two_inits_that_disagree_are_refused(corpus: Path, runs: Path, tmp_path: Path) -> None:
    from convodrive.training.loop import TrainRequest, train

    other = TrainRequest(
        "a2p", corpus, preset="tiny", stage="lip", out=tmp_path / "lip5", steps=2, seed=5, device="cpu", progress=False
    )
    assert train(other).step == 2
    both = cli_in_process(
        "train", "a2p", "--stage", "face", "--corpus", str(corpus), *TINY, "--out", str(tmp_path / "f"),
        "--init", str(runs / "lip"), "--init", str(tmp_path / "lip5"),
    )  # fmt: skip
    assert both.returncode == 2 and "different values" in both.stderr


@pytest.fixture(scope="module")
def graphs(runs: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[A2P, dict[str, Path]]:
    """A few graphs of the distill stage exported (all twelve take minutes on a loaded machine;
    ``convodrive export`` checks every one's parity when the shipped model is made)."""
    _, _, _, spec, net = restore(runs / "distill")
    assert isinstance(net, A2P)
    folder = tmp_path_factory.mktemp("a2p-graphs")
    paths = {}
    for g in export_graphs(net, spec):
        if g.name in ("guide_step", "face_student_step", "body_memory"):
            paths[g.name] = folder / f"{g.name}.onnx"
            export_graph(g, paths[g.name])
            worst = max(parity(g, paths[g.name], sizes=(1, 7, 33)).values())
            assert worst < 1e-4, (g.name, worst)
    return net, paths


def test_guide_sampling_through_the_step_graph_equals_a_full_torch_rerun(graphs: tuple[A2P, dict[str, Path]]) -> None:
    """Tokens drawn with ONNX Runtime, one step per token and the cache passed in and out (from
    an empty one, and sliding past the band), are those the whole-prefix torch model gives for the
    same uniform draws."""
    net, paths = graphs
    guide = net.guide
    assert guide is not None
    step_graph = Graph(paths["guide_step"], SessionOptions(threads=1, device="cpu"))
    config = net.config
    takes, seconds, levels, span = 2, 5, config.vq_levels, config.guide_audio_span
    torch.manual_seed(3)
    memory = guide.audio_memory(torch.randn(1, seconds + span - 1, 30, 2 * 80)).repeat(takes, 1, 1)
    speaker = np.zeros(takes, np.int64)
    cache = KVCache.empty(
        config.guide_layers,
        takes,
        config.guide_heads,
        config.guide_width // config.guide_heads,
        config.guide_band,
        guide.start_token,
    )
    rngs = [np.random.default_rng([9, t]) for t in range(takes)]
    tokens = []
    seen: list[np.ndarray] = []  # the step graph's logits, token after token
    for second in range(seconds):
        band = memory[:, second : second + span].detach().numpy()

        def step(token, position, keys, values, band=band):
            out = step_graph(
                token=token, position=position, audio=band, past_keys=keys, past_values=values, speaker=speaker
            )
            seen.append(out["logits"].reshape(takes, -1))
            return out["logits"], out["keys"], out["values"]

        tokens.append(sample_tokens(step, cache, levels, 0.9, rngs))
    drawn = np.concatenate(tokens, axis=1)
    assert drawn.shape[1] > config.guide_band  # the cache slid
    inputs = torch.cat([torch.full((takes, 1), guide.start_token), torch.from_numpy(drawn[:, :-1])], dim=1)
    with torch.no_grad():
        logits = guide(inputs, memory, torch.from_numpy(speaker)).numpy()
    # What is continuous is compared across the two runtimes (a draw near a tie may go either way
    # with a CPU's rounding); the draws are then those of the step graph's own logits.
    np.testing.assert_allclose(np.stack(seen, axis=1), logits, atol=1e-4)
    rngs = [np.random.default_rng([9, t]) for t in range(takes)]
    for i in range(drawn.shape[1]):
        expected = top_p(seen[i], 0.9, np.array([r.random() for r in rngs]))
        np.testing.assert_array_equal(drawn[:, i], expected)


def test_body_memory_graph_reads_guide_poses_at_any_count(graphs: tuple[A2P, dict[str, Path]]) -> None:
    """The runtime passes as many guide poses as lie near the window, one when there is none."""
    net, paths = graphs
    body = net.body
    assert body is not None
    graph = Graph(paths["body_memory"], SessionOptions(threads=1, device="cpu"))
    rng = np.random.default_rng(0)
    for count in (1, 3, 9):
        feed = {
            "audio": (rng.standard_normal((1, 50, 2, 80)) - 8).astype(np.float32),
            "guide": rng.standard_normal((1, count, 258)).astype(np.float32),
            "guide_positions": (np.arange(count) * 30.0 - 20).astype(np.float32)[None],
            "guide_valid": np.ones((1, count), np.float32),
            "keep": np.ones((1, 2), np.float32),
            "speaker": np.zeros(1, np.int64),
        }
        out = graph(feed)
        with torch.no_grad():
            want = body.memory(
                [net.audio_norm(torch.from_numpy(feed["audio"]))],
                torch.from_numpy(feed["keep"]),
                torch.from_numpy(feed["speaker"]),
                torch.from_numpy(feed["guide"]),
                torch.from_numpy(feed["guide_positions"]),
                torch.from_numpy(feed["guide_valid"]),
            )
        np.testing.assert_allclose(out["guide_keys"], want.keys[1].numpy(), atol=1e-4)
        assert out["guide_bias"].shape == (1, 1, 1, count + 1)


def test_the_velocity_loss_counts_the_step_from_the_known_frames_to_the_new_ones() -> None:
    """A prediction that is right on the new frames but starts them away from the known prefix (a
    seam) pays; one that is wrong only on the known frames, which the sampler replaces, does not."""
    from convodrive.training.recipes.a2p_losses import seam_velocity_error

    target = torch.linspace(0, 1, 20)[None, :, None].repeat(1, 1, 3)
    known = torch.zeros(1, 20, 1)
    known[:, :8] = 1.0
    mask = torch.ones(1, 1, 3)
    wrong_where_pinned = target + 5 * known
    assert float(seam_velocity_error(wrong_where_pinned, target, known, mask)) == 0.0
    jumped = target + 0.5 * (1 - known)  # the new frames' shape is right, their start is not
    assert float(seam_velocity_error(jumped, target, known, mask)) > 0.01
