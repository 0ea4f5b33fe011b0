"""The base of learned generators: ONNX model folders run in overlapping windows, streaming.

A subclass names its window plan and runs one window: given the window's audio features (both
voices' log-mel, exactly as the corpus stored them) and, after the first window, the ``context``
frames it must continue from, it returns the window's normalised motion features for each take.
This base does the rest: it loads and verifies the model folder (``convodrive.neural``), computes
the log-mel features in streaming blocks (``convodrive.audio.logmel``, chunk-invariant), cuts the
stream into windows (``neural.windows.WindowPlan``), pads the last window with silence, seeds
each window from (seed, window index), eases each window's first new frames onto the motion it
continues (``neural.windows.ease_in``, over ``blend`` frames), and decodes features to canonical frames
(``motion.representation``). Everything depends only on the audio and the seed, never on how the
audio was chunked, so ``stream == generate`` for a seed, and K takes share one feature pass.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from convodrive.audio.features import frame_edge
from convodrive.audio.logmel import LogMelStream, MelSpec, log_mel
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk, DyadicAudio, motion_frames_for
from convodrive.generators.base import Generator, take_seed
from convodrive.motion import representation as rep
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.neural import Graph, ModelFolder, SessionOptions, load_model_folder
from convodrive.neural.windows import WindowPlan, ease_in, smooth_new_frames
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.errors import InputFileError, UserError


@dataclasses.dataclass(frozen=True)
class LearnedOptions(PluginOptions):
    """Options every learned generator has; a subclass's Options extends this dataclass."""

    model: str = option("", help="model folder (convodrive export); empty: the weights shipped with the generator")
    threads: int = option(1, low=1, high=64, help="ONNX Runtime intra-op threads per graph")
    device: str = option("auto", choices=("auto", "cpu", "cuda"), help="where graphs run (auto: CUDA when present)")
    blend: int = option(
        10,
        low=0,
        high=600,
        help="frames over which a window eases from the motion it continues into its own (0: none, a jump may show at the seam)",
    )
    smooth: float = option(
        0.0,
        low=0.0,
        high=10.0,
        help="Gaussian low-pass of the body in each window's new frames, sigma in frames (0: none; the face keeps its quick blinks and lips); adds no look-ahead",
    )


