"""Small corpora in the formats users bring (BEAT2, SHOW, Seamless Interaction, their own), written
the way those data sets write them, for the importer tests (and for tests that train on imports).

Every writer returns the folder and what it put there, so tests can compare the import with the
source: the rotations each joint was given, the audio each file holds.
"""

from __future__ import annotations

import json
import pickle
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import soundfile as sf
from scipy.signal import resample_poly

from convodrive.audio.synth import speak
from convodrive.motion import rotations
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_NAMES

SECONDS = 7.0
SENTENCES = (
    "We tried the new route this morning and it was much faster.",
    "I think the robot should look at you when you talk to it.",
    "The meeting went on for hours, and nobody knew the plan.",
    "My sister moved to a small town near the coast last year.",
)


def speech(seed: int, seconds: float = SECONDS, rate: int = 16000) -> np.ndarray:
    """``seconds`` of mono audio: espeak-ng speech from 0.3 s, the last 1.2 s silent."""
    rng = np.random.default_rng(seed)
    out = np.zeros(int(seconds * 16000), np.float32)
    t, stop = int(0.3 * 16000), len(out) - int(1.2 * 16000)
    for k in range(2):
        voice = speak(SENTENCES[(seed + k) % len(SENTENCES)], voice="en-us+m3" if seed % 2 else "en-us+f2")
        voice = 0.5 * voice[: max(0, stop - t)] / max(float(np.abs(voice).max()), 1e-9)
        out[t : t + len(voice)] += voice
        t += len(voice) + int(0.6 * 16000)
    out += rng.normal(0, 1e-3, len(out)).astype(np.float32)
    if rate != 16000:
        r = Fraction(rate, 16000)
        out = resample_poly(out, r.numerator, r.denominator).astype(np.float32)
    return out


def random_axis_angles(rng: np.random.Generator, frames: int, joints: int, scale: float = 0.5) -> np.ndarray:
    """Smooth random rotations (T, joints, 3)."""
    base = rng.normal(scale=scale, size=(joints, 3))
    wobble = rng.normal(scale=0.1, size=(joints, 3)) * np.sin(np.linspace(0, 6, frames))[:, None, None]
    return base[None] + wobble


def write_beat2(folder: Path, clips: int = 3, seed: int = 0) -> dict[str, Any]:
    """``smplxflame_30/*.npz`` + ``wave16k/*.wav`` + ``train_test_split.csv``; Z-up roots as MoSh++ fits have."""
    rng = np.random.default_rng(seed)
    (folder / "smplxflame_30").mkdir(parents=True)
    (folder / "wave16k").mkdir()
    names = [f"{2 + (i % 2) * 2}_{'scott' if i % 2 == 0 else 'lawrence'}_0_{i + 1}_{i + 1}" for i in range(clips)]
    frames = int(SECONDS * 30)
    poses = {}
    for i, name in enumerate(names):
        pose = random_axis_angles(rng, frames, 55)
        z_up = rotations.matrix_to_axis_angle(rotations.euler_to_matrix(np.array([-np.pi / 2, 0.0, 0.3]), "XYZ"))
        pose[:, 0] = z_up + rng.normal(scale=0.02, size=(frames, 3))
        poses[name] = pose
        np.savez(
            folder / "smplxflame_30" / f"{name}.npz",
            poses=pose.reshape(frames, 165).astype(np.float32),
            trans=rng.normal(scale=0.05, size=(frames, 3)).astype(np.float32),
            expressions=rng.normal(size=(frames, 100)).astype(np.float32),
            betas=np.zeros(300, np.float32),
            model=np.array("smplx2020"),
            gender=np.array("neutral"),
            mocap_frame_rate=np.array(30),
        )
        sf.write(folder / "wave16k" / f"{name}.wav", speech(i), 16000, subtype="PCM_16")
    kinds = ["train", "test", "val", "additional"]
    rows = ["id,type"] + [f"{n},{kinds[i % len(kinds)]}" for i, n in enumerate(names)]
    (folder / "train_test_split.csv").write_text("\n".join(rows) + "\n")
    return {"names": names, "poses": poses, "splits": {n: kinds[i % len(kinds)] for i, n in enumerate(names)}}


