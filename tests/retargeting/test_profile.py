"""Robot profiles: validation errors name the file and key; the servo head profile matches its twin."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.plumbing.safe_yaml import load_yaml_file
from convodrive.retargeting import RobotProfile, load_profile

GOOD = """
name: tiny
joints:
  pan:
    source: {rotation: head, euler: YXZ, axis: 0}
    limits: [-1.0, 1.0]
  jaw:
    source: {blendshape: jawOpen, map: [[0, 0], [1, 0.4]]}
    limits: [0, 0.4]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.yaml"
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize(
    "old, new, key, problem",
    [
        ("blendshape: jawOpen", "blendshape: jawOpened", "joints.jaw.source.blendshape", "unknown channel"),
        ("rotation: head,", "rotation: nose,", "joints.pan.source.rotation", "unknown canonical joint"),
        ("limits: [-1.0, 1.0]", "limits: [1.0, -1.0]", "joints.pan.limits", "min 1.0 is above max -1.0"),
        ("map: [[0, 0], [1, 0.4]]", "map: [[0, 0], [0.5, 0.4], [0.4, 0.1]]", "joints.jaw.source.map", "not monotonic"),
        ("map: [[0, 0], [1, 0.4]]", "map: [[0, 0], [0.5, 0.4], [1, 0.1]]", "joints.jaw.source.map", "not monotonic"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    gain: fast", "joints.jaw.gain", "must be a number"),
        ("euler: YXZ", "euler: YXX", "joints.pan.source.euler", "permutation of XYZ"),
        (
            "limits: [0, 0.4]",
            "limits: [0, 0.4]\n    smoothing: {filter: kalman}",
            "joints.jaw.smoothing.filter",
            "unknown filter",
        ),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    speed: 3", "joints.jaw.speed", "unknown key"),
    ],
)
def test_validation_error_names_file_key_and_problem(tmp_path, old, new, key, problem):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(InputFileError) as info:
        load_profile(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert key in message and problem in message


def test_bad_yaml_and_missing_profile_are_user_errors(tmp_path):
    with pytest.raises(InputFileError, match="not valid YAML"):
        load_profile(write(tmp_path, "joints: [unclosed"))
    with pytest.raises(UserError, match="unknown robot profile 'no_such_robot'"):
        load_profile("no_such_robot")


def test_good_profile_builds_spec_and_passes_opaque_sections(tmp_path):
    text = GOOD + "backends:\n  dynamixel: {port: /dev/null, baud: 57600}\ngenerator:\n  procedural: {energy: 0.5}\n"
    profile = load_profile(write(tmp_path, text))
    assert profile.name == "tiny" and profile.spec.names == ("pan", "jaw")
    np.testing.assert_allclose(profile.spec.upper, [1.0, 0.4])
    assert profile.backend_options("dynamixel") == {"port": "/dev/null", "baud": 57600}
    assert profile.backend_options("maestro") == {}
    assert profile.generator_options("procedural") == {"energy": 0.5}
    assert profile.model_path is None


def test_from_dict_and_bare_name_resolve_model():
    profile = load_profile("servo_head")
    assert profile.model_path is not None and profile.model_path.name == "servo_head.xml"
    again = RobotProfile.from_dict(
        {"name": "x", "model": "servo_head.xml", "joints": {"j": {"source": {"translation": "y"}, "limits": [0, 1]}}},
        "inline",
    )
    assert again.model_path == profile.model_path


@pytest.mark.mujoco
def test_servo_head_profile_and_twin_share_joints_and_limits():
    import mujoco

    profile = load_profile("servo_head")
    assert profile.spec.names == ("neck_pan", "neck_tilt", "neck_roll", "jaw", "eye_pan", "eye_tilt", "eyelids")
    model = mujoco.MjModel.from_xml_path(str(profile.model_path))
    for i, name in enumerate(profile.spec.names):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert jid >= 0, name
        assert int(model.jnt_type[jid]) == int(mujoco.mjtJoint.mjJNT_HINGE)
        np.testing.assert_allclose(model.jnt_range[jid], [profile.spec.lower[i], profile.spec.upper[i]], err_msg=name)
        act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        assert act >= 0 and model.actuator_trnid[act, 0] == jid
        np.testing.assert_allclose(model.actuator_ctrlrange[act], model.jnt_range[jid], err_msg=name)
    # Every actuator drives a profile joint: one profile drives the whole twin.
    assert {model.actuator(a).name for a in range(model.nu)} == set(profile.spec.names)


@pytest.mark.mujoco
def test_humanoid_profile_drives_every_actuated_joint():
    import mujoco

    profile = load_profile("convo_humanoid")
    model = mujoco.MjModel.from_xml_path(str(profile.model_path))
    actuated = {model.joint(model.actuator_trnid[a, 0]).name for a in range(model.nu)}
    assert actuated == set(profile.spec.names)
    for i, name in enumerate(profile.spec.names):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert (
            model.jnt_range[jid][0] <= profile.spec.lower[i] + 1e-6
            and profile.spec.upper[i] <= model.jnt_range[jid][1] + 1e-6
        )


@pytest.mark.parametrize(
    "old, new, key, problem",
    [
        # defect 7: an infinite gain or weight passed, then every frame was refused and the head never moved
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    gain: .inf", "joints.jaw.gain", "must be a finite number"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    gain: 1e300", "joints.jaw.gain", "at most 1e+06 in size"),
        ("axis: 0}", "axis: 0, weight: .inf}", "joints.pan.source.weight", "must be a finite number"),
        ("axis: 0}", "axis: 0, weight: inf}", "joints.pan.source.weight", "must be a number"),
        ("[1, 0.4]]", "[1, .nan]]", "joints.jaw.source.map[1][1]", "must be a finite number"),
        ("limits: [0, 0.4]", "limits: [0, .inf]", "joints.jaw.limits[1]", "must be a finite number"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    offset: -.inf", "joints.jaw.offset", "must be a finite number"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    max_velocity: -.inf", "joints.jaw.max_velocity", "finite"),
        # defect 11: a repeated key or joint silently replaced the first
        ("  jaw:\n", "  pan:\n", "line 7", "duplicate key 'pan' (first at line 4)"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    limits: [0, 0.3]", "line 9", "duplicate key 'limits'"),
        ("limits: [0, 0.4]", "limits: [0, 0.4]\n    gian: 2", "joints.jaw.gian", "did you mean 'gain'?"),
        # issue 31 defect 15: an integer past Python's int-string limit (4300 digits) was a
        # ValueError traceback from the YAML reader; one below it but past a float's range was an
        # OverflowError from the checks
        (
            "limits: [0, 0.4]",
            "limits: [0, 0.4]\n    max_velocity: " + "9" * 5000,
            "line 10: max_velocity",
            "an integer of 5000 digits is too long",
        ),
        ("limits: [0, 0.4]", "limits: [0, " + "9" * 5000 + "]", "line 9", "an integer of 5000 digits is too long"),
        (
            "limits: [0, 0.4]",
            "limits: [0, 0.4]\n    max_velocity: " + "9" * 400,
            "joints.jaw.max_velocity",
            "at most 1e+06 in size, got an integer of 400 digits",
        ),
        (
            "limits: [0, 0.4]",
            "limits: [0, 0.4]\n    gain: -" + "9" * 400,
            "joints.jaw.gain",
            "got an integer of 400 digits",
        ),
    ],
)
def test_numbers_are_finite_and_keys_unique(tmp_path, old, new, key, problem):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(InputFileError) as info:
        load_profile(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    assert key in message and problem in message, message


def test_unlimited_velocity_is_still_allowed(tmp_path):
    path = write(tmp_path, GOOD.replace("limits: [0, 0.4]", "limits: [0, 0.4]\n    max_velocity: .inf"))
    assert load_profile(path).spec.max_velocity[1] == np.inf


@pytest.mark.mujoco
@pytest.mark.gymnasium
def test_ik_joint_listed_twice_is_refused():
    data = load_profile("gymnasium_humanoid")
    assert data.ik is not None
    raw = load_yaml_file(data.path)
    raw["ik"]["joints"].append(raw["ik"]["joints"][0])
    with pytest.raises(InputFileError, match=r"ik.joints\[\d+\]: joint '.+' is listed twice"):
        RobotProfile.from_dict(raw, data.path)
