"""convodrive train: DDP equals one process, resumption continues exactly, mistakes are one line."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import cli_in_process, require, run_cli

pytestmark = [require("torch"), require("onnxruntime")]

import torch  # noqa: E402
from safetensors.torch import load_file  # noqa: E402

from convodrive.training.loop import TrainRequest, train  # noqa: E402

TINY = ["--preset", "tiny", "--device", "cpu", "--no-progress"]


def _weights(run: Path) -> dict[str, torch.Tensor]:
    latest = sorted((run / "checkpoints").iterdir())[-1]
    return load_file(str(latest / "model.safetensors"))


def _max_diff(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> float:
    assert a.keys() == b.keys()
    return max(float((a[k] - b[k]).abs().max()) for k in a)


@pytest.mark.xdist_group("cpu_hogs")  # two trainers on two cores: not beside the demo's real-time servo head
def test_two_ddp_processes_train_the_same_weights_as_one(tiny_corpus: Path, tmp_path: Path) -> None:
    common = ["fgd", "--corpus", str(tiny_corpus), *TINY, "--steps", "6", "--batch-size", "8"]
    one = subprocess.run(
        [sys.executable, "-m", "convodrive.training", *common, "--out", str(tmp_path / "one")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert one.returncode == 0, one.stderr
    two = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node",
            "2",
            "-m",
            "convodrive.training",
            *common,
            "--out",
            str(tmp_path / "two"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert two.returncode == 0, two.stderr
    a, b = _weights(tmp_path / "one"), _weights(tmp_path / "two")
    assert _max_diff(a, b) < 1e-5
    train(
        TrainRequest(
            "fgd",
            tiny_corpus,
            preset="tiny",
            steps=1,
            batch_size=8,
            out=tmp_path / "init",
            device="cpu",
            progress=False,
        )
    )
    assert _max_diff(a, _weights(tmp_path / "init")) > 1e-3  # six steps moved the weights
    assert 'world_size": 2' in (tmp_path / "two" / "run.json").read_text()


def test_a_resumed_run_continues_exactly(tiny_corpus: Path, tmp_path: Path) -> None:
    common = ["train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--set", "checkpoint_every=4"]
    for steps, out in ((8, "straight"), (4, "resumed")):  # in this process; the resumption below is the CLI's
        settings = {"checkpoint_every": 4}
        train(
            TrainRequest(
                "fgd",
                tiny_corpus,
                preset="tiny",
                steps=steps,
                out=tmp_path / out,
                device="cpu",
                progress=False,
                settings=settings,
            )
        )
    second = run_cli(*common, "--steps", "8", "--out", str(tmp_path / "resumed"))
    assert second.returncode == 0, second.stderr
    assert _max_diff(_weights(tmp_path / "straight"), _weights(tmp_path / "resumed")) == 0.0
    log = (tmp_path / "resumed" / "metrics.csv").read_text().splitlines()
    assert log[0] == "step,wall_s,split,name,value" and any(line.startswith("8,") for line in log)
    other = run_cli(*common, "--steps", "8", "--set", "channels=5", "--out", str(tmp_path / "resumed"))
    assert other.returncode == 2 and "other settings" in other.stderr
    # A longer run may stretch its learning-rate decay with it.
    longer = run_cli(*common, "--steps", "10", "--set", "decay_steps=10", "--out", str(tmp_path / "resumed"))
    assert longer.returncode == 0, longer.stderr
    assert any(line.startswith("10,") for line in (tmp_path / "resumed" / "metrics.csv").read_text().splitlines())


def test_batches_assembled_by_worker_processes_train_the_same_weights(tiny_corpus: Path, tmp_path: Path) -> None:
    # a2p's lip regressor has dropout, which draws on torch's global generator as the workers' seeds would
    for workers in (0, 2):
        train(
            TrainRequest(
                "a2p",
                tiny_corpus,
                preset="tiny",
                stage="lip",
                steps=4,
                batch_size=8,
                out=tmp_path / f"workers{workers}",
                device="cpu",
                progress=False,
                workers=workers,
            )
        )
    assert _max_diff(_weights(tmp_path / "workers0"), _weights(tmp_path / "workers2")) == 0.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["train", "nosuchmodel", "--corpus", "C"], "unknown model 'nosuchmodel' (available: a2p, fgd"),
        (["train", "fgd", "--corpus", "C", "--preset", "huge"], "has no preset 'huge' (available: paper, small, tiny)"),
        (["train", "fgd", "--corpus", "C", "--preset", "tiny", "--set", "chanels=3"], "did you mean 'channels'"),
        (["train", "fgd", "--corpus", "NOPE", "--preset", "tiny"], "NOPE: no such corpus folder"),
        (["train", "fgd", "--corpus", "C", "--preset", "tiny", "--threads", "0"], "--threads must be at least 1"),
        (["train", "fgd", "--corpus", "C", "--preset", "tiny", "--workers", "-1"], "--workers must be at least 0"),
        (["train", "probtalk", "--corpus", "C"], "no conversation of the train split lasts 6.13 s"),
        (
            ["train", "a2p", "--corpus", "C", "--stage", "lip"],
            "no conversation of the train split lasts 5.00 s (lip stage)",
        ),
    ],
)
def test_user_mistakes_are_one_line(args: list[str], message: str, tiny_corpus: Path, tmp_path: Path) -> None:
    args = [str(tiny_corpus) if a == "C" else a for a in args]
    out = cli_in_process(*args, "--out", str(tmp_path / "run"))
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_a_corpus_with_a_missing_shard_is_one_line(tiny_corpus: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(tiny_corpus, broken)
    shard = sorted((broken / "shards").iterdir())[0]
    shard.unlink()
    out = cli_in_process("train", "fgd", "--corpus", str(broken), *TINY, "--out", str(tmp_path / "run"))
    assert out.returncode == 2 and shard.name in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