def torch_losses() -> dict[str, Any] | None:
    """Fitting losses as torch tensors, as SHOW's ``losses_to_log`` holds them (None without torch)."""
    try:
        import torch
    except ImportError:
        return None
    return {"loss_total": torch.tensor(1.25), "loss_hand": torch.tensor([0.5, 0.25])}


def write_show(folder: Path, seed: int = 0, with_torch: bool = True) -> dict[str, Any]:
    """``<speaker>/<video>/<clip>/<clip>.pkl`` + 22 kHz stereo ``.wav``, as SHOW's release has them:
    camera-flipped roots, 12 hand PCA coefficients, FLAME expressions and torch-tensor losses."""
    rng = np.random.default_rng(seed)
    layout = [
        ("oliver", "Show_A-xyz.webm", "100-00_00_01-00_00_08"),
        ("oliver", "Show_A-xyz.webm", "101-00_00_09-00_00_16"),
        ("conan", "Show_B-abc.webm", "200-00_01_00-00_01_07"),
    ]
    frames = int(SECONDS * 30)
    losses = torch_losses() if with_torch else None
    clips = {}
    for i, (speaker, video, clip) in enumerate(layout):
        where = folder / speaker / video / clip
        where.mkdir(parents=True)
        body = random_axis_angles(rng, frames, 21)
        data = {
            "betas": np.zeros((1, 300), np.float32),
            "expression": rng.normal(size=(frames, 100)).astype(np.float32),
            "jaw_pose": np.abs(random_axis_angles(rng, frames, 1, 0.2)[:, 0]).astype(np.float32),
            "leye_pose": random_axis_angles(rng, frames, 1, 0.1)[:, 0].astype(np.float32),
            "reye_pose": random_axis_angles(rng, frames, 1, 0.1)[:, 0].astype(np.float32),
            "global_orient": (
                np.array([3.0747, -0.0158, -0.0152]) + rng.normal(scale=0.01, size=(frames, 1, 3))
            ).astype(np.float32),
            "body_pose_axis": body.reshape(frames, 63).astype(np.float32),
            "left_hand_pose": rng.normal(size=(frames, 12)).astype(np.float32),
            "right_hand_pose": rng.normal(size=(frames, 12)).astype(np.float32),
            "transl": rng.normal(scale=0.01, size=(frames, 3)).astype(np.float32),
            "pose_embedding": rng.normal(size=(frames, 32)).astype(np.float32),
            "camera_transl": np.zeros((1, 3), np.float32),
            "width": 1280,
            "height": 720,
            "batch_size": frames,
        }
        raw = pickle.dumps({**data, "losses_to_log": losses} if losses is not None else data)
        (where / f"{clip}.pkl").write_bytes(raw)
        mono = speech(10 + i, rate=22000)
        sf.write(where / f"{clip}.wav", np.stack([mono, 0.9 * mono], 1), 22000, subtype="PCM_16")
        clips[clip] = data
    return {"clips": clips, "speakers": {"oliver", "conan"}}


def write_mano(path: Path, seed: int = 0, kind: str = "npz") -> dict[str, np.ndarray]:
    """Hand PCA components: an SMPL-X-model-like ``.npz`` or TalkSHOW's ``hand_component.json``."""
    rng = np.random.default_rng(seed)
    comps = {side: np.linalg.qr(rng.normal(size=(45, 45)))[0] for side in ("left", "right")}
    means = {side: rng.normal(scale=0.1, size=45) for side in ("left", "right")}
    if kind == "npz":
        np.savez(
            path,
            hands_componentsl=comps["left"],
            hands_componentsr=comps["right"],
            hands_meanl=means["left"],
            hands_meanr=means["right"],
            shapedirs=np.zeros((3, 3)),
        )
        return {
            "left": comps["left"],
            "right": comps["right"],
            "left_mean": means["left"],
            "right_mean": means["right"],
        }
    path.write_text(json.dumps({"left": comps["left"].tolist(), "right": comps["right"].tolist()}))
    return {"left": comps["left"], "right": comps["right"]}


SMPLH_BODY = JOINT_NAMES[:22]


