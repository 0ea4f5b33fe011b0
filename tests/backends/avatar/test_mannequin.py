"""The mannequin reads as a person: sleeves that hide the forearm in every gesture, a face large
enough to read lips, every ARKit channel wired, and contact sheets that say who is talking."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from convodrive.backends.avatar.mannequin import build_mannequin
from convodrive.backends.avatar.rig import Rig
from convodrive.generators.procedural.poses import ARM_JOINTS, KEY_POSES, LIBRARY, LIBRARY_RIGHT, rest_pose
from convodrive.motion.channels import ARKIT_NAMES, BLENDSHAPE_INDEX, ConversationState
from convodrive.motion.clip import MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX, REST_POSITIONS

SIZE = 192
pytestmark = [pytest.mark.gl]


def _inside_cuffs(rig: Rig) -> np.ndarray:
    """Skin vertices of the wrists that sit inside the sleeves in the rest pose."""
    (skin,) = (s for s in rig.surfaces if rig.materials[s.material].name == "skin")
    idx = np.arange(skin.start, skin.end)
    v = rig.rest[idx]
    hidden = np.zeros(len(idx), bool)
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        wrist = REST_POSITIONS[JOINT_INDEX[f"{side}_wrist"]]
        along = sgn * v[:, 0]
        near = np.linalg.norm(v[:, 1:] - wrist[1:], axis=1) < 0.04
        hidden |= near & (along > sgn * wrist[0] - 0.06) & (along < sgn * wrist[0] - 0.026)
    return idx[hidden]


def _gesture(index: int, amount: float, wrist: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MotionFrame:
    """A key pose of the procedural generator, exaggerated as expressiveness 1.5 does, and a wrist
    bent further still."""
    f = MotionFrame.neutral()
    f.pose[:] = rest_pose()
    for arm, lib, sgn in (("left", LIBRARY, 1.0), ("right", LIBRARY_RIGHT, -1.0)):
        f.pose[ARM_JOINTS[arm]] = lib[0] + amount * (lib[index] - lib[0])
        f.pose[JOINT_INDEX[f"{arm}_wrist"]] += np.array(wrist) * [1, sgn, sgn]
    return f


def _marked(rig: Rig) -> Rig:
    """The mannequin with the wrist skin inside its cuffs painted pure green (and one ring of it
    left skin-coloured, so no blend of green reaches a cuff's edge)."""
    hidden = _inside_cuffs(rig)
    faces = np.concatenate([s.faces.astype(np.int64) + s.start for s in rig.surfaces])
    inside = np.zeros(rig.num_vertices, bool)
    inside[hidden] = True
    edge = faces[~inside[faces].all(1)].ravel()  # corners of triangles that leave the hidden set
    inside[edge] = False
    colors = rig.colors.copy()
    colors[inside, :3] = [0.0, 1.0, 0.0]
    return dataclasses.replace(rig, colors=colors)


def _green(image: np.ndarray) -> int:
    img = image.astype(int)
    return int(((img[..., 1] > img[..., 0] + 40) & (img[..., 1] > img[..., 2] + 40)).sum())


def _renderer(rig: Rig, azimuth: float):
    from convodrive.backends.avatar.render_scene import CAMERAS, AvatarRenderer, CameraPreset

    preset = CAMERAS["upper"]
    camera = CameraPreset(preset.anchor, preset.offset, 3.6, 3.6, preset.elevation_deg, azimuth_deg=azimuth)
    return AvatarRenderer(SIZE, SIZE, camera, rig=rig)


WRIST_BENDS = ((0.0, 0.0, 0.0), (0.0, 0.0, -1.1), (0.0, 0.0, 0.9), (-1.2, 0.0, 0.5))
"""Extra wrist rotations (axis-angle, left arm; mirrored for the right) on top of each gesture."""


@pytest.mark.parametrize("azimuth", [0.0, 60.0, 150.0])
def test_no_skin_inside_the_sleeves_shows_in_any_gesture(azimuth):
    """The wrist skin inside each cuff is painted green: in no gesture of the generator,
    exaggerated as expressiveness 1.5 does and with the wrist bent further, from front, side or
    back, does a green pixel show."""
    rig = _marked(build_mannequin())
    assert (rig.colors[:, 1] == 1.0).sum() > 50
    r = _renderer(rig, azimuth)
    try:
        for k in range(len(KEY_POSES)):
            for wrist in WRIST_BENDS:
                assert _green(r.render(_gesture(k, 1.5, wrist))) == 0, (KEY_POSES[k], wrist)
    finally:
        r.close()


def test_the_green_wrist_shows_when_the_cuffs_are_gone():
    """The test above can fail: with each cuff's vertices pulled into the elbow, the green shows."""
    rig = _marked(build_mannequin())
    (cloth,) = (s for s in rig.surfaces if rig.materials[s.material].name == "cloth")
    v = rig.rest[cloth.start : cloth.end]
    cuff = cloth.start + np.flatnonzero((np.abs(v[:, 0]) > 0.6) & (np.abs(v[:, 0]) < 0.7) & (v[:, 1] > 1.3))
    r = _renderer(rig, 0.0)
    pose = r.poser.pose

    def short_sleeves(f):
        verts, normals = pose(f)
        verts[cuff] = verts[cuff].mean(0)
        return verts, normals

    r.poser.pose = short_sleeves
    try:
        assert _green(r.render(_gesture(2, 1.0))) > 20
    finally:
        r.close()


def test_upper_camera_shows_the_face_over_a_fifth_of_the_frame():
    from convodrive.backends.avatar.render_scene import AvatarRenderer

    r = AvatarRenderer(SIZE, SIZE, "upper")
    try:
        marks = r.rig.landmarks
        (_, chin), (_, hairline) = r.project(np.stack([marks["chin"], marks["hairline"]]))
        (_, crown), (_, pelvis) = r.project(np.stack([marks["crown"], marks["pelvis"]]))
    finally:
        r.close()
    assert (chin - hairline) / SIZE >= 0.2
    assert crown > 0  # the whole head in frame
    assert pelvis > SIZE  # it is an upper-body view


def test_every_arkit_channel_moves_the_mannequin():
    from convodrive.backends.avatar.skinning import RigPoser

    rig = build_mannequin()
    assert rig.morph_names == ARKIT_NAMES
    poser = RigPoser(rig)
    rest, _ = poser.pose(MotionFrame.neutral())
    for name in ARKIT_NAMES:
        f = MotionFrame.neutral()
        f.face[BLENDSHAPE_INDEX[name]] = 1.0
        moved, _ = poser.pose(f)
        assert np.linalg.norm(moved - rest, axis=1).max() > 5e-4, name


def test_contact_sheet_labels_each_frame_with_who_is_talking(tmp_path):
    from PIL import Image

    from convodrive.backends.render import STATE_COLORS, ContactSheet

    sheet = ContactSheet(cells=4)
    states = [
        ConversationState.SPEAKING,
        ConversationState.LISTENING,
        ConversationState.OVERLAP,
        ConversationState.SILENCE,
    ]
    for i, state in enumerate(states):
        sheet.offer(i, np.full((64, 64, 3), 200, np.uint8), state)
    path = sheet.write(tmp_path / "sheet.png", fps=30)
    pixels = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3)
    for state in states:
        assert (np.abs(pixels.astype(int) - STATE_COLORS[state]).sum(1) == 0).sum() > 50, state.name
