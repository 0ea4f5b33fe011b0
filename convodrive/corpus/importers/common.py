"""What every importer shares: body-model joint tables, root normalisation, audio and length checks.

Joints map onto the canonical skeleton by name, never by position: each table below lists a
body model's joints in its own order, and ``JOINT_INDEX`` places them. The canonical skeleton uses
SMPL-X's names, and its rest pose is a T-pose like SMPL-X's and SMPL-H's, so their local joint
rotations carry over unchanged.
"""

from __future__ import annotations

import dataclasses
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.audio.analysis import voice_activity
from convodrive.audio.source import AudioSource, ChannelMap, DyadicAudio, motion_frames_for, probe_audio
from convodrive.corpus.writer import Recording, quantise
from convodrive.motion import rotations
from convodrive.motion.channels import ARKIT_NAMES, ConversationState
from convodrive.motion.clip import MotionClip
from convodrive.motion.resample import resample
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS
from convodrive.plumbing.errors import InputFileError

_FINGERS = tuple(f"{finger}{k}" for finger in ("index", "middle", "pinky", "ring", "thumb") for k in (1, 2, 3))
SMPLX_JOINTS: tuple[str, ...] = JOINT_NAMES
"""SMPL-X's 55 joints in its own order (the canonical skeleton took its names and order from it)."""
SMPLH_JOINTS: tuple[str, ...] = (
    JOINT_NAMES[:22] + tuple(f"left_{f}" for f in _FINGERS) + tuple(f"right_{f}" for f in _FINGERS)
)
"""SMPL-H's 52 joints: SMPL-X's body without jaw and eyes, then the 15 joints of each hand."""
HAND_JOINTS: dict[str, tuple[str, ...]] = {side: tuple(f"{side}_{f}" for f in _FINGERS) for side in ("left", "right")}

MAX_ARRAY_BYTES = 1 << 30
"""A source array larger than this (1 GiB) is refused: a clip's motion is a few MB; a ``.npy``
header can claim any shape, and loading it first would allocate what it claims."""
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}

ALL_FACE = tuple(ARKIT_NAMES)
"""A source with no ARKit channels (FLAME expressions, or no face at all) lists these as missing."""
LENGTH_TOLERANCE_FRAMES = 6
"""Audio and motion may differ by this much (0.2 s: recorders start and stop a little apart);
the motion is then cut or its last frame held to the audio's length. More is an error."""


def pose_from_joints(values: np.ndarray, names: tuple[str, ...], source: Path) -> tuple[np.ndarray, tuple[str, ...]]:
    """Canonical (T, 55, 3) poses from (T, len(names) * 3) axis-angles of the named joints, and
    the canonical joints the source does not have."""
    values = np.asarray(values, np.float64)
    if values.ndim != 2 or values.shape[1] != 3 * len(names):
        raise InputFileError(source, f"pose array has shape {values.shape}, expected (frames, {3 * len(names)})")
    if len(values) == 0:
        raise InputFileError(source, "holds no frames")
    if not np.all(np.isfinite(values)):
        raise InputFileError(source, "pose array holds NaN or infinite values")
    pose = np.zeros((len(values), NUM_JOINTS, 3), np.float64)
    pose[:, [JOINT_INDEX[n] for n in names]] = values.reshape(len(values), len(names), 3)
    missing = tuple(n for n in JOINT_NAMES if n not in set(names))
    return pose, missing


def read_numeric_npz(path: Path, what: str = ".npz") -> tuple[dict[str, np.ndarray], list[str]]:
    """The numeric arrays of the ``.npz`` (``what``, for messages) at ``path`` (strings and objects are left unread) and
    the names of all its entries. Each ``.npy`` header is read first: an array claiming more than
    its entry holds or than ``MAX_ARRAY_BYTES`` is an ``InputFileError``, never an allocation."""
    arrays: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            infos = [i for i in zf.infolist() if i.filename.endswith(".npy")]
            for info in infos:
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version not in _HEADER_READERS:
                        raise ValueError(f".npy version {version}")
                    shape, fortran, dtype = _HEADER_READERS[version](fh)
                    if dtype.kind not in "biuf":
                        continue
                    claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    name = info.filename[: -len(".npy")]
                    if claimed > min(info.file_size, MAX_ARRAY_BYTES):
                        raise InputFileError(
                            path,
                            f"array {name!r} claims shape {shape} ({claimed} bytes) but its entry holds {info.file_size}"
                            if claimed > info.file_size
                            else f"array {name!r} of shape {shape} is larger than {MAX_ARRAY_BYTES >> 30} GiB",
                        )
                    data = np.frombuffer(bytearray(fh.read(claimed)), dtype)
                    arrays[name] = data.reshape(shape, order="F" if fortran else "C")
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise InputFileError(path, f"not a readable {what} ({exc.__class__.__name__})") from None
    return arrays, [i.filename[: -len(".npy")] for i in infos]