def write_seamless(folder: Path, seed: int = 0) -> dict[str, Any]:
    """One dyad (two participants) and one participant whose partner is missing; 48 kHz mono WAVs,
    SMPL-H arrays under the names of ``seamless.KEYS`` (split keys for some, ``poses`` for one)."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    frames = int(SECONDS * 30)
    people = ["V00_S0001_I00000001_P0001", "V00_S0001_I00000001_P0002", "V01_S0002_I00000007_P0003"]
    poses = {}
    for i, stem in enumerate(people):
        pose = random_axis_angles(rng, frames, 52)
        poses[stem] = pose
        flat = pose.reshape(frames, 156).astype(np.float32)
        if i < 2:
            arrays = {
                "smplh:global_orient": flat[:, :3],
                "smplh:body_pose": flat[:, 3:66],
                "smplh:left_hand_pose": flat[:, 66:111],
                "smplh:right_hand_pose": flat[:, 111:156],
                "smplh:translation": rng.normal(scale=0.02, size=(frames, 3)).astype(np.float32),
                "movement:expression": rng.normal(size=(frames, 128)).astype(np.float32),
                "keypoints": rng.normal(size=(frames, 133, 3)).astype(np.float32),
            }
        else:  # at 60 fps: every frame twice, so the 30 fps import must equal the 30 fps source
            arrays = {
                "poses": np.repeat(flat, 2, axis=0),
                "trans": np.zeros((2 * frames, 3), np.float32),
                "fps": np.array(60.0),
            }
        np.savez(folder / f"{stem}.npz", **arrays)
        # The dyad's two microphones: each person speaks in turn (one first, the other after).
        audio = np.zeros(int(SECONDS * 48000), np.float32)
        voice = speech(20 + i, seconds=3.2, rate=48000)
        offset = 0 if i != 1 else int(3.5 * 48000)
        audio[offset : offset + len(voice)] = voice[: len(audio) - offset]
        sf.write(folder / f"{stem}.wav", audio, 48000, subtype="PCM_16")
        (folder / f"{stem}.json").write_text(json.dumps({"id": stem}))
    return {"people": people, "poses": poses}


def random_clip(rng: np.random.Generator, seconds: float, fps: float = 30.0) -> MotionClip:
    """Smooth random motion of every joint and face channel at ``fps``."""
    frames = int(round(seconds * fps))
    face = 0.5 + 0.4 * np.sin(np.linspace(0, 8, frames)[:, None] + rng.uniform(0, 6, 52))
    return MotionClip(
        pose=(0.6 * random_axis_angles(rng, frames, 55, 0.4)).astype(np.float32),
        translation=np.zeros((frames, 3), np.float32),
        face=face.astype(np.float32),
        vad=np.zeros((frames, 2), np.float32),
        state=np.zeros(frames, np.int8),
        fps=fps,
    )


def write_own(folder: Path, seed: int = 0) -> dict[str, Any]:
    """What a user records: ``alice/take1`` (stereo WAV + convodrive .npz), ``alice/take2`` (mono WAV
    + a 60 fps BVH from a suit + a Live Link Face CSV from a phone), ``bob/take3`` (WAV + CSV only)."""
    from convodrive.motion.bvh import write_bvh
    from convodrive.motion.livelink import write_livelink_csv
    from convodrive.motion.npz import save_clip

    rng = np.random.default_rng(seed)
    for who in ("alice", "bob"):
        (folder / who).mkdir(parents=True, exist_ok=True)
    clips = {
        "take1": random_clip(rng, SECONDS),
        "take2": random_clip(rng, SECONDS, fps=60.0),
        "take2_face": random_clip(rng, SECONDS),
        "take3": random_clip(rng, SECONDS),
    }
    save_clip(clips["take1"], folder / "alice" / "take1.npz")
    write_bvh(clips["take2"], folder / "alice" / "take2.bvh")
    write_livelink_csv(clips["take2_face"], folder / "alice" / "take2.csv")
    write_livelink_csv(clips["take3"], folder / "bob" / "take3.csv")
    partner = np.roll(speech(31), int(3.5 * 16000))
    sf.write(folder / "alice" / "take1.wav", np.stack([speech(30), partner], 1), 16000, subtype="PCM_16")
    sf.write(folder / "alice" / "take2.wav", speech(32, rate=44100), 44100, subtype="PCM_16")
    sf.write(folder / "bob" / "take3.wav", speech(33), 16000, subtype="PCM_16")
    return clips
