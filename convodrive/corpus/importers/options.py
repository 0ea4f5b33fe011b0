"""What a user may tell an importer (``convodrive corpus import KIND SRC --out DIR ...``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class ImportOptions:
    speaker: str | None = None
    """A speaker label for every conversation, instead of the one the source's names give."""
    mano: Path | None = None
    """Hand PCA components (SHOW): an SMPL-X model ``.npz`` or TalkSHOW's ``hand_component.json``."""
