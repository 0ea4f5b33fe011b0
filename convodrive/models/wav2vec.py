"""The optional pretrained audio front-end: wav2vec 2.0 (through ``transformers``) at 30 fps.

For users who have a wav2vec 2.0 checkpoint in a local folder (e.g. a copy of
``facebook/wav2vec2-base-960h``, which ProbTalk uses): it is loaded from that folder only, never
downloaded (the Hugging Face offline switches are set before loading), kept frozen, and exported
to ONNX beside the model that uses it, so a run still needs no torch. The hidden states (about
50 Hz) are linearly resampled to the motion clock, one vector per 30 fps frame.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from convodrive.plumbing.errors import InputFileError, UserError

OFFLINE = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}


class Wav2VecFrontEnd(nn.Module):
    """(B, samples) 16 kHz audio -> (B, frames, hidden) with ``frames = samples * 3 // 1600``."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)

    @property
    def hidden_size(self) -> int:
        return int(self.model.config.hidden_size)

    @classmethod
    def from_folder(cls, folder: str | Path) -> Wav2VecFrontEnd:
        """Load from a local folder (config.json plus weights); never from the network."""
        folder = Path(folder)
        if not (folder / "config.json").is_file():
            raise InputFileError(
                folder, "not a wav2vec 2.0 folder (no config.json); it must be a local copy, nothing is downloaded"
            )
        os.environ.update(OFFLINE)
        try:
            from transformers import Wav2Vec2Model
        except ImportError:
            raise UserError("the wav2vec front-end needs transformers (pip install 'convodrive[frontend]')") from None
        try:
            model = Wav2Vec2Model.from_pretrained(str(folder), local_files_only=True)
        except (OSError, ValueError) as exc:
            raise InputFileError(
                folder, f"cannot load wav2vec 2.0 weights ({str(exc).splitlines()[0][:160]})"
            ) from None
        return cls(model)

    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        frames = audio.shape[1] * 3 // 1600
        hidden = self.model(audio).last_hidden_state  # (B, ~50 Hz, hidden)
        resampled = nn.functional.interpolate(hidden.transpose(1, 2), size=frames, mode="linear", align_corners=False)
        return resampled.transpose(1, 2)
