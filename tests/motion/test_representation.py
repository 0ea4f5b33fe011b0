"""The learning representation: round trips, layout, masks and normalisation statistics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from convodrive.motion import representation as rep
from convodrive.motion import rotations as rot
from convodrive.motion.channels import ARKIT_NAMES, ConversationState
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX, NUM_JOINTS
from convodrive.plumbing.errors import InputFileError


def random_rotations(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Axis-angles with angles spread over [0, pi], a tenth of them within 1e-3 of pi."""
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = rng.uniform(0.0, np.pi, size=shape)
    near_pi = rng.random(shape) < 0.1
    angle = np.where(near_pi, np.pi - rng.uniform(0.0, 1e-3, size=shape), angle)
    return axis * angle[..., None]


def geodesic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between axis-angles a and b, precise near zero."""
    rel = np.swapaxes(rot.axis_angle_to_matrix(a), -1, -2) @ rot.axis_angle_to_matrix(b)
    q = rot.matrix_to_quat(rel)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def random_clip(rng: np.random.Generator, frames: int = 64) -> MotionClip:
    vad = (rng.random((frames, 2)) > 0.5).astype(np.float32)
    return MotionClip(
        pose=random_rotations(rng, (frames, NUM_JOINTS)).astype(np.float32),
        translation=rng.normal(size=(frames, 3)).astype(np.float32),
        face=rng.random((frames, len(ARKIT_NAMES))).astype(np.float32),
        vad=vad,
        state=np.array([ConversationState.from_activity(bool(s), bool(o)) for s, o in vad > 0.5], np.int8),
    )


def test_layout_is_contiguous_named_and_separable() -> None:
    assert rep.FEATURE_DIM == 330 == len(rep.feature_names())
    assert rep.GROUPS["face"] == slice(0, 70) and rep.GROUPS["body"] == slice(70, 328)
    assert rep.GROUPS["vad"] == slice(328, 330)
    names = rep.feature_names()
    assert names[rep.PARTS["arkit"]][17] == "arkit.jawOpen"
    assert names[rep.PARTS["jaw"].start] == "jaw.jaw.0" and names[-2:] == ["vad.self", "vad.other"]
    assert len(rep.PART_JOINTS["hands"]) == 30 and len(set(rep.COVERED_JOINTS)) == 46
    # The layout travels as JSON and says which 6D convention it uses.
    data = json.loads(json.dumps(rep.layout()))
    assert data["parts"]["hands"] == [rep.PARTS["hands"].start, rep.PARTS["hands"].stop]
    assert "rows" in data["rotation"]


def test_round_trip_is_exact_on_covered_joints_including_near_pi() -> None:
    rng = np.random.default_rng(0)
    clip = random_clip(rng, frames=400)
    features = rep.encode_clip(clip)
    assert features.dtype == np.float32 and features.shape == (400, rep.FEATURE_DIM)
    back = rep.decode(features, base=clip)
    covered = [JOINT_INDEX[j] for j in rep.COVERED_JOINTS]
    err = geodesic(clip.pose[:, covered], back.pose[:, covered])
    assert err.max() < 1e-5
    # Away from pi, where axis-angle is unique, the vectors themselves agree.
    angle = np.linalg.norm(clip.pose[:, covered], axis=-1)
    clear = angle < np.pi - 1e-2
    assert clear.sum() > 1000
    np.testing.assert_allclose(back.pose[:, covered][clear], clip.pose[:, covered][clear], atol=1e-5)
    np.testing.assert_allclose(back.face, clip.face, atol=1e-7)
    np.testing.assert_array_equal(back.vad, clip.vad)
    np.testing.assert_array_equal(back.state, clip.state)
    # Uncovered joints and the translation come from the base clip.
    uncovered = [i for i in range(NUM_JOINTS) if i not in covered]
    np.testing.assert_array_equal(back.pose[:, uncovered], clip.pose[:, uncovered])
    np.testing.assert_array_equal(back.translation, clip.translation)


def test_encode_handles_batches_and_decode_without_base_rests() -> None:
    rng = np.random.default_rng(1)
    pose = random_rotations(rng, (3, 10, NUM_JOINTS))
    face = rng.random((3, 10, 52))
    vad = rng.random((3, 10, 2))
    batched = rep.encode(pose, face, vad)
    assert batched.shape == (3, 10, rep.FEATURE_DIM)
    np.testing.assert_array_equal(batched[1], rep.encode(pose[1], face[1], vad[1]))
    clip = rep.decode(batched[0])
    assert clip.num_frames == 10 and np.all(clip.pose[:, JOINT_INDEX["pelvis"]] == 0)
    assert np.all(clip.translation == 0)


def test_decode_turns_any_network_output_into_valid_motion() -> None:
    rng = np.random.default_rng(2)
    raw = rng.normal(scale=2.0, size=(50, rep.FEATURE_DIM)).astype(np.float32)
    clip = rep.decode(raw)
    assert np.all(np.isfinite(clip.pose))
    assert clip.face.min() >= 0 and clip.face.max() <= 1 and clip.vad.min() >= 0 and clip.vad.max() <= 1
    # Re-encoding gives orthonormal 6D rows: decode projected the raw vectors onto rotations.
    again = rep.encode_clip(clip)
    rows = again[:, rep.PARTS["upper"]].reshape(50, -1, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(rows, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.sum(rows[..., 0, :] * rows[..., 1, :], axis=-1), 0.0, atol=1e-5)


def test_feature_mask_follows_joint_and_channel_masks() -> None:
    joints = np.ones(NUM_JOINTS, bool)
    joints[[JOINT_INDEX[j] for j in rep.PART_JOINTS["hands"]]] = False
    mask = rep.feature_mask(joints=joints, face=np.zeros(52, bool))
    assert not mask[rep.PARTS["hands"]].any() and not mask[rep.PARTS["arkit"]].any()
    assert mask[rep.PARTS["upper"]].all() and mask[rep.PARTS["jaw"]].all() and mask[rep.PARTS["vad"]].all()
    joints[JOINT_INDEX["left_elbow"]] = False
    mask = rep.feature_mask(joints=joints)
    names = np.array(rep.feature_names())
    assert set(names[~mask & (np.arange(rep.FEATURE_DIM) < rep.PARTS["hands"].start)]) == {
        f"upper.left_elbow.{k}" for k in range(6)
    }
    with pytest.raises(ValueError):
        rep.feature_mask(joints=np.ones(3, bool))


def test_stats_match_numpy_skip_masked_columns_and_survive_json(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    parts = [rep.encode_clip(random_clip(rng, frames=n)) for n in (100, 37, 260)]
    parts = [p + 1000.0 * (p.dtype.type(1)) for p in parts]  # a large offset: the running shift keeps precision
    full = rep.feature_mask()
    no_face = rep.feature_mask(face=np.zeros(52, bool))
    stats = rep.FeatureStats.fit([(parts[0], full), (parts[1], no_face), (parts[2], full)])
    both = np.concatenate([parts[0], parts[2]]).astype(np.float64)
    arkit = rep.PARTS["arkit"]
    np.testing.assert_allclose(stats.mean[arkit], both[:, arkit].mean(0), rtol=1e-6)
    np.testing.assert_allclose(stats.std[arkit], both[:, arkit].std(0), rtol=1e-3)
    everything = np.concatenate(parts).astype(np.float64)
    body = rep.GROUPS["body"]
    np.testing.assert_allclose(stats.mean[body], everything[:, body].mean(0), rtol=1e-6)
    assert stats.count[arkit.start] == 360 and stats.count[body.start] == 397
    normalised = stats.normalise(parts[2])
    np.testing.assert_allclose(stats.denormalise(normalised), parts[2], rtol=1e-6)
    path = stats.save(tmp_path / "stats.json")
    again = rep.FeatureStats.load(path)
    np.testing.assert_array_equal(again.mean, stats.mean)
    np.testing.assert_array_equal(again.std, stats.std)


def test_stats_of_constant_and_unseen_columns_keep_unit_spread() -> None:
    features = np.zeros((20, rep.FEATURE_DIM), np.float32)
    features[:, 0] = 3.0
    mask = rep.feature_mask(face=np.zeros(52, bool))
    stats = rep.FeatureStats.fit([(features, mask)])
    assert stats.mean[0] == 3.0 and stats.std[0] == 1.0
    arkit = rep.PARTS["arkit"]
    assert np.all(stats.count[arkit] == 0) and np.all(stats.std[arkit] == 1.0) and np.all(stats.mean[arkit] == 0)
    assert np.all(np.isfinite(stats.normalise(features)))


def test_a_channel_the_data_never_moved_decodes_to_its_constant() -> None:
    """A network's error on a constant channel comes out at unit scale (its std is floored to 1):
    in the corpus the fingers bend about one axis only, and noise on the others twisted them
    sideways. Denormalising pins constant channels; moving ones and unseen ones pass through."""
    rng = np.random.default_rng(8)
    clip = MotionClip.neutral(60)
    clip.pose[:, JOINT_INDEX["left_index1"], 2] = rng.uniform(0.0, 1.2, 60)  # bends about z only
    no_hands_face = rep.feature_mask(face=np.zeros(52, bool))
    stats = rep.FeatureStats.fit([(rep.encode_clip(clip), rep.feature_mask())])
    names = rep.feature_names()
    index = {n: i for i, n in enumerate(names)}
    assert not stats.constant[index["hands.left_index1.0"]]  # cos of the bend: moves
    assert stats.constant[index["hands.left_index1.2"]] and stats.constant[index["hands.left_index1.5"]]
    noisy = rng.normal(0.0, 0.3, (60, rep.FEATURE_DIM)).astype(np.float32)  # a network's error
    out = stats.denormalise(noisy)
    constant = stats.constant
    np.testing.assert_array_equal(out[:, constant], np.broadcast_to(stats.mean[constant], (60, constant.sum())))
    np.testing.assert_allclose(out[:, ~constant], noisy[:, ~constant] * stats.std[~constant] + stats.mean[~constant])
    finger = rep.decode(out).pose[:, JOINT_INDEX["left_index1"]]
    sideways = np.abs(finger[:, :2]).max()
    assert sideways < 1e-6, sideways  # no twist about the axes the data never used
    # Columns no data covered are left alone: pinning a whole rotation to its mean 0 would not decode.
    unseen = rep.FeatureStats.fit([(rep.encode_clip(clip), no_hands_face)])
    assert not unseen.constant[rep.PARTS["arkit"]].any()


def test_stats_from_a_model_folder_s_arrays_with_or_without_counts() -> None:
    features = rep.encode_clip(MotionClip.neutral(20))  # every rotation the identity: seen, constant
    mask = rep.feature_mask(joints=np.array([j not in ("left_elbow",) for j in rep.JOINT_NAMES]))
    stats = rep.FeatureStats.fit([(features, mask)])
    saved = {"mean": stats.mean, "std": stats.std, "count": stats.count}
    np.testing.assert_array_equal(rep.FeatureStats.from_arrays(saved).count, stats.count)
    inferred = rep.FeatureStats.from_arrays({"mean": stats.mean, "std": stats.std})  # an older export
    elbow = [i for i, n in enumerate(rep.feature_names()) if n.startswith("upper.left_elbow.")]
    assert np.all(inferred.count[elbow] == 0) and not inferred.constant[elbow].any()
    others = np.setdiff1d(np.arange(rep.FEATURE_DIM), elbow)
    assert np.all(inferred.count[others] > 0)
    np.testing.assert_array_equal(inferred.constant[others], stats.constant[others])


def test_bad_statistics_files_are_one_line_errors(tmp_path: Path) -> None:
    bad = tmp_path / "stats.json"
    bad.write_text("{not json")
    with pytest.raises(InputFileError, match="stats.json: not readable JSON"):
        rep.FeatureStats.load(bad)
    stats = rep.FeatureStats.fit([(np.zeros((4, rep.FEATURE_DIM)), rep.feature_mask())]).to_json()
    stats["mean"] = stats["mean"][:-1]
    bad.write_text(json.dumps(stats))
    with pytest.raises(InputFileError, match="330 values"):
        rep.FeatureStats.load(bad)
    with pytest.raises(InputFileError, match="no such file"):
        rep.FeatureStats.load(tmp_path / "missing.json")
