"""Hostile and broken avatars: buffer and image URIs that leave the avatar's folder or name a
device or a FIFO, invalid base64, node graphs with cycles, indices out of range, deep JSON and
accessors claiming billions of values. Each is one line naming the file, exit 2, in bounded time;
and an avatar with no morph targets is posed (the body moves, the face stays still)."""

from __future__ import annotations

import base64
import copy
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from convodrive.backends.avatar.gltf_read import load_avatar
from convodrive.backends.avatar.gltf_write import glb_bytes, rig_to_gltf
from convodrive.backends.avatar.mannequin import build_mannequin
from convodrive.backends.avatar.skinning import RigPoser
from convodrive.cli.main import main
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.clip import MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX


@pytest.fixture(scope="module")
def mannequin() -> tuple[dict[str, Any], bytes]:
    return rig_to_gltf(build_mannequin())


def split_gltf(mannequin: tuple[dict[str, Any], bytes], folder: Path, uri: str) -> tuple[dict[str, Any], Path]:
    """The mannequin as a .gltf in ``folder`` whose buffer is the file ``uri`` names (written
    beside it as ``m.bin``; the caller moves or replaces it)."""
    doc, blob = copy.deepcopy(mannequin[0]), mannequin[1]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.bin").write_bytes(blob)
    doc["buffers"][0]["uri"] = uri
    path = folder / "m.gltf"
    path.write_text(json.dumps(doc))
    return doc, path


def check_fails(path: Path, capsys: pytest.CaptureFixture[str], *needles: str) -> None:
    assert main(["avatar", "check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(path) in err, err
    for needle in needles:
        assert needle in err, err


def test_a_buffer_beside_the_gltf_and_a_data_uri_load(mannequin, tmp_path):
    _, path = split_gltf(mannequin, tmp_path / "a", "m.bin")
    assert load_avatar(path).rest.shape[0] > 1000
    _, path = split_gltf(
        mannequin, tmp_path / "b", "data:application/octet-stream;base64," + base64.b64encode(mannequin[1]).decode()
    )
    assert load_avatar(path).rest.shape[0] > 1000


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("uri", "needle"),
    [
        ("/dev/zero", "buffer 0: uri '/dev/zero' is not a relative path inside the avatar's folder"),
        ("/etc/passwd", "buffer 0: uri '/etc/passwd' is not a relative path inside the avatar's folder"),
        ("../../m.bin", "buffer 0: uri '../../m.bin' leads out of the avatar's folder"),
        ("file:///etc/passwd", "is not a relative path inside the avatar's folder"),
        ("link.bin", "buffer 0: uri 'link.bin' leads out of the avatar's folder"),
        ("fifo.bin", "buffer 0: 'fifo.bin' is not a regular file"),
        ("short.bin", "buffer 0 holds 100 bytes but its views need"),
        ("data:application/octet-stream;base64,@@@", "buffer 0: its data: URI is not valid base64"),
    ],
)
def test_buffer_uris_stay_inside_the_folder_and_name_regular_files(mannequin, tmp_path, capsys, uri, needle):
    deep = tmp_path / "x" / "y"
    _, path = split_gltf(mannequin, deep, uri)
    (tmp_path / "m.bin").write_bytes(mannequin[1])  # two levels up: readable, but outside
    (deep / "link.bin").symlink_to(tmp_path / "m.bin")
    os.mkfifo(deep / "fifo.bin")  # reading it would block for ever
    (deep / "short.bin").write_bytes(b"\0" * 100)
    check_fails(path, capsys, needle)


@pytest.mark.timeout(60)
def test_image_uris_stay_inside_the_folder(mannequin, tmp_path, capsys):
    doc, path = split_gltf(mannequin, tmp_path / "a", "m.bin")
    doc["images"] = [{"uri": "../secret.png"}]
    doc["textures"] = [{"source": 0}]
    doc["materials"][0].setdefault("pbrMetallicRoughness", {})["baseColorTexture"] = {"index": 0}
    path.write_text(json.dumps(doc))
    (tmp_path / "secret.png").write_bytes(b"\x89PNG")
    check_fails(path, capsys, "image 0: uri '../secret.png' leads out of the avatar's folder")


def _edit(doc: dict[str, Any], change: str) -> None:
    nodes = doc["nodes"]
    if change == "cycle":
        nodes[1].setdefault("children", []).append(0)
    elif change == "two parents":
        nodes[0].setdefault("children", []).append(nodes[1]["children"][0])
    elif change == "child":
        nodes[1].setdefault("children", []).append(999)
    elif change == "joint":
        doc["skins"][0]["joints"][3] = -1
    elif change == "mesh":
        next(n for n in nodes if "mesh" in n)["mesh"] = 77
    elif change == "scene":
        doc["scene"] = 5
    elif change == "nodes object":
        doc["nodes"] = {"0": nodes[0]}
    elif change == "huge accessor":
        doc["accessors"].append({"componentType": 5126, "type": "VEC3", "count": 2_000_000_000})
        doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = len(doc["accessors"]) - 1
    elif change == "matrix":
        nodes[2]["matrix"] = "identity"


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ("cycle", "the node graph has a cycle"),
        ("two parents", "has two parents"),
        ("child", "node 1 children refers to nodes 999, but there are"),
        ("joint", "skin 0 joints refers to nodes -1"),
        ("mesh", "mesh refers to meshes 77"),
        ("scene", "scene refers to scenes 5, but there are 1"),
        ("nodes object", "'nodes' must be a list of objects"),
        ("huge accessor", "count must be a whole number from 1 to"),
        ("matrix", "node 2 matrix must be 16 numbers"),
    ],
)
def test_broken_structure_is_one_line_before_anything_is_walked(mannequin, tmp_path, capsys, change, needle):
    doc = copy.deepcopy(mannequin[0])
    _edit(doc, change)
    path = tmp_path / "bad.glb"
    path.write_bytes(glb_bytes(doc, mannequin[1]))
    check_fails(path, capsys, needle)


