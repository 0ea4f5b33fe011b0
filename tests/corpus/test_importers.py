"""Importers: small folders written in each corpus's own format import into valid corpora, joints
mapped by name, missing channels masked; bad source files are one line, exit 2, nothing written."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from convodrive.audio.source import AudioSource
from convodrive.corpus import Corpus
from convodrive.corpus.importers.common import HAND_JOINTS
from convodrive.corpus.stats import feature_stats
from convodrive.motion import representation, rotations
from convodrive.motion.channels import ARKIT_NAMES
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES
from tests.conftest import cli_in_process, run_cli
from tests.corpus import sources


def imported(kind: str, src: Path, out: Path, *extra: str) -> tuple[Corpus, str]:
    result = run_cli("corpus", "import", kind, str(src), "--out", str(out), *extra)
    assert result.returncode == 0, result.stderr
    corpus = Corpus.open(out)
    assert list(corpus.check()) == corpus.conversations
    assert "non-commercial" in corpus.manifest["licence"] or kind == "own"
    # Usable for training: windows sample, features encode, statistics fit over what is present.
    window = corpus.sample_windows("train", 150, 4, np.random.default_rng(0))[0]
    assert window.features().shape == (150, representation.FEATURE_DIM)
    assert np.all(np.isfinite(feature_stats(corpus, "train").std))
    return corpus, result.stdout


def fails(kind: str, src: Path, out: Path, *fragments: str, extra: tuple[str, ...] = ()) -> None:
    result = cli_in_process("corpus", "import", kind, str(src), "--out", str(out), *extra)
    assert result.returncode == 2, result.stdout + result.stderr
    line = result.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line, line
    for fragment in fragments:
        assert fragment in line, line
    assert not out.exists()  # nothing half-written


def root_matrix(pose: np.ndarray) -> np.ndarray:
    return rotations.axis_angle_to_matrix(pose[:, JOINT_INDEX["pelvis"]])


def assert_same_rotations(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(rotations.axis_angle_to_matrix(a), rotations.axis_angle_to_matrix(b), atol=2e-6)


# -- BEAT2 ---------------------------------------------------------------------------------------
@pytest.mark.espeak
def test_beat2_imports_joints_by_name_masks_the_face_and_keeps_the_splits(tmp_path: Path) -> None:
    src = tmp_path / "beat_english_v2.0.0"
    truth = sources.write_beat2(src)
    corpus, stdout = imported("beat2", src, tmp_path / "corpus")
    assert "beat2 corpus" in stdout and "52 face channels" in stdout
    assert corpus.speakers == ["lawrence", "scott"]
    for name in truth["names"]:
        conv = corpus.conversation(name)
        assert conv.missing_face == ARKIT_NAMES and conv.missing_joints == ()
        expected = {"train": "train", "test": "test", "val": "val", "additional": "train"}[truth["splits"][name]]
        assert conv.split == expected
        clip = corpus.takes(name)[0]
        assert clip.num_frames == 210 and np.all(clip.face == 0)
        src_pose = truth["poses"][name].astype(np.float32)
        for joint in ("left_elbow", "jaw", "right_eye_smplhf", "right_thumb2", "head"):
            assert_same_rotations(clip.pose[:, JOINT_INDEX[joint]], src_pose[:, JOINT_INDEX[joint]])
        # The Z-up root is turned upright: its average is the canonical facing.
        assert np.degrees(np.abs(rotations.matrix_to_axis_angle(root_matrix(clip.pose).mean(0))).max()) < 3
        # Voice activity from the audio: the speech at the start is heard, the tail is silent.
        assert clip.vad[15:45, 0].mean() > 0.8 and clip.vad[-15:, 0].max() == 0 and clip.vad[:, 1].max() == 0
    stats = feature_stats(corpus, "train")
    assert np.all(stats.count[representation.PARTS["arkit"]] == 0)
    assert np.all(stats.count[representation.PARTS["hands"]] > 0)


@pytest.mark.espeak
def test_beat2_audio_and_motion_of_different_lengths_is_one_line(tmp_path: Path) -> None:
    src = tmp_path / "beat"
    truth = sources.write_beat2(src, clips=2)
    wav = src / "wave16k" / f"{truth['names'][1]}.wav"
    audio, rate = sf.read(wav)
    sf.write(wav, audio[: len(audio) - 16000], rate, subtype="PCM_16")  # one second short
    fails("beat2", src, tmp_path / "out", f"{truth['names'][1]}.wav", "audio lasts 6.00 s", "has 210 frames")


@pytest.mark.espeak
def test_beat2_truncated_npz_and_missing_audio_are_one_line(tmp_path: Path) -> None:
    src = tmp_path / "beat"
    truth = sources.write_beat2(src, clips=2)
    npz = src / "smplxflame_30" / f"{truth['names'][0]}.npz"
    data = npz.read_bytes()
    npz.write_bytes(data[: len(data) // 3])
    fails("beat2", src, tmp_path / "out", npz.name, "not a readable BEAT2 .npz")
    npz.write_bytes(data)
    (src / "wave16k" / f"{truth['names'][1]}.wav").unlink()
    fails("beat2", src, tmp_path / "out", "no audio beside it")
    fails("beat2", tmp_path / "nowhere", tmp_path / "out", "no such folder")


# -- SHOW ----------------------------------------------------------------------------------------
@pytest.mark.espeak
def test_show_imports_through_the_restricted_unpickler_and_masks_hands_without_mano(tmp_path: Path) -> None:
    src = tmp_path / "ExpressiveWholeBodyDatasetReleaseV1.0"
    truth = sources.write_show(src)
    corpus, stdout = imported("show", src, tmp_path / "corpus")
    assert "no --mano components were given: masked" in stdout
    assert corpus.speakers == ["conan", "oliver"]
    hands = HAND_JOINTS["left"] + HAND_JOINTS["right"]
    for clip_name, data in truth["clips"].items():
        conv = corpus.conversation(clip_name)
        assert conv.missing_joints == tuple(j for j in JOINT_NAMES if j in hands)
        assert conv.missing_face == ARKIT_NAMES
        if sources.torch_losses() is not None:
            assert conv.metadata["dropped"] == ["losses_to_log.loss_total", "losses_to_log.loss_hand"]
        clip = corpus.takes(clip_name)[0]
        body = data["body_pose_axis"].reshape(-1, 21, 3)
        assert_same_rotations(clip.pose[:, JOINT_INDEX["left_elbow"]], body[:, JOINT_INDEX["left_elbow"] - 1])
        assert_same_rotations(clip.pose[:, JOINT_INDEX["jaw"]], data["jaw_pose"])
        assert np.all(clip.pose[:, [JOINT_INDEX[j] for j in hands]] == 0)
        # The camera-flipped root (about pi around X) is turned upright.
        assert np.degrees(np.abs(rotations.matrix_to_axis_angle(root_matrix(clip.pose).mean(0))).max()) < 3
        # The show's stereo soundtrack is the speaker's voice; the partner is silent.
        audio = corpus.audio(clip_name)
        assert np.abs(audio.other_voice).max() == 0 and np.abs(audio.self_voice).max() > 0.1
    # Clips of one video share a split.
    a, b = (corpus.conversation(c) for c in list(truth["clips"])[:2])
    assert a.group == b.group and a.split == b.split


@pytest.mark.parametrize("kind", ["npz", "json"])
@pytest.mark.espeak
def test_show_hands_from_mano_components(tmp_path: Path, kind: str) -> None:
    src = tmp_path / "show"
    truth = sources.write_show(src, with_torch=False)
    mano = tmp_path / ("SMPLX_NEUTRAL.npz" if kind == "npz" else "hand_component.json")
    comps = sources.write_mano(mano, kind=kind)
    corpus, _ = imported("show", src, tmp_path / "corpus", "--mano", str(mano))
    name, data = next(iter(truth["clips"].items()))
    conv = corpus.conversation(name)
    assert conv.missing_joints == ()
    clip = corpus.takes(name)[0]
    for side in ("left", "right"):
        expected = data[f"{side}_hand_pose"].astype(np.float64) @ comps[side][:12]
        if f"{side}_mean" in comps:
            expected = expected + comps[f"{side}_mean"]
        got = clip.pose[:, [JOINT_INDEX[j] for j in HAND_JOINTS[side]]]
        assert_same_rotations(got, expected.reshape(-1, 15, 3))


@pytest.mark.espeak
def test_show_pickles_that_ask_for_code_are_refused_and_never_run(tmp_path: Path) -> None:
    src = tmp_path / "show"
    sources.write_show(src, with_torch=False)
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self) -> tuple:
            return (__import__("os").system, (f"touch {marker}",))

    victim = next(src.rglob("*.pkl"))
    victim.write_bytes(pickle.dumps({"global_orient": Evil()}))
    fails("show", src, tmp_path / "out", victim.name, "refused: the pickle asks for posix.system")
    assert not marker.exists()
    victim.write_bytes(b"\x80\x04\x95")  # truncated
    fails("show", src, tmp_path / "out", victim.name, "pickle")


@pytest.mark.torch
def test_show_tensors_are_dropped_without_importing_torch(tmp_path: Path) -> None:
    src = tmp_path / "show"
    sources.write_show(src)
    pkl = next(src.rglob("*.pkl"))
    code = (
        "import sys; from pathlib import Path; from convodrive.corpus.importers.pickles import load_pickle, drop_skipped;"
        f"data, dropped = drop_skipped(load_pickle(Path({str(pkl)!r})));"
        "print(sorted(data)[:2], dropped, 'torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("['losses_to_log.loss_total', 'losses_to_log.loss_hand'] False")


@pytest.mark.espeak
def test_show_bad_mano_file_is_one_line(tmp_path: Path) -> None:
    src = tmp_path / "show"
    sources.write_show(src, with_torch=False)
    bad = tmp_path / "hands.json"
    bad.write_text(json.dumps({"left": [[0.0] * 44]}))
    fails("show", src, tmp_path / "out", "hands.json", extra=("--mano", str(bad)))


# -- Seamless Interaction ------------------------------------------------------------------------
@pytest.mark.espeak
def test_seamless_pairs_dyads_and_maps_smplh_by_name(tmp_path: Path) -> None:
    src = tmp_path / "seamless"
    truth = sources.write_seamless(src)
    corpus, _ = imported("seamless", src, tmp_path / "corpus")
    a, b, alone = (corpus.conversation(p) for p in truth["people"])
    assert a.group == b.group != alone.group and a.split == b.split
    assert a.metadata["partner"] == truth["people"][1] and alone.metadata["partner"] is None
    assert set(a.missing_joints) == {"jaw", "left_eye_smplhf", "right_eye_smplhf"}
    assert a.missing_face == ARKIT_NAMES
    for person in truth["people"]:
        clip = corpus.takes(person)[0]
        src_pose = truth["poses"][person].astype(np.float32)
        for k, joint in ((18, "left_elbow"), (22, "left_index1"), (51, "right_thumb3")):
            assert_same_rotations(clip.pose[:, JOINT_INDEX[joint]], src_pose[:, k])
        assert np.all(clip.pose[:, JOINT_INDEX["jaw"]] == 0)
    # Self is each participant's own microphone, the partner the other's; voice activity follows.
    own = AudioSource(src / f"{truth['people'][1]}.wav").read_all().self_voice
    audio_b = corpus.audio(truth["people"][1])
    np.testing.assert_allclose(audio_b.self_voice, own, atol=2 / 32768)
    np.testing.assert_allclose(corpus.audio(truth["people"][0]).other_voice, own, atol=2 / 32768)
    clip_a = corpus.takes(truth["people"][0])[0]
    assert clip_a.vad[15:60, 0].mean() > 0.8 and clip_a.vad[15:60, 1].mean() < 0.1  # A talks first
    assert clip_a.vad[125:170, 1].mean() > 0.8  # then B, heard on A's partner channel
    assert np.abs(corpus.audio(truth["people"][2]).other_voice).max() == 0  # no partner: silent


@pytest.mark.espeak
def test_seamless_npz_without_pose_keys_is_one_line_naming_what_it_has(tmp_path: Path) -> None:
    src = tmp_path / "seamless"
    truth = sources.write_seamless(src)
    np.savez(src / f"{truth['people'][0]}.npz", something=np.zeros((10, 3)))
    fails("seamless", src, tmp_path / "out", "no SMPL-H pose arrays", "it has something")


# -- own recordings -------------------------------------------------------------------------------
@pytest.mark.espeak
def test_own_recordings_npz_bvh_and_livelink_merge_and_mask(tmp_path: Path) -> None:
    src = tmp_path / "recordings"
    clips = sources.write_own(src)
    corpus, stdout = imported("own", src, tmp_path / "corpus")
    assert corpus.speakers == ["alice", "bob"] and corpus.manifest["licence"] == "that of your own recordings"
    # A convodrive clip holds everything: nothing masked, values as saved.
    one = corpus.conversation("take1")
    assert one.missing_joints == () and one.missing_face == ()
    got = corpus.takes("take1")[0]
    np.testing.assert_allclose(got.pose, clips["take1"].pose, atol=1e-6)
    np.testing.assert_allclose(got.face, clips["take1"].face, atol=1e-6)
    assert got.vad[15:45, 0].mean() > 0.8 and got.vad[120:150, 1].mean() > 0.8  # partner on channel 1
    # A 60 fps BVH from a suit and a Live Link take from a phone merge: body from one, face from the other.
    two = corpus.conversation("take2")
    assert (
        two.missing_joints == ()
        and two.missing_face == ()
        and two.metadata["motion_files"]
        == [
            "take2.bvh",
            "take2.csv",
        ]
    )
    got = corpus.takes("take2")[0]
    assert got.num_frames == 210
    body = [JOINT_INDEX[j] for j in ("left_elbow", "spine2", "right_index2")]
    assert_close_rotations(got.pose[:, body], clips["take2"].pose[::2][:, body], atol=1e-3)  # 60 -> 30 fps
    np.testing.assert_allclose(got.face, clips["take2_face"].face, atol=1e-5)
    # A phone alone: face, head, eyes and jaw; the body is masked.
    three = corpus.conversation("take3")
    assert set(JOINT_NAMES) - set(three.missing_joints) == {"head", "left_eye_smplhf", "right_eye_smplhf", "jaw"}
    assert three.missing_face == ()
    mask = corpus.window("take3", 0, 0, 30).feature_mask()
    assert mask[representation.PARTS["arkit"]].all() and not mask[representation.PARTS["upper"]].any()


def assert_close_rotations(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    np.testing.assert_allclose(rotations.axis_angle_to_matrix(a), rotations.axis_angle_to_matrix(b), atol=atol)


@pytest.mark.espeak
def test_own_wav_without_motion_and_motion_of_another_length(tmp_path: Path) -> None:
    src = tmp_path / "recordings"
    sources.write_own(src)
    (src / "bob" / "take3.csv").unlink()
    fails("own", src, tmp_path / "out", "take3.wav", "no motion beside it")
    sources.write_own(tmp_path / "again")
    audio, rate = sf.read(tmp_path / "again" / "alice" / "take1.wav")
    sf.write(tmp_path / "again" / "alice" / "take1.wav", audio[: rate * 5], rate, subtype="PCM_16")
    fails("own", tmp_path / "again", tmp_path / "out", "take1.wav", "audio lasts 5.00 s", "take1.npz has 210 frames")
