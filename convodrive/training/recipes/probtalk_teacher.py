"""A model folder's refiner as the teacher of a retrained refiner's body (``refiner_teacher``).

A refiner retrained for a better face (``refiner_fd``) gives up some of what the old one did for
the body: one network of the same size carries both, and the face's distance term pulls its
capacity away. Against the old refiner's own output on the same input, the body has a target
that is a function of that input (the truth is one draw of many), which a network of that size
learns far more closely. The teacher runs in ONNX Runtime, as the generator runs it.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import torch

from convodrive.models.probtalk_config import REFINER_GROUPS
from convodrive.neural.folder import load_model_folder
from convodrive.neural.session import Graph, SessionOptions
from convodrive.plumbing.errors import UserError
from convodrive.training.recipes.probtalk_decoder import FOLDER_NORMALISATION
from convodrive.training.staged import check_same_data


def check_teacher(folder: str, normalisation: dict[str, np.ndarray], speakers: Sequence[str]) -> None:
    """One-line error unless ``folder`` has a refiner graph that learnt this corpus's normalisation
    and speakers (a speaker's index must name the same style in both)."""
    found = load_model_folder(folder)  # every file's sha256 checked
    if "refiner" not in found.graphs:
        raise UserError(f"refiner_teacher={folder}: the folder has no refiner graph")
    check_same_data(found.arrays("normalisation.npz"), normalisation, f"refiner_teacher={folder}", FOLDER_NORMALISATION)
    learnt = list(found.spec["features"].get("speakers", []))
    if learnt != list(speakers):
        raise UserError(f"refiner_teacher={folder}: its speakers ({', '.join(learnt)}) are not this corpus's")


@functools.lru_cache(maxsize=2)
def _teacher(folder: str) -> Graph:
    found = load_model_folder(folder)
    return Graph(found.graph_path("refiner"), SessionOptions(threads=1, device="cpu"))


def taught_target(
    folder: str,
    groups: Sequence[str],
    combined: torch.Tensor,
    audio: torch.Tensor,
    known: torch.Tensor,
    speaker: torch.Tensor,
    motion: torch.Tensor,
) -> torch.Tensor:
    """``motion`` with the channels of ``groups`` in the frames no context fixes replaced by the
    teacher's refinement of ``combined`` (what the student refines too)."""
    refined = _teacher(folder)(
        motion=combined.detach().cpu().numpy().astype(np.float32),
        audio=audio.detach().cpu().numpy().astype(np.float32),
        known_mask=known.detach().cpu().numpy().astype(np.float32),
        speaker=speaker.detach().cpu().numpy().astype(np.int64),
    )["refined"]
    taught = torch.from_numpy(refined).to(motion.device, motion.dtype)
    target = motion.clone()
    free = known == 0
    for group in groups:
        columns = torch.from_numpy(REFINER_GROUPS[group]).to(motion.device)
        target[..., columns] = torch.where(free, taught[..., columns], motion[..., columns])
    return target
