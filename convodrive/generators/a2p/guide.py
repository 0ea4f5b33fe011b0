"""a2p's guide poses: one body pose a second, sampled as the audio arrives, for the body diffusion.

For every second whose audio has been heard (up to ``GUIDE_REACH`` frames past its pose frame),
``guide_audio`` embeds its audio, ``guide_step`` samples its residual-VQ codes one by one with
nucleus sampling and a KV cache that carries on across windows (``convodrive.neural.autoregressive``),
and ``vq_decoder`` turns codes into poses. A stream's ``GuideState`` keeps only what later seconds
still read, so its size is fixed however long the stream.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from convodrive import FPS
from convodrive.motion import representation as rep
from convodrive.neural.autoregressive import KVCache, sample_tokens

GUIDE_REACH = 15
"""A guide pose is sampled once the audio half a second past its frame has been heard."""
BODY = rep.GROUPS["body"]
VQ_DECODER_SECONDS = 8
"""The VQ decoder's receptive field: the codes of the 7 seconds before a new one shape its pose."""


@dataclasses.dataclass
class GuideState:
    """What a stream's guide carries from window to window."""

    cache: KVCache
    audio: np.ndarray | None = None
    """Log-mel (frames, 2, bands) from frame ``audio_start``: what the guide has still to hear."""
    audio_start: int = 0
    next_second: int = 0
    """The first second whose guide pose is not sampled yet."""
    embeddings: list[np.ndarray] = dataclasses.field(default_factory=list)
    """Audio embeddings (1, width) of the seconds before ``next_second`` the guide still hears."""
    codes: np.ndarray | None = None
    """(K, seconds, levels) codes of the seconds before ``next_second`` the VQ decoder still reads."""
    poses: dict[int, np.ndarray] = dataclasses.field(default_factory=dict)
    """Guide poses (K, body dims) by second, those a later window may still use."""


class GuidePoses:
    """The three guide graphs of one model folder, driven for any number of streams."""

    def __init__(
        self,
        graphs: Mapping[str, Any],
        arch: Mapping[str, Any],
        speaker: np.ndarray,
        silence: np.ndarray,
        top_p: float,
        temperature: float,
    ) -> None:
        self.audio_graph, self.step_graph, self.vq_decoder = (
            graphs[k] for k in ("guide_audio", "guide_step", "vq_decoder")
        )
        self.arch, self.speaker, self.silence = arch, speaker, silence
        self.top_p, self.temperature = top_p, temperature
        self.levels, self.span = int(arch["vq_levels"]), int(arch["guide_audio_span"])
        chunk = np.repeat(silence[None, None, None], FPS, axis=2).astype(np.float32)
        self.silent_second = self.audio_graph(chunks=chunk)["audio"][0, 0]

    def state(self, takes: int) -> GuideState:
        heads, width = int(self.arch["guide_heads"]), int(self.arch["guide_width"])
        band = int(self.arch["guide_band"])
        cache = KVCache.empty(
            int(self.arch["guide_layers"]), takes, heads, width // heads, band, int(self.arch["vq_codes"])
        )
        return GuideState(cache, embeddings=[self.silent_second] * (self.span - 1))

    def hear(self, state: GuideState, audio: np.ndarray, start: int) -> None:
        """Keep the window's audio (frames from ``start``) that the guide has still to hear."""
        if state.audio is None:
            state.audio, state.audio_start = audio, start
        else:
            end = state.audio_start + len(state.audio)
            state.audio = np.concatenate([state.audio, audio[max(0, end - start) :]])
        first = FPS * state.next_second - GUIDE_REACH
        if first > state.audio_start:
            state.audio = state.audio[first - state.audio_start :]
            state.audio_start = first

    def sample(self, state: GuideState, heard: int, rngs: Sequence[np.random.Generator]) -> None:
        """Sample the guide poses of every second whose audio up to ``heard`` frames is in."""
        seconds = list(range(state.next_second, (heard - GUIDE_REACH) // FPS + 1))
        if not seconds:
            return
        chunks = np.stack([self._chunk(state, s) for s in seconds])[None]
        embedded = self.audio_graph(chunks=chunks)["audio"][0]
        new_codes = np.empty((len(rngs), len(seconds), self.levels), np.int64)
        for i in range(len(seconds)):
            state.embeddings = (state.embeddings + [embedded[i]])[-self.span :]
            step = self.step_function(np.repeat(np.stack(state.embeddings)[None], len(rngs), axis=0))
            new_codes[:, i] = sample_tokens(step, state.cache, self.levels, self.top_p, rngs, self.temperature)
            state.embeddings = state.embeddings[-(self.span - 1) :] if self.span > 1 else []
        history = 0 if state.codes is None else state.codes.shape[1]
        codes = new_codes if state.codes is None else np.concatenate([state.codes, new_codes], axis=1)
        poses = self.vq_decoder(codes=codes)["poses"][:, history:]
        for i, second in enumerate(seconds):
            state.poses[second] = poses[:, i]
        state.codes = codes[:, -(VQ_DECODER_SECONDS - 1) :]
        state.next_second = seconds[-1] + 1

    def near(self, state: GuideState, start: int, window: int, takes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The guide poses from a second before the window to its end, at frames relative to
        its start (at least one row, marked invalid when there is none); older ones are dropped."""
        near = [s for s in sorted(state.poses) if start - FPS <= FPS * s < start + window]
        for s in [s for s in state.poses if FPS * s < start - FPS]:
            del state.poses[s]
        if not near:
            dim = BODY.stop - BODY.start
            empty = np.zeros((takes, 1), np.float32)
            return np.zeros((takes, 1, dim), np.float32), empty, empty.copy()
        guide = np.stack([state.poses[s] for s in near], axis=1).astype(np.float32)
        positions = np.tile(np.array([FPS * s - start for s in near], np.float32), (takes, 1))
        return guide, positions, np.ones((takes, len(near)), np.float32)

    def _chunk(self, state: GuideState, second: int) -> np.ndarray:
        """The 30 log-mel frames of ``second``, centred on its pose frame (silence before the start)."""
        assert state.audio is not None
        first = FPS * second - GUIDE_REACH
        frames = np.repeat(self.silence[None], FPS, axis=0)
        lo = max(first, state.audio_start, 0)
        frames[lo - first :] = state.audio[lo - state.audio_start : first + FPS - state.audio_start]
        return frames

    def step_function(self, band: np.ndarray) -> Any:
        """The guide's step function for tokens that hear ``band`` (K, span, width)."""
        speaker = np.repeat(self.speaker, len(band))

        def step(token: np.ndarray, position: np.ndarray, keys: np.ndarray, values: np.ndarray) -> tuple[Any, ...]:
            out = self.step_graph(
                token=token, position=position, audio=band, past_keys=keys, past_values=values, speaker=speaker
            )
            return out["logits"], out["keys"], out["values"]

        return step
