"""``probtalk``: ProbTalk's PQ-VAE, MaskGIT predictor and refiner, streaming in ONNX Runtime + NumPy.

Each window of audio becomes motion in four graph calls and a NumPy loop:

1. ``predictor_memory`` (once per window): both voices' log-mel, the known context frames and the
   speaker -> every layer's cross-attention keys and values and speaker modulation;
2. ``predictor_step`` (once per MaskGIT pass, T passes): token ids + that memory -> logits; the
   sampling loop between passes is ``convodrive.neural.maskgit`` (NumPy);
3. ``vq_decoder``: codes -> coarse motion; the known frames are copied in;
4. ``refiner`` (with ``refine``, the default): coarse motion + audio + known mask -> the window's
   motion, its face's shapes clipped to [0, 1] as the run shows them (a refiner trained with
   ``refiner_shown`` sends a shape at rest past it, and the next window's context must be motion
   the predictor learned from); the body is then low-passed (``smooth``, the base class's) since
   the PQ-VAE's decoder shivers. The shipped refiner learned with squared error
   (``refiner_loss``); an L1 one flattens the mouth's brief shapes, and with it ``refine=false``
   scores better (see the model card).

K takes (``--samples K``) are the batch of the same calls. With ``face_temperature`` (default on)
the memory and MaskGIT passes run for 2K rows: each take's body comes from its draw at
``temperature``, its face from a second, hotter draw (every code carries face and body, and at the
body's temperature the face seldom blinks). Windows overlap by ``context`` frames:
a window continues from the previous window's last frames, which it is given as known motion
and keeps unchanged, so a stream of any length is one continuous motion (the base class,
``convodrive.generators.learned``, cuts the stream and keeps memory constant). ``file`` mode
uses the paper's 180-frame windows; ``live`` mode short ones, so a frame waits for at most
``window - context`` frames of audio (0.4 s by default).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from convodrive.generators.learned import LearnedGenerator, LearnedOptions
from convodrive.motion import representation as rep
from convodrive.neural.maskgit import maskgit_sample
from convodrive.neural.windows import WindowPlan
from convodrive.plugins.options import option
from convodrive.plumbing.errors import UserError

MODES: dict[str, tuple[int, int]] = {"file": (180, 30), "live": (48, 36)}
"""Window and context frames of each mode: the paper's 180 and 30; a 12-frame hop for live runs."""
GRAPHS = ("predictor_memory", "predictor_step", "vq_decoder")


@dataclasses.dataclass(frozen=True)
class ProbTalkOptions(LearnedOptions):
    mode: str = option(
        "file",
        choices=tuple(MODES),
        help="file: 180-frame windows (the paper's); live: 48-frame windows, 0.4 s look-ahead",
    )
    window: int = option(0, low=0, high=3600, help="frames per window; 0: the mode's (file 180, live 48)")
    context: int = option(
        -1,
        low=-1,
        high=3599,
        help="frames each window continues from the previous one; -1: the mode's (file 30, live 36)",
    )
    iterations: int = option(8, low=1, high=64, help="MaskGIT passes per window (the paper's T)")
    temperature: float = option(
        1.0, low=0.01, high=10.0, help="sampling temperature of the codes (lower: safer, less varied)"
    )
    face_temperature: float = option(
        1.4,
        low=0.0,
        high=10.0,
        help="temperature of a second draw of the codes whose face replaces the first draw's "
        "(0 or equal to temperature: one draw); every code carries face and body, and the face wants a "
        "hotter draw than the body (its blinks), see the model card",
    )
    speaker: str = option("", help="speaker style the model learned (its model card lists them); empty: the first")
    dyadic: bool = option(True, help="hear the partner's channel (false: the model hears silence there)")
    refine: bool = option(
        True,
        help="run the refiner (false: the PQ-VAE decoder's motion; see the model card for what each scores)",
    )
    smooth: float = option(
        1.0,
        low=0.0,
        high=10.0,
        help="Gaussian low-pass of the body in each window's new frames, sigma in frames (0: none); "
        "the PQ-VAE's decoder shivers",
    )
    blend: int = option(
        12,
        low=0,
        high=600,
        help="frames over which a window eases into its own motion (0: none); 12: a token and a half",
    )

    def __post_init__(self) -> None:
        window, context = self.frames()
        if window < 8:
            raise ValueError(f"window must be at least 8 frames, got {window}")
        if not 0 <= context < window:
            raise ValueError(f"context must be below window ({window}), got {context}")

    def frames(self) -> tuple[int, int]:
        """Window and context in frames, the mode's where not given."""
        window, context = MODES[self.mode]
        return self.window or window, context if self.context < 0 else self.context


