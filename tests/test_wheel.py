"""The wheel is the program: pyproject's package list names every package of the tree, and the wheel
built from it, installed (not editable) in a fresh environment, holds every file of the source
packages (samples, sims, robot profiles, shipped weights, the FGD embedder, the web page), imports
every module and drives a clip with the procedural generator and a learned one.

An editable install hides a package missing from the list (its finder maps the whole source tree),
which is how ``convodrive.corpus.importers`` once went missing from the wheel."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
import soundfile as sf

from tests.conftest import REPO


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def _source_files(folder: Path) -> list[Path]:
    """Files of the checkout under ``folder`` (tracked, or new and not ignored), relative to REPO."""
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "--", str(folder.relative_to(REPO))],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    return [Path(name) for name in listed.stdout.splitlines() if (REPO / name).is_file()]


def _package_roots() -> dict[str, Path]:
    """Each installed top package and the folder it comes from (pyproject's package-dir)."""
    return {name: REPO / folder for name, folder in _pyproject()["tool"]["setuptools"]["package-dir"].items()}


def _packages_in_tree() -> set[str]:
    """Every folder with an ``__init__.py`` under the package roots, as the dotted name it installs as."""
    found = set()
    for name, root in _package_roots().items():
        for init in root.rglob("__init__.py"):
            if ".venv" not in init.parts and "build" not in init.relative_to(root).parts:
                found.add(".".join([name, *init.parent.relative_to(root).parts]))
    return found


def test_the_package_list_is_the_tree() -> None:
    """pyproject lists each package once, and every package of the tree, since setuptools cannot
    find packages that package-dir maps into the convodrive namespace."""
    listed = _pyproject()["tool"]["setuptools"]["packages"]
    assert len(listed) == len(set(listed)), sorted({p for p in listed if listed.count(p) > 1})
    tree = _packages_in_tree()
    assert "convodrive.corpus.importers" in tree
    assert set(listed) == tree, (
        f"not listed: {sorted(tree - set(listed))}; no such package: {sorted(set(listed) - tree)}"
    )


def _expected_in_wheel() -> set[str]:
    """Every file of the source packages, as the path it has in the wheel (caches aside)."""
    roots = _package_roots()
    expected = set()
    for name, root in roots.items():
        nested = [r for n, r in roots.items() if n != name and r != root and root in r.parents]
        for rel in _source_files(root):
            path = REPO / rel
            if any(n in path.parents for n in nested) or "__pycache__" in rel.parts or path.suffix == ".pyc":
                continue
            expected.add("/".join([*name.split("."), *path.relative_to(root).parts]))
    return expected


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel, built offline from a copy of the package folders (the checkout stays untouched)."""
    root = tmp_path_factory.mktemp("wheel")
    project = root / "project"
    for name in ("pyproject.toml", "README.md"):
        (project / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, project / name)
    for folder in set(_package_roots().values()):
        for rel in _source_files(folder):
            (project / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, project / rel)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q"]
        + ["-w", str(root / "dist"), str(project)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, built.stdout + built.stderr
    (found,) = (root / "dist").glob("convodrive-*.whl")
    return found


@pytest.fixture(scope="module")
def venv(wheel: Path) -> Path:
    """A fresh venv with the wheel installed, which sees this interpreter's site-packages for the
    dependencies through a .pth file: the folders only, so no editable finder of a development
    install is loaded there."""
    env_dir = wheel.parent.parent / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    python = env_dir / "bin" / "python"
    site = Path(
        subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    deps = [p for p in sys.path if p.endswith(("site-packages", "dist-packages")) and Path(p).is_dir()]
    (site / "zz_test_dependencies.pth").write_text("".join(f"{p}\n" for p in deps))
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert installed.returncode == 0, installed.stdout + installed.stderr
    return env_dir


def _in_venv(venv: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    """A command of the venv, as a user's shell runs it: from a folder outside the checkout, with
    nothing of the test's own environment pointing at the source tree."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(list(args), capture_output=True, text=True, timeout=300, cwd=cwd, env=env)


@pytest.mark.slow
@pytest.mark.build_tools
def test_the_wheel_holds_every_file_of_the_packages(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as zf:
        names = {n for n in zf.namelist() if not n.startswith("convodrive-")}
    expected = _expected_in_wheel()
    for data in (
        "convodrive/samples/dialogue.wav",
        "convodrive/sims/convo_humanoid.xml",
        "convodrive/config/robots/servo_head.yaml",
        "convodrive/generators/probtalk/model/model.json",
        "convodrive/generators/a2p/model/model.json",
        "convodrive/eval/fgd_model/model.json",
        "convodrive/backends/web/index.html",
        "convodrive/corpus/importers/__init__.py",
    ):
        assert data in expected
    assert not expected - names, f"missing from the wheel: {sorted(expected - names)}"
    assert not names - expected, f"in the wheel but not the tree: {sorted(names - expected)}"


IMPORT_ALL = """
import importlib, json, pkgutil, sys
import convodrive
names, failed = ["convodrive"], {}
for info in pkgutil.walk_packages(convodrive.__path__, "convodrive.", onerror=lambda name: failed.setdefault(name, "walk")):
    if info.name.rsplit(".", 1)[-1] == "__main__":
        continue  # running, not a module to import
    try:
        importlib.import_module(info.name)
        names.append(info.name)
    except Exception as exc:
        failed[info.name] = f"{type(exc).__name__}: {exc}"
outside = [n for n in names if not (getattr(sys.modules[n], "__file__", None) or "").startswith(sys.prefix)]
editable = [repr(f) for f in sys.meta_path if "editable" in repr(f).lower()]
print(json.dumps({"imported": names, "failed": failed, "outside": outside, "editable": editable}))
"""


@pytest.mark.slow
@pytest.mark.build_tools
@pytest.mark.onnxruntime
@pytest.mark.torch
@pytest.mark.mujoco
@pytest.mark.gl
@pytest.mark.live
def test_the_installed_wheel_imports_every_module(venv: Path, tmp_path: Path) -> None:
    out = _in_venv(venv, "python", "-c", IMPORT_ALL, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.splitlines()[-1])
    assert result["failed"] == {}
    assert result["outside"] == [], "modules loaded from outside the installed wheel"
    assert result["editable"] == [], "a development install's finder is active"
    for module in ("convodrive.corpus.importers", "convodrive.retargeting", "convodrive.backends.servo"):
        assert module in result["imported"]
    assert len(result["imported"]) > 150


@pytest.mark.slow
@pytest.mark.build_tools
@pytest.mark.onnxruntime
def test_the_installed_wheel_runs_corpus_import_and_drives(venv: Path, tmp_path: Path) -> None:
    helped = _in_venv(venv, "convodrive", "corpus", "import", "--help", cwd=tmp_path)
    assert helped.returncode == 0, helped.stderr
    assert "usage: convodrive corpus import" in helped.stdout

    # A 2 s clip of the sample the wheel installed.
    where = _in_venv(venv, "python", "-c", "import convodrive.samples as s; print(s.__path__[0])", cwd=tmp_path)
    sample = Path(where.stdout.strip()) / "dialogue.wav"
    assert sample.is_relative_to(venv), sample
    audio, rate = sf.read(sample)
    sf.write(tmp_path / "clip.wav", audio[: 2 * rate], rate)

    for generator, extra in (("procedural", ["--config", "servo_head"]), ("probtalk", [])):
        out = tmp_path / generator
        drive = ["convodrive", "drive", "clip.wav", "--generator", generator, "--backend", "record", "--out", str(out)]
        run = _in_venv(venv, *drive, *extra, "-q", cwd=tmp_path)
        assert run.returncode == 0, run.stderr
        report = json.loads((out / "run_report.json").read_text())
        assert report["frames"] == report["expected_frames"] == 60
        assert report["backends"]["record"]["report"]["frames_written"] == 60
        assert (out / "motion.npz").is_file()
        if generator == "probtalk":  # the shipped weights, read from the installed wheel
            assert Path(report["generator"]["model"]).is_relative_to(venv), report["generator"]
