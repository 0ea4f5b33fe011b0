"""The avatar's face and skinning, checked in rendered pixels and against forward kinematics."""

from __future__ import annotations

import numpy as np
import pytest

from convodrive.backends.avatar.mannequin import MAX_INFLUENCES, build_mannequin
from convodrive.backends.avatar.mannequin_head import MOUTH_HALF_WIDTH, MOUTH_Y
from convodrive.backends.avatar.skinning import RigPoser
from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.channels import JAW_OPEN_RAD as JAW_RAD_AT_FULL_OPEN
from convodrive.motion.clip import MotionFrame
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX, REST_POSITIONS, forward_kinematics

SIZE = 192


@pytest.fixture(scope="module")
def face_renderer():
    from convodrive.backends.avatar.render_scene import AvatarRenderer

    r = AvatarRenderer(SIZE, SIZE, camera="face")
    yield r
    r.close()


def _frame(**channels: float) -> MotionFrame:
    f = MotionFrame.neutral()
    for name, value in channels.items():
        f.face[BLENDSHAPE_INDEX[name]] = value
    return f


def _changed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(int) - b.astype(int)).sum(-1) > 24


def _box(renderer, points: np.ndarray, margin: float = 3) -> tuple[slice, slice]:
    px = renderer.project(points)
    x0, y0 = np.floor(px.min(0) - margin).astype(int)
    x1, y1 = np.ceil(px.max(0) + margin).astype(int)
    return slice(max(y0, 0), y1), slice(max(x0, 0), x1)


def _mouth_box(r):
    """Lips, mouth corners and the jaw below them (an open jaw moves the chin and its sides)."""
    w = MOUTH_HALF_WIDTH + 0.027
    z = r.rig.landmarks["mouth"][2]
    return _box(r, np.array([[-w, MOUTH_Y + 0.016, z], [w, MOUTH_Y - 0.075, z]]))


def _eye_boxes(r):
    return [
        _box(r, r.rig.landmarks[k] + np.array([[-0.02, -0.017, 0.012], [0.02, 0.02, 0.012]]))
        for k in ("left_eye", "right_eye")
    ]


def _mask(shape, boxes) -> np.ndarray:
    m = np.zeros(shape, bool)
    for ys, xs in boxes:
        m[ys, xs] = True
    return m


@pytest.mark.gl
def test_jaw_open_changes_the_mouth_and_nothing_else(face_renderer):
    r = face_renderer
    closed, opened = r.render(_frame(jawOpen=0.0)), r.render(_frame(jawOpen=1.0))
    diff = _changed(closed, opened)
    mouth = _mask(diff.shape, [_mouth_box(r)])
    assert diff[mouth].sum() > 0.04 * mouth.sum()  # a visible opening
    assert diff[~mouth].sum() == 0
    assert not diff[_mask(diff.shape, _eye_boxes(r))].any()


@pytest.mark.gl
def test_blink_changes_the_eyes_and_nothing_else(face_renderer):
    r = face_renderer
    open_, shut = r.render(_frame()), r.render(_frame(eyeBlinkLeft=1.0, eyeBlinkRight=1.0))
    diff = _changed(open_, shut)
    eyes = _mask(diff.shape, _eye_boxes(r))
    for ys, xs in _eye_boxes(r):
        assert diff[ys, xs].sum() > 20  # each eye closes
    assert diff[~eyes].sum() == 0
    for box in _pupil_boxes(r):  # a closed lid hides the pupil
        assert _dark(open_, box).sum() > 0 and _dark(shut, box).sum() == 0


def _pupil_boxes(r):
    """The eyeball's visible band: wide enough for the pupil to travel, below the lash line."""
    return [
        _box(r, r.rig.landmarks[k] + np.array([[-0.013, -0.004, 0.012], [0.013, 0.003, 0.012]]), margin=0)
        for k in ("left_eye", "right_eye")
    ]


def _dark(image: np.ndarray, box) -> np.ndarray:
    ys, xs = box
    return image[ys, xs].astype(int).sum(-1) < 150


def _iris(image: np.ndarray, box) -> np.ndarray:
    """Iris and pupil pixels: blue or dark, unlike the white sclera and the warm skin."""
    patch = image[box].astype(int)
    return (patch[..., 2] - patch[..., 0] > 15) | (patch.sum(-1) < 200)


def _pupil_x(image: np.ndarray, box) -> float:
    dark = np.argwhere(_iris(image, box))
    assert len(dark) > 0
    return float(dark[:, 1].mean()) + box[1].start