class ProbTalkGenerator(LearnedGenerator):
    name = "probtalk"
    description = "ProbTalk: PQ-VAE codes predicted by MaskGIT from both voices (learned, ONNX Runtime)"
    Options: ClassVar[type[LearnedOptions]] = ProbTalkOptions
    model_kind = "probtalk"
    shipped_model: ClassVar[Path | None] = Path(__file__).with_name("model")

    options: ProbTalkOptions

    def __init__(self, options: ProbTalkOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.folder.require_graphs(GRAPHS, "export the predictor or refiner stage")
        arch = self.folder.spec["architecture"]
        self.groups, self.codes = int(arch["groups"]), int(arch["codes"])
        self.per_token = 2 ** (len(arch["vq_channels"]) - 1)
        speakers = list(self.folder.spec["features"].get("speakers", []))
        wanted = self.options.speaker or (speakers[0] if speakers else "")
        if wanted not in speakers:
            raise UserError(
                f"generator probtalk: speaker '{wanted}' is not one the model learned ({', '.join(speakers)})"
            )
        self.speaker = speakers.index(wanted)
        self.refine = self.options.refine and "refiner" in self.folder.graphs
        self.memory = self.graph("predictor_memory")
        self.step = self.graph("predictor_step")
        self.decoder = self.graph("vq_decoder")
        self.refiner = self.graph("refiner") if self.refine else None
        self.shown = rep.shape_bounds(self.stats.mean, self.stats.std)
        """The run shows the face's shapes clipped to these; the next window continues from them."""
        self.windows = 0

    def window_plan(self) -> WindowPlan:
        assert isinstance(self.options, ProbTalkOptions)
        return WindowPlan(*self.options.frames())

    def run_window(
        self, audio: np.ndarray, context: np.ndarray | None, rngs: Sequence[np.random.Generator]
    ) -> np.ndarray:
        takes, window = len(rngs), len(audio)
        frames = -(-window // self.per_token) * self.per_token  # whole tokens; the end padded with silence
        heard = np.concatenate([audio, np.repeat(self._silence[None], frames - window, axis=0)]).astype(np.float32)
        if not self.options.dyadic:
            heard[:, 1] = self._silence[1]
        heard = np.repeat(heard[None], takes, axis=0)
        known = np.zeros((takes, frames, self.stats.mean.shape[0]), np.float32)
        known_mask = np.zeros((takes, frames, 1), np.float32)
        if context is not None:
            known[:, : context.shape[1]] = context
            known_mask[:, : context.shape[1]] = 1.0
        speaker = np.full(takes, self.speaker, np.int64)
        memory = self.memory(audio=heard, known=known, known_mask=known_mask, speaker=speaker)
        temperature = np.full(takes, self.options.temperature)
        face_draw = self.options.face_temperature > 0 and self.options.face_temperature != self.options.temperature
        if face_draw:  # the face's draws ride in the same batch, from generators spawned off each take's
            memory = {name: np.concatenate([value, value], axis=1) for name, value in memory.items()}
            rngs = [*rngs, *(np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0]) for rng in rngs)]
            temperature = np.concatenate([temperature, np.full(takes, self.options.face_temperature)])

        def logits(tokens: np.ndarray) -> np.ndarray:
            return self.step(tokens=tokens, **memory)["logits"]

        tokens = maskgit_sample(
            logits, frames // self.per_token * self.groups, self.codes, self.options.iterations, rngs, temperature
        )
        coarse = self.decoder(codes=tokens.reshape(len(rngs), frames // self.per_token, self.groups))["motion"]
        if face_draw:
            coarse, hotter = coarse[:takes], coarse[takes:]
            coarse[..., rep.GROUPS["face"]] = hotter[..., rep.GROUPS["face"]]
        motion = known_mask * known + (1 - known_mask) * coarse
        if self.refiner is not None:
            motion = self.refiner(motion=motion, audio=heard, known_mask=known_mask, speaker=speaker)["refined"]
        self.windows += 1
        return np.clip(motion[:, :window], *self.shown)

    def report(self) -> dict[str, Any]:
        return {
            "model": str(self.folder.path),
            "mode": self.options.mode,
            "window": self.plan.window,
            "context": self.plan.context,
            "iterations": self.options.iterations,
            "refined": self.refine,
            "windows": self.windows,
        }