def upright_root(pose: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Re-express the root so that its average orientation is the canonical one (upright, facing +Z).

    Data sets disagree on the world frame (Z up for MoSh++ fits, camera coordinates with Y down for
    SHOW's monocular fits); conversation is filmed or captured facing the person, so the average
    root orientation is "facing forward" in every one of them. The root translation turns the same
    way and is measured from its mean.
    """
    root = rotations.axis_angle_to_quat(pose[:, 0])
    root = np.where(np.sum(root * root[:1], axis=-1, keepdims=True) < 0, -root, root)
    mean = root.mean(axis=0)
    fix = rotations.quat_to_matrix(mean * np.array([1.0, -1.0, -1.0, -1.0]))  # the inverse of the mean
    out = pose.copy()
    out[:, 0] = rotations.matrix_to_axis_angle(fix @ rotations.axis_angle_to_matrix(pose[:, 0]))
    moved = np.asarray(translation, np.float64) - np.mean(translation, axis=0)
    return out, moved @ fix.T


def read_speaker_audio(path: Path) -> DyadicAudio:
    """One speaker's recording at 16 kHz as self, the partner silent. A stereo file is two
    microphones of the same scene (a TV show, a lavalier pair), so its channels are mixed."""
    if probe_audio(path).channels == 1:
        return AudioSource(path).read_all()
    both = AudioSource(path, ChannelMap(0, 1)).read_all()
    return DyadicAudio(0.5 * (both.self_voice + both.other_voice), np.zeros_like(both.self_voice), str(path))


def fit_length(clip: MotionClip, frames: int, audio_path: Path, motion_path: Path) -> MotionClip:
    """The clip cut, or its last frame held, to ``frames``; an ``InputFileError`` naming the audio
    when the two disagree by more than ``LENGTH_TOLERANCE_FRAMES``."""
    if abs(clip.num_frames - frames) > LENGTH_TOLERANCE_FRAMES:
        raise InputFileError(
            audio_path,
            f"audio lasts {frames / FPS:.2f} s ({frames} frames at 30 fps) but its motion "
            f"{motion_path.name} has {clip.num_frames} frames ({clip.num_frames / FPS:.2f} s)",
        )
    return resample(clip, FPS, frames)


def recording(
    rec_id: str,
    audio: DyadicAudio,
    pose: np.ndarray,
    translation: np.ndarray,
    face: np.ndarray | None,
    *,
    speaker: str,
    audio_path: Path,
    motion_path: Path,
    missing_joints: tuple[str, ...] = (),
    missing_face: tuple[str, ...] = (),
    group: str | None = None,
    split: str | None = None,
    metadata: dict[str, Any] | None = None,
    fps: float = FPS,
) -> Recording:
    """One take of imported motion at ``fps`` with its audio, as the writer takes it: resampled to
    30 fps, lengths reconciled, voice activity and state from the audio (as generators compute
    them at run time)."""
    n = len(pose)
    clip = MotionClip(
        pose=np.asarray(pose, np.float32),
        translation=np.asarray(translation, np.float32),
        face=np.zeros((n, len(ARKIT_NAMES)), np.float32) if face is None else np.clip(face, 0, 1).astype(np.float32),
        vad=np.zeros((n, 2), np.float32),
        state=np.zeros(n, np.int8),
        fps=fps,
    )
    clip = resample(clip, FPS)
    stereo = quantise(np.stack([audio.self_voice, audio.other_voice], axis=1))
    audio = DyadicAudio(stereo[:, 0], stereo[:, 1], audio.source)
    frames = motion_frames_for(audio.duration)
    clip = fit_length(clip, frames, audio_path, motion_path)
    vad = voice_activity(audio)
    clip = dataclasses.replace(clip, vad=vad, state=ConversationState.from_vad(vad))
    return Recording(
        rec_id,
        stereo,
        [clip],
        speaker,
        group=group,
        missing_joints=missing_joints,
        missing_face=missing_face,
        split=split,
        metadata={"audio": audio_path.name, "motion": motion_path.name, **(metadata or {})},
    )
