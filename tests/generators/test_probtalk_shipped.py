"""The probtalk weights shipped in the package: they load verified with their card, fit the package,
and the mouth they make on the bundled dialogue follows self's voice and rests while self is silent;
the torso sways and drifts as slowly as its teacher's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from convodrive.audio.source import AudioSource, DyadicAudio
from convodrive.eval.behaviour import behaviour_figures
from convodrive.eval.segments import load_segments
from convodrive.generators.probtalk.generator import ProbTalkGenerator
from convodrive.motion import representation as rep
from convodrive.motion.clip import MotionClip
from convodrive.motion.skeleton import JOINT_INDEX
from tests.conftest import REPO
from tests.seams import seam_changes

pytestmark = pytest.mark.onnxruntime

SHIPPED = ProbTalkGenerator.shipped_model
assert SHIPPED is not None
FACE_JOINTS = ("jaw", "left_eye_smplhf", "right_eye_smplhf")


def test_the_shipped_folder_is_verified_small_enough_and_carded() -> None:
    gen = ProbTalkGenerator()  # no model option: the shipped folder, every sha256 checked
    assert Path(gen.folder.path) == SHIPPED and gen.folder.spec["preset"] == "small"
    size = sum(f.stat().st_size for f in SHIPPED.iterdir())
    assert size <= 20 * 2**20, f"{size / 2**20:.1f} MiB is more than the package ships"
    card = (SHIPPED / "MODEL_CARD.md").read_text()
    for needed in ("scripts/train_probtalk.sh", "corpus make", "## Licence", "FGD holistic", "knn", "random"):
        assert needed in card, needed


@pytest.fixture(scope="module")
def dialogue() -> DyadicAudio:
    return AudioSource(REPO / "samples" / "dialogue.wav").read_all()


@pytest.fixture(scope="module")
def take(dialogue: DyadicAudio) -> MotionClip:
    """The shipped model's take of the bundled dialogue (seed 0, default options), made once for
    the tests that each look at one side of it."""
    return ProbTalkGenerator().generate(dialogue, seed=0)[0]


def test_the_shipped_mouth_follows_the_bundled_dialogue(dialogue: DyadicAudio, take: MotionClip) -> None:
    audio, clip = dialogue, take
    figures = behaviour_figures(clip, audio, load_segments(REPO / "samples" / "dialogue.json"))
    lips = figures["lip_sync"]
    assert lips["pearson_jaw_vs_self_envelope"] >= 0.6, lips
    assert lips["jaw_closed_when_self_silent"] >= 0.9, lips
    # The body moves: not a statue, not noise. Its joints only: the jaw is the lips' figures', and
    # the eyes wander (the card's Still open), so that the fastest joint of a frame was most often
    # an eye or the jaw. The body's median: the procedural teacher 0.019, these weights 0.022-0.034
    # (seeds 0-2), their whole skeleton's 0.049-0.052.
    body = np.setdiff1d(np.arange(clip.pose.shape[1]), [JOINT_INDEX[j] for j in FACE_JOINTS])
    speed = np.abs(np.diff(clip.pose[:, body], axis=0)).max(axis=(1, 2))
    assert 1e-4 < np.median(speed) < 0.05, "radians a frame"


def test_the_shipped_model_is_continuous_at_window_seams(take: MotionClip) -> None:
    seams, inside = seam_changes(take.pose, ProbTalkGenerator().plan.hop)
    assert len(seams) >= 4
    assert seams.max() <= inside.max(), (seams, inside.max())


def test_the_shipped_model_samples_different_takes_of_one_dialogue(dialogue: DyadicAudio, take: MotionClip) -> None:
    """The predictor's samples reach the motion: two seeds give two gestures (ProbTalk's Var above
    zero), where a decoder that ignored its codes gave takes 3e-4 rad apart."""
    first, second = take, ProbTalkGenerator().generate(dialogue, seed=1)[0]
    apart = np.degrees(np.abs(first.pose - second.pose)).mean(axis=0)  # (joints, 3), degrees
    assert apart.max() > 2.0, apart.max()


def test_the_chest_moves_as_slowly_as_the_corpus_s(take: MotionClip) -> None:
    """The corpus turns spine3 under a degree a second on average and never about one of its
    axes; the refiner's error on that axis's channels (held constant, so scaled by 1) turned it
    11 degrees a second, a shiver, until decoding pinned channels the corpus never moved."""
    spine3 = take.pose[:, JOINT_INDEX["spine3"]]
    speed = np.degrees(np.linalg.norm(np.diff(spine3, axis=0), axis=1)).mean() * 30
    assert speed < 2.0, speed


def test_the_torso_sways_and_drifts_at_its_teacher_s_pace(take: MotionClip) -> None:
    """The PQ-VAE's codes leave the spine near its mean; the refiner learns its spread from the
    spine's distance in distribution, by speaker (``refiner_fd_groups``, ``refiner_fd_by_speaker``).
    On the bundled dialogue (seeds 0-3) the refiner before it turned spine2 about its long axis by
    0.11-0.14 degrees (standard deviation; the procedural teacher's 0.67) and shook spine1 at
    3.3-3.7 degrees a second (the teacher's 0.88); these weights: 0.74-0.79 degrees and 1.0-1.3
    degrees a second."""
    sway = np.degrees(take.pose[:, JOINT_INDEX["spine2"], 1]).std()
    assert sway > 0.4, f"spine2 sways {sway:.2f} degrees"
    spine1 = take.pose[:, JOINT_INDEX["spine1"]]
    speed = np.degrees(np.linalg.norm(np.diff(spine1, axis=0), axis=1)).mean() * 30
    assert speed < 2.0, f"spine1 moves {speed:.2f} degrees a second"


def test_each_window_continues_from_the_face_as_it_is_shown(dialogue: DyadicAudio) -> None:
    """The shipped refiner learned with ``refiner_shown``: a shape at rest may come out past rest,
    which shows as rest. The next window's context is that shown face, within the shapes' [0, 1],
    never the raw output the predictor never learned from."""
    gen = ProbTalkGenerator()
    low, high = rep.shape_bounds(gen.stats.mean, gen.stats.std)
    assert gen.refiner is not None
    refiner, run_window = gen.refiner, gen.run_window
    raw: list[np.ndarray] = []
    contexts: list[np.ndarray] = []

    def refine(**inputs: np.ndarray) -> dict[str, np.ndarray]:
        out = refiner(**inputs)
        raw.append(out["refined"])
        return out

    def window(audio: np.ndarray, context: np.ndarray | None, rngs: list) -> np.ndarray:
        if context is not None:
            contexts.append(context)
        return run_window(audio, context, rngs)

    gen.refiner, gen.run_window = refine, window  # type: ignore[assignment,method-assign]
    gen.generate(dialogue, seed=0)
    assert len(contexts) >= 4
    assert max(float((low - r).max()) for r in raw) > 0.5, "the refiner sends a resting shape past rest"
    assert all(((c >= low) & (c <= high)).all() for c in contexts)
