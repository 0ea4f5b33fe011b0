"""Your own recordings: WAV files, each with the motion captured with it, side by side.

Layout (any depth)::

    <name>.wav    channel 0 you, channel 1 your partner (mono: no partner)
    <name>.npz    a convodrive clip (everything), or
    <name>.bvh    a mocap suit's body (joints mapped by name), and/or
    <name>.csv    a Live Link Face take from an iPhone (ARKit face, head and eyes)

A ``.bvh`` and a ``.csv`` of one name are merged: the body from the suit, the face from the phone.
Motion is read by the one loader (``convodrive.motion.load``) and resampled to 30 fps by the one
resampler; what a format lacks is masked (a BVH has no face, a Live Link take no body). The
speaker label is the folder a file sits in (``own`` for files directly in SRC), or ``--speaker``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from convodrive import FPS
from convodrive.audio.source import AudioSource
from convodrive.corpus.importers.common import LENGTH_TOLERANCE_FRAMES, recording
from convodrive.corpus.importers.options import ImportOptions
from convodrive.corpus.manifest import safe_id
from convodrive.corpus.writer import Recording
from convodrive.motion.channels import ARKIT_NAMES, NUM_BLENDSHAPES
from convodrive.motion.clip import MotionClip
from convodrive.motion.load import load_motion
from convodrive.motion.resample import resample
from convodrive.motion.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS
from convodrive.plumbing.errors import InputFileError

LICENCE = "that of your own recordings"
MOTION_SUFFIXES = (".npz", ".bvh", ".csv")
_LIVELINK_JOINTS = ("head", "left_eye_smplhf", "right_eye_smplhf", "jaw")


def find(src: Path, options: ImportOptions) -> list[tuple[Path, list[Path], str]]:
    """Each WAV, its motion files and its speaker label."""
    items = []
    for wav in sorted(p for p in src.rglob("*") if p.suffix.lower() == ".wav" and p.is_file()):
        motion = [wav.with_suffix(s) for s in MOTION_SUFFIXES if wav.with_suffix(s).is_file()]
        if not motion:
            raise InputFileError(wav, "no motion beside it (expected a .npz, .bvh or Live Link .csv of the same name)")
        if wav.with_suffix(".npz") in motion and len(motion) > 1:
            raise InputFileError(
                wav, "has a .npz clip and other motion files beside it: keep one (a .bvh and a .csv merge)"
            )
        folder = wav.parent.relative_to(src)
        speaker = options.speaker or (folder.parts[-1] if folder.parts else "own")
        items.append((wav, motion, speaker))
    if not items:
        raise InputFileError(src, "holds no WAV files (each with a .npz, .bvh or Live Link .csv of the same name)")
    return items


def present(clip: MotionClip, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Which canonical joints and ARKit channels a loaded file really holds."""
    kind = path.suffix.lower()
    joints, face = np.ones(NUM_JOINTS, bool), np.ones(NUM_BLENDSHAPES, bool)
    if kind == ".bvh":
        joints[:] = False
        joints[[JOINT_INDEX[j] for j in clip.metadata.get("mapped_joints", {}).values()]] = True
        face[:] = False
    elif kind == ".csv":
        absent = set(clip.metadata.get("missing_columns", ()))
        joints[:] = False
        for joint, column in zip(_LIVELINK_JOINTS, ("HeadYaw", "LeftEyeYaw", "RightEyeYaw", "jawOpen")):
            joints[JOINT_INDEX[joint]] = column not in absent
        face = np.array([name not in absent for name in ARKIT_NAMES])
    return joints, face


def merge(
    parts: list[tuple[MotionClip, np.ndarray, np.ndarray]], frames: int
) -> tuple[MotionClip, np.ndarray, np.ndarray]:
    """One clip of ``frames`` frames from several files: each joint and face channel from the first
    file that holds it; the root translation from the first file with a body."""
    pose = np.zeros((frames, NUM_JOINTS, 3), np.float32)
    translation = np.zeros((frames, 3), np.float32)
    face = np.zeros((frames, NUM_BLENDSHAPES), np.float32)
    have_j, have_f = np.zeros(NUM_JOINTS, bool), np.zeros(NUM_BLENDSHAPES, bool)
    for clip, joints, channels in parts:
        take_j, take_f = joints & ~have_j, channels & ~have_f
        pose[:, take_j] = clip.pose[:frames, take_j]
        face[:, take_f] = clip.face[:frames, take_f]
        if joints[JOINT_INDEX["pelvis"]] and not have_j[JOINT_INDEX["pelvis"]]:
            translation = clip.translation[:frames]
        have_j |= joints
        have_f |= channels
    clip = MotionClip(pose, translation, face, np.zeros((frames, 2), np.float32), np.zeros(frames, np.int8), fps=FPS)
    return clip, have_j, have_f


def load(item: tuple[Path, list[Path], str], options: ImportOptions) -> list[Recording]:
    wav, motion_files, speaker = item
    audio = AudioSource(wav).read_all()
    parts = []
    for path in motion_files:
        clip = load_motion(path)
        parts.append((resample(clip, FPS), *present(clip, path)))
    frames = max(p[0].num_frames for p in parts)
    for (clip, _, _), path in zip(parts, motion_files):
        if frames - clip.num_frames > LENGTH_TOLERANCE_FRAMES:
            raise InputFileError(
                path, f"has {clip.num_frames} frames at 30 fps, the other motion file beside it {frames}"
            )
    padded = [(resample(c, FPS, frames), j, f) for c, j, f in parts]
    clip, joints, face = merge(padded, frames)
    return [
        recording(
            safe_id(wav.stem),
            audio,
            clip.pose,
            clip.translation,
            clip.face,
            speaker=speaker,
            audio_path=wav,
            motion_path=motion_files[0],
            missing_joints=tuple(n for n, ok in zip(JOINT_NAMES, joints) if not ok),
            missing_face=tuple(n for n, ok in zip(ARKIT_NAMES, face) if not ok),
            metadata={"source": "own", "motion_files": [p.name for p in motion_files]},
        )
    ]