def test_json_nested_too_deep_is_one_line(tmp_path, capsys):
    path = tmp_path / "deep.gltf"
    path.write_text('{"asset": {"version": "2.0"}, "extras": ' + "[" * 100_000 + "]" * 100_000 + "}")
    check_fails(path, capsys, "nested too deep")


def _without_morphs(mannequin: tuple[dict[str, Any], bytes], path: Path) -> Path:
    doc = copy.deepcopy(mannequin[0])
    for mesh in doc["meshes"]:
        mesh.pop("extras", None)
        mesh.pop("weights", None)
        for prim in mesh["primitives"]:
            prim.pop("targets", None)
    path.write_bytes(glb_bytes(doc, mannequin[1]))
    return path


def test_an_avatar_without_morph_targets_is_posed_with_a_still_face(mannequin, tmp_path):
    rig = load_avatar(_without_morphs(mannequin, tmp_path / "nm.glb"))
    assert rig.morph_names == () and rig.morph_deltas.size == 0
    poser = RigPoser(rig)
    still, _ = poser.pose(MotionFrame.neutral())
    smiling = MotionFrame.neutral()
    smiling.face[BLENDSHAPE_INDEX["mouthSmileLeft"]] = 1.0
    np.testing.assert_array_equal(poser.pose(smiling)[0], still)  # no morph: the face stays
    waving = MotionFrame.neutral()
    waving.pose[JOINT_INDEX["left_shoulder"]] = [0.0, 0.0, 1.0]
    moved = np.linalg.norm(poser.pose(waving)[0] - still, axis=1)
    assert moved.max() > 0.1  # the arm swings through tens of centimetres


@pytest.mark.gl
def test_an_avatar_without_morph_targets_renders_a_video(mannequin, tmp_path, capsys):
    import soundfile

    speech = tmp_path / "talk.wav"
    soundfile.write(speech, np.random.default_rng(0).normal(0, 0.05, (8000, 2)), 16000)
    avatar = _without_morphs(mannequin, tmp_path / "nm.glb")
    out = tmp_path / "out"
    rc = main(["drive", str(speech), "--backend", "render", "-B", f"render.avatar={avatar}", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert (out / "avatar.mp4").stat().st_size > 1000
    assert re.search(r"render\s+ok\s+sent\s+[1-9]\d*\s+dropped\s+0\s+errors\s+0", (out / "run_report.txt").read_text())


@pytest.mark.gl
@pytest.mark.timeout(120)
def test_drive_with_a_cyclic_avatar_exits_2_before_any_frame(mannequin, tmp_path, capsys):
    import soundfile

    speech = tmp_path / "talk.wav"
    soundfile.write(speech, np.zeros((8000, 2)), 16000)
    doc = copy.deepcopy(mannequin[0])
    _edit(doc, "cycle")
    bad = tmp_path / "cyc.glb"
    bad.write_bytes(glb_bytes(doc, mannequin[1]))
    rc = main(
        ["drive", str(speech), "--backend", "render", "-B", f"render.avatar={bad}", "--out", str(tmp_path / "out")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"{bad}: node" in err[0] and "cycle" in err[0], err
    assert not (tmp_path / "out").exists()