class LearnedGenerator(Generator):
    Options: ClassVar[type[LearnedOptions]] = LearnedOptions
    model_kind: ClassVar[str] = ""
    """The ``model`` a folder's model.json must name (the recipe that trained it)."""
    shipped_model: ClassVar[Path | None] = None
    """The folder of the weights shipped in the package, used when ``model`` is empty."""
    extra: ClassVar[str] = "neural"
    requires: ClassVar[tuple[str, ...]] = ("onnxruntime",)

    options: LearnedOptions

    def __init__(self, options: LearnedOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        path = self.options.model or self.shipped_model
        if not path:
            raise UserError(f"generator '{self.name}' needs a model folder: -G model=DIR")
        self.folder: ModelFolder = load_model_folder(path)
        if self.model_kind and self.folder.model != self.model_kind:
            raise InputFileError(
                self.folder.path,
                f"holds a '{self.folder.model}' model, generator '{self.name}' reads '{self.model_kind}'",
            )
        features = self.folder.spec.get("features", {})
        layout = features.get("layout", {})
        if layout.get("version") != rep.LAYOUT_VERSION or layout.get("dim") != rep.FEATURE_DIM:
            raise InputFileError(
                self.folder.path,
                f"feature layout {layout.get('version')} ({layout.get('dim')} dims) is not this convodrive's {rep.LAYOUT_VERSION} ({rep.FEATURE_DIM})",
            )
        self.mel_spec = MelSpec.from_dict(features.get("corpus", {}).get("audio_features", {}))
        self.stats = self._normalisation()
        self.session_options = SessionOptions(threads=self.options.threads, device=self.options.device)
        self.plan = self.window_plan()
        self._silence = log_mel(np.zeros((2 * self.mel_spec.window, 2), np.float32), 1, self.mel_spec)[0]

    # -- what a subclass provides ----------------------------------------------------------------
    @abc.abstractmethod
    def window_plan(self) -> WindowPlan: ...

    @abc.abstractmethod
    def run_window(
        self, audio: np.ndarray, context: np.ndarray | None, rngs: Sequence[np.random.Generator], state: Any = None
    ) -> np.ndarray:
        """(K, window, FEATURE_DIM) normalised motion for K takes, from ``audio`` (window, 2, bands)
        log-mel and ``context`` (K, context, FEATURE_DIM) normalised motion (None for window 0).
        ``state`` is what ``stream_state`` made for this stream (passed only when not None)."""

    def stream_state(self, takes: int) -> Any:
        """A new stream's state, which ``run_window`` carries from one window to the next (an
        autoregressive cache, what earlier windows decided). Kept by the stream, not the
        generator, so streams never share it. None (the default): windows need no state."""
        return None

    def graph(self, name: str) -> Graph:
        """A session on one of the folder's graphs, with this generator's thread and device settings;
        its inputs and outputs must be the ones model.json describes."""
        graph = Graph(self.folder.graph_path(name), self.session_options)
        self.folder.check_graph(name, graph.input_names, graph.output_names)
        return graph

    def _normalisation(self) -> rep.FeatureStats:
        """The folder's feature statistics: ``mean`` and ``std`` of the layout's width, finite."""
        norm = self.folder.arrays("normalisation.npz")
        for key in ("mean", "std") + (("count",) if "count" in norm else ()):
            value = norm.get(key)
            if value is None or value.shape != (rep.FEATURE_DIM,) or value.dtype.kind not in "fiu":
                shape = "missing" if value is None else f"{value.dtype} {value.shape}"
                raise InputFileError(
                    self.folder.path / "normalisation.npz", f"'{key}' must be ({rep.FEATURE_DIM},) numbers, got {shape}"
                )
            if not np.all(np.isfinite(value)):
                raise InputFileError(self.folder.path / "normalisation.npz", f"'{key}' holds NaN or infinite values")
        return rep.FeatureStats.from_arrays(norm)

    # -- the contract ---------------------------------------------------------------------------
    @property
    def lookahead_frames(self) -> int:
        audio_frames = -(-self.mel_spec.lookahead_samples // int(frame_edge(1)))
        return self.plan.lookahead_frames + audio_frames

    def stream(self, chunks: Iterable[AudioChunk], seed: int = 0) -> Iterator[MotionFrame]:
        for takes in self.stream_takes(chunks, [seed]):
            yield takes[0]

    def stream_takes(self, chunks: Iterable[AudioChunk], seeds: Sequence[int]) -> Iterator[tuple[MotionFrame, ...]]:
        plan, k = self.plan, len(seeds)
        mel = LogMelStream(2, self.mel_spec)
        # Only what a later window still needs is kept, so memory stays constant however long the
        # audio: audio[i] is frame a0 + i, motion[:, i] is frame m0 + i.
        # The first window starts plan.context frames early, over silence (see WindowPlan).
        audio = np.repeat(self._silence[None], plan.context, axis=0).astype(np.float32)
        motion = np.zeros((k, 0, rep.FEATURE_DIM), np.float32)
        a0 = m0 = plan.start(0)
        emitted = index = received = 0
        state = self.stream_state(k)
        carried = {} if state is None else {"state": state}

        def run(index: int, window_audio: np.ndarray) -> None:
            nonlocal motion
            start = plan.start(index)
            context = motion[:, start - m0 : start - m0 + plan.context] if index > 0 and plan.context else None
            rngs = [np.random.default_rng([int(s) & 0xFFFFFFFF, index]) for s in seeds]
            out = np.asarray(self.run_window(window_audio, context, rngs, **carried), np.float32)
            keep = plan.context if index > 0 else 0
            if context is not None:
                out = ease_in(out, context, min(self.options.blend, out.shape[1] - context.shape[1]))
                out[:, :keep] = context  # the low-pass's past is the motion already out
            out = smooth_new_frames(out, keep, self.options.smooth, rep.GROUPS["body"])
            motion = np.concatenate([motion[:, : start + keep - m0], out[:, keep:]], axis=1)

        def frames(stop: int) -> Iterator[tuple[MotionFrame, ...]]:
            nonlocal emitted
            if stop <= emitted:
                return
            clips = [rep.decode(self.stats.denormalise(motion[t, emitted - m0 : stop - m0])) for t in range(k)]
            for i in range(stop - emitted):
                frames_i = []
                for clip in clips:
                    f = clip.frame(i)
                    f.time = (emitted + i) / 30.0
                    frames_i.append(f)
                yield tuple(frames_i)
            emitted = stop

        def forget() -> None:
            """Drop the frames before the next window that are already out."""
            nonlocal audio, motion, a0, m0
            next_start = plan.start(index)
            keep_from = min(emitted, next_start)
            motion, m0 = motion[:, keep_from - m0 :], keep_from
            audio, a0 = audio[max(0, next_start - a0) :], max(a0, next_start)

        for chunk in chunks:
            received += len(chunk)
            audio = np.concatenate([audio, mel.push(np.stack([chunk.self_voice, chunk.other_voice], axis=1))])
            while a0 + len(audio) >= plan.start(index) + plan.window:
                start = plan.start(index) - a0
                run(index, audio[start : start + plan.window])
                index += 1
                yield from frames(plan.start(index - 1) + plan.window)
                forget()
        total = motion_frames_for(received / ANALYSIS_RATE)
        if total > a0 + len(audio):
            audio = np.concatenate([audio, mel.finish(total)])
        audio = audio[: max(0, total - a0)]
        while emitted < total:
            start = plan.start(index)
            window_audio = audio[start - a0 : start - a0 + plan.window]
            if len(window_audio) < plan.window:
                pad = np.repeat(self._silence[None], plan.window - len(window_audio), axis=0)
                window_audio = np.concatenate([window_audio, pad])
            run(index, window_audio)
            index += 1
            yield from frames(min(total, start + plan.window))
            forget()

    def generate(self, audio: DyadicAudio, seed: int = 0, num_samples: int = 1) -> list[MotionClip]:
        """Offline: all takes in one batched pass (each take is what ``stream`` with its seed gives)."""
        seeds = [take_seed(seed, i) for i in range(num_samples)]
        per_frame = list(self.stream_takes(audio.chunks(), seeds))
        return [
            MotionClip.from_frames([frames[i] for frames in per_frame], metadata={"generator": self.name, "seed": s})
            for i, s in enumerate(seeds)
        ]