@pytest.mark.gl
def test_gaze_moves_the_pupils_from_joints_and_from_channels(face_renderer):
    r = face_renderer
    boxes = _pupil_boxes(r)
    ahead = r.render(_frame())
    look_left = _frame()  # eye joints turned toward +X: the character's left, the image's right
    look_left.pose[JOINT_INDEX["left_eye_smplhf"]] = [0, 0.4, 0]
    look_left.pose[JOINT_INDEX["right_eye_smplhf"]] = [0, 0.4, 0]
    turned = r.render(look_left)
    by_channels = r.render(_frame(eyeLookOutLeft=1.0, eyeLookInRight=1.0))
    for box in boxes:
        x0 = _pupil_x(ahead, box)
        assert _pupil_x(turned, box) > x0 + 1.5
        assert _pupil_x(by_channels, box) > x0 + 1.5


@pytest.mark.parametrize("channel", ["mouthFunnel", "mouthPucker", "mouthSmileLeft", "mouthSmileRight", "mouthClose"])
@pytest.mark.gl
def test_lip_shapes_move_the_lips(face_renderer, channel):
    r = face_renderer
    base = _frame(jawOpen=0.6) if channel == "mouthClose" else _frame()
    shaped = _frame(jawOpen=0.6, mouthClose=1.0) if channel == "mouthClose" else _frame(**{channel: 1.0})
    diff = _changed(r.render(base), r.render(shaped))
    mouth = _mask(diff.shape, [_mouth_box(r)])
    assert diff[mouth].sum() > 15
    assert diff[~mouth].sum() == 0


@pytest.mark.gl
def test_smile_is_one_sided(face_renderer):
    r = face_renderer
    diff = _changed(r.render(_frame()), r.render(_frame(mouthSmileLeft=1.0)))
    mx = r.project(r.rig.landmarks["mouth"])[0, 0]
    cols = np.nonzero(diff.any(0))[0]
    # the character's left corner is on the image's right
    assert (cols > mx).sum() > 3 * max((cols < mx).sum(), 1)


@pytest.mark.gl
def test_brows_raise(face_renderer):
    r = face_renderer
    diff = _changed(r.render(_frame()), r.render(_frame(browInnerUp=1.0)))
    eye_y = r.project(r.rig.landmarks["left_eye"])[0, 1]
    rows = np.nonzero(diff.any(1))[0]
    assert len(rows) and rows.max() < eye_y  # only above the eyes


def test_skinning_matches_forward_kinematics():
    avatar = build_mannequin()
    poser = RigPoser(avatar)
    rng = np.random.default_rng(3)
    frame = MotionFrame.neutral()
    frame.pose[:] = rng.normal(0, 0.3, frame.pose.shape)
    frame.translation[:] = [0.1, -0.05, 0.2]
    verts, normals = poser.pose(frame)
    rot, pos = forward_kinematics(axis_angle_to_matrix(frame.pose.astype(float)), frame.translation.astype(float))
    w = avatar.weights.tocsr()
    assert np.allclose(np.asarray(w.sum(1)).ravel(), 1.0)
    assert np.diff(w.indptr).max() <= MAX_INFLUENCES
    rigid = np.flatnonzero(np.isclose(w.max(1).toarray().ravel(), 1.0))
    joints = np.asarray(w[rigid].argmax(1)).ravel()
    moved = set(avatar.morph_index)
    keep = np.array([i not in moved for i in rigid])
    rigid, joints = rigid[keep], joints[keep]
    for j in (
        JOINT_INDEX["left_eye_smplhf"],
        JOINT_INDEX["right_index3"],
        JOINT_INDEX["left_wrist"],
        JOINT_INDEX["head"],
    ):
        assert (joints == j).sum() > 10
    expected = np.einsum("vab,vb->va", rot[joints], avatar.rest[rigid] - REST_POSITIONS[joints]) + pos[joints]
    assert np.abs(verts[rigid] - expected).max() < 1e-4
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)


def test_skinning_matrices_of_rest_pose_are_identity():
    m = RigPoser(build_mannequin()).skin_matrices(MotionFrame.neutral()).reshape(-1, 3, 4)
    assert np.allclose(m[:, :, :3], np.eye(3)) and np.allclose(m[:, :, 3], 0.0)


def test_jaw_joint_opens_the_mouth_like_jaw_open():
    poser = RigPoser(build_mannequin())
    by_joint = MotionFrame.neutral()
    by_joint.pose[JOINT_INDEX["jaw"]] = [JAW_RAD_AT_FULL_OPEN, 0, 0]
    both = _frame(jawOpen=1.0)
    both.pose[JOINT_INDEX["jaw"]] = [JAW_RAD_AT_FULL_OPEN, 0, 0]
    a, _ = poser.pose(by_joint)
    b, _ = poser.pose(_frame(jawOpen=1.0))
    c, _ = poser.pose(both)
    assert np.allclose(a, b, atol=1e-5) and np.allclose(b, c, atol=1e-5)  # never opened twice
