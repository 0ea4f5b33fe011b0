"""The MuJoCo faces, measured on the models' geometry: the humanoid's lips meet at rest and its open
mouth shows the mouth between them, not skin; its front camera shows it whole, feet included; the
servo head's jaw stays joined to the skull at every opening."""

from __future__ import annotations

import importlib.resources

import numpy as np
import pytest

from tests.conftest import require

pytestmark = require("mujoco")

import mujoco  # noqa: E402

SIMS = importlib.resources.files("convodrive.sims")
HUMANOID = SIMS.joinpath("convo_humanoid.xml")
SERVO_HEAD = SIMS.joinpath("servo_head.xml")


def _posed(path, **joints: float):
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    for name, value in joints.items():
        d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)]] = value
    mujoco.mj_forward(m, d)
    return m, d


def _geom(m, name: str) -> int:
    gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
    assert gid >= 0, name
    return gid


def _distance(m, d, a: str, b: str) -> float:
    """Signed distance between two geoms' surfaces (negative: they overlap)."""
    return float(mujoco.mj_geomDistance(m, d, _geom(m, a), _geom(m, b), 0.2, np.zeros(6)))


def _hit(m, d, origin, direction) -> int:
    gid = np.array([-1], np.int32)
    mujoco.mj_ray(m, d, np.asarray(origin, float), np.asarray(direction, float), None, 1, -1, gid)
    return int(gid[0])


def _material(m, gid: int) -> str:
    return (
        ""
        if gid < 0 or m.geom_matid[gid] < 0
        else mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_MATERIAL, m.geom_matid[gid])
    )


def _between_the_lips(m, d) -> list[str]:
    """What a view from the front meets along the midline between the lips' centres."""
    head = d.xmat[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "head")].reshape(3, 3)
    up, forward = head[:, 2], head[:, 0]
    top, bottom = (d.geom_xpos[_geom(m, n)] for n in ("upper_lip", "lower_lip"))
    seen = []
    for t in np.linspace(0.1, 0.9, 9):
        point = top + t * (bottom - top)
        seen.append(_material(m, _hit(m, d, point + 0.2 * forward, -forward)))
    assert np.dot(top - bottom, up) > 0
    return seen


def test_humanoid_lips_meet_at_rest():
    m, d = _posed(HUMANOID, jaw=0.0)
    assert _distance(m, d, "upper_lip", "lower_lip") <= 0.0
    assert set(_between_the_lips(m, d)) == {"lip"}  # no dark slit between closed lips


@pytest.mark.parametrize("jaw", [0.2, 0.35, 0.5])
def test_humanoid_open_mouth_shows_the_mouth_down_to_the_lower_lip(jaw):
    """Wide open, the lower lip stays on the chin and bounds the opening: between the lips the
    view meets lips, teeth and the mouth's inside, never a band of chin skin."""
    m, d = _posed(HUMANOID, jaw=jaw)
    assert _distance(m, d, "lower_lip", "chin") < -0.002
    seen = _between_the_lips(m, d)
    assert "skin" not in seen and "mouth" in seen, seen


def test_humanoid_front_camera_shows_the_whole_seated_body():
    m, d = _posed(HUMANOID)
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "front")
    width, height = 640, 480
    pos, rot = d.cam_xpos[cam], d.cam_xmat[cam].reshape(3, 3)
    f = height / 2 / np.tan(np.radians(m.cam_fovy[cam]) / 2)
    shoes = [g for g in range(m.ngeom) if _material(m, g) == "shoe"]
    hair = [_geom(m, "hair")]
    assert len(shoes) == 2
    for g in shoes + hair:
        for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            world = d.geom_xpos[g] + d.geom_xmat[g].reshape(3, 3) @ (corner * m.geom_size[g])
            local = rot.T @ (world - pos)
            assert local[2] < 0  # in front of the camera
            x, y = width / 2 + f * local[0] / -local[2], height / 2 - f * local[1] / -local[2]
            assert 0 <= x <= width and 0 <= y <= height, (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g), x, y)


def _hinge_in_jaw(m, d) -> int:
    """How many of 25 points along the jaw's hinge axis (12 cm of it, centred on the head) lie
    inside the jaw's own geoms. A jaw hung from its hinge carries geometry along the axis it turns
    about, as a mandible does; a plate beside its hinge floats when it turns."""
    jaw = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "jaw")
    joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "jaw")
    anchor, axis = d.xanchor[joint], d.xaxis[joint]
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == jaw]
    return sum(any(_contains(m, d, g, anchor + t * axis) for g in geoms) for t in np.linspace(-0.06, 0.06, 25))


def _contains(m, d, g: int, point: np.ndarray) -> bool:
    """Whether ``point`` lies inside geom ``g`` (ellipsoid, capsule, box or sphere)."""
    local = d.geom_xmat[g].reshape(3, 3).T @ (point - d.geom_xpos[g])
    size = m.geom_size[g]
    kind = m.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return float(np.sum((local / size) ** 2)) <= 1.0
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return float(np.linalg.norm(local)) <= size[0]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return bool(np.all(np.abs(local) <= size))
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        z = np.clip(local[2], -size[1], size[1])
        return float(np.linalg.norm(local - [0, 0, z])) <= size[0]
    return False


@pytest.mark.parametrize("jaw", [0.0, 0.175, 0.35])
def test_servo_head_jaw_stays_joined_to_the_skull(jaw):
    """The jaw overlaps the skull at every opening and hangs from its hinge: its geometry runs
    along the hinge axis inside the skull, on both sides of the head."""
    m, d = _posed(SERVO_HEAD, jaw=jaw)
    assert _distance(m, d, "jaw", "skull") < -0.005
    for ramus in ("ramus_l", "ramus_r"):
        assert _distance(m, d, ramus, "skull") < -0.005
    assert _hinge_in_jaw(m, d) >= 4


def test_servo_head_open_mouth_shows_between_the_lips():
    m, d = _posed(SERVO_HEAD, jaw=0.35)
    frame = d.xmat[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "roll")].reshape(3, 3)
    forward = frame[:, 0]
    top, bottom = (d.geom_xpos[_geom(m, n)] for n in ("upper_lip", "lower_lip"))
    seen = {
        _material(m, _hit(m, d, top + t * (bottom - top) + 0.2 * forward, -forward)) for t in np.linspace(0.2, 0.8, 7)
    }
    assert seen == {"dark"}, seen


def test_servo_head_lips_meet_at_rest():
    m, d = _posed(SERVO_HEAD, jaw=0.0)
    assert _distance(m, d, "upper_lip", "lower_lip") <= 0.0
