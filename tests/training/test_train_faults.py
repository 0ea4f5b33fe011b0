"""convodrive train and export against bad settings, bad folders, a full disk and damaged checkpoints:
one line on stderr naming the option or file, exit code 2, nothing half-written left behind."""

from __future__ import annotations

import json
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import cli_in_process, require, run_cli

pytestmark = [require("torch"), require("onnxruntime")]

TINY = ["--preset", "tiny", "--device", "cpu", "--no-progress"]


def _one_line(out: subprocess.CompletedProcess, *fragments: str) -> None:
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and all(f in lines[0] for f in fragments), out.stderr


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (["--set", "lr=NaN"], "--set lr=nan: the learning rate must be a number above 0"),
        (["--set", "lr=-1"], "--set lr=-1.0: the learning rate"),
        (["--set", "lr=Infinity"], "--set lr=inf: the learning rate"),
        (["--set", "lr=1e30"], "--set lr=1e+30: the learning rate"),
        (["--set", "log_every=0"], "--set log_every=0: must be between 1 and"),
        (["--set", "val_every=0"], "--set val_every=0: must be between 1 and"),
        (["--set", "checkpoint_every=0"], "--set checkpoint_every=0: must be between 1 and"),
        (["--set", "channels=100000000"], "--set channels=100000000: must be between 1 and 4096"),
        (["--set", "channels=0"], "--set channels=0: must be between 1 and 4096"),
        (["--batch-size", "100000000"], "--batch-size must be between 1 and 65536, got 100000000"),
        (["--set", "velocity_weight=Infinity"], "training diverged at step 1 (loss inf"),
    ],
)
def test_bad_settings_are_one_line_and_leave_no_folder(
    settings: list[str], message: str, tiny_corpus: Path, tmp_path: Path
) -> None:
    out = cli_in_process("train", "fgd", "--corpus", str(tiny_corpus), *TINY, *settings, "--out", str(tmp_path / "run"))
    _one_line(out, message)
    assert not (tmp_path / "run").exists()  # the diverged run wrote run.json and metrics.csv, then removed them


def test_a_run_that_fails_in_an_existing_folder_leaves_it_as_it_was(tiny_corpus: Path, tmp_path: Path) -> None:
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("mine")
    out = run_cli(
        "train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--set", "velocity_weight=Infinity",
        "--out", str(tmp_path / "run"),
    )  # fmt: skip
    _one_line(out, "training diverged at step 1")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["notes.txt"]


def test_an_out_that_cannot_be_a_run_folder_is_refused_before_anything_runs(tiny_corpus: Path, tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    for target, message in ((afile, "exists and is not a folder"), (afile / "run", f"{afile} is not a folder")):
        out = cli_in_process("train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--out", str(target))
        _one_line(out, f"--out {target}", message)
    # A folder root may write in but a user may not: a fresh interpreter without root's override.
    out = run_cli("train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--out", str(locked / "run"), as_user=True)
    _one_line(out, f"--out {locked / 'run'}", "cannot create it in")
    assert afile.read_text() == "x" and not any(locked.iterdir())


def _limited(limit: int, *args: str) -> subprocess.CompletedProcess:
    """``convodrive`` whose files may not grow past ``limit`` bytes: its writes fail as on a full
    disk (Python ignores SIGXFSZ, so a write past the limit is an EFBIG error)."""

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run(
        [sys.executable, "-m", "convodrive.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=cap,
    )


def test_a_full_disk_at_a_checkpoint_is_one_line_and_keeps_the_last(
    tiny_corpus: Path, tiny_fgd_run: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(tiny_fgd_run, run)  # checkpoint step 10; the model file is about 110 kB
    before = {p.name: p.read_bytes() for p in (run / "checkpoints" / "step-00000010").iterdir()}
    out = _limited(60_000, "train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--steps", "20", "--out", str(run))
    _one_line(out, "step-00000020: cannot be written", "the last checkpoint, step-00000010, is intact")
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-00000010"]  # no .ckpt-* left
    assert {p.name: p.read_bytes() for p in (run / "checkpoints" / "step-00000010").iterdir()} == before


def test_a_killed_save_leaves_temporary_folders_the_next_run_removes(
    tiny_corpus: Path, tiny_fgd_run: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(tiny_fgd_run, run)
    stale = run / "checkpoints" / ".ckpt-k1ll3d"  # what a SIGKILL during save_checkpoint leaves
    stale.mkdir()
    (stale / "model.safetensors").write_bytes(b"\0" * 100)
    out = run_cli("train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--steps", "11", "--out", str(run))
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-00000010", "step-00000011"]


def _damage_truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _damage_state(edit: str) -> object:
    def damage(path: Path) -> None:
        state = json.loads(path.read_text())
        if edit == "list":
            path.write_text("[]")
        elif edit == "step":
            state["step"] = "ten"
            path.write_text(json.dumps(state))
        else:
            state["model_config"]["channels"] += 1
            path.write_text(json.dumps(state))

    return damage


@pytest.mark.parametrize(
    ("command", "file", "damage", "message"),
    [
        ("train", "optimizer.safetensors", _damage_truncate, "cannot be read"),
        ("train", "state.json", _damage_state("step"), "'step' is 'ten', not a step count"),
        ("export", "state.json", _damage_state("list"), "is not a JSON object (a list)"),
        ("export", "state.json", _damage_state("channels"), ""),
        ("export", "data.npz", _damage_truncate, "cannot be read"),
    ],
    ids=["train-truncated-optimizer", "train-step-text", "export-state-list", "export-config-weights", "export-npz"],
)
def test_a_damaged_checkpoint_is_one_line_naming_the_file(
    command: str, file: str, damage: object, message: str, tiny_corpus: Path, tiny_fgd_run: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(tiny_fgd_run, run)
    ckpt = run / "checkpoints" / "step-00000010"
    damage(ckpt / file)  # type: ignore[operator]
    if command == "train":
        out = cli_in_process("train", "fgd", "--corpus", str(tiny_corpus), *TINY, "--steps", "12", "--out", str(run))
        named = ckpt / file
    else:
        out = cli_in_process("export", str(ckpt), "--out", str(tmp_path / "model"))
        named = ckpt / ("model.safetensors" if message == "" else file)  # weights of another shape than the config
        assert not (tmp_path / "model").exists()
    _one_line(out, f"{named}: ", message)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-00000010"]


def test_a_batch_larger_than_the_free_memory_is_refused_before_the_first_step() -> None:
    import numpy as np
    import torch

    from convodrive.plumbing.errors import UserError
    from convodrive.training.batches import available_memory, check_batch_fits
    from convodrive.training.recipe import Batch, Examples

    class Wide(Examples):
        """Examples of 4 GB each, as a tensor that only claims the size (expanded, not allocated)."""

        def __len__(self) -> int:
            return 10

        def batch(self, indices: np.ndarray) -> Batch:
            return {"motion": torch.zeros(1, 1).expand(len(indices), 10**9)}

    free = available_memory()
    assert free is not None and free > 0
    if free > 2 * 4 * 10**9:
        check_batch_fits(Wide(), 1, 1)  # one example fits a machine with 8 GB free
    with pytest.raises(UserError, match=r"--batch-size 65536: one batch holds .* GiB of examples, more than half"):
        check_batch_fits(Wide(), 65536, 65536)
