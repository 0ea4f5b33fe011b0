"""The ONNX graphs of a ``probtalk`` stage: what ``convodrive.generators.probtalk`` runs in ONNX Runtime.

By stage: ``vq_encoder`` and ``vq_decoder`` (codes <-> motion); then ``predictor_memory`` (the
conditions of a window -> every layer's cross-attention keys and values and speaker modulation,
run once per window) and ``predictor_step`` (tokens + that memory -> logits, run once per MaskGIT
pass); then ``refiner``. Example sizes count tokens (8 frames each).
"""

from __future__ import annotations

import numpy as np
import torch

from convodrive.models.probtalk import ProbTalk
from convodrive.motion import representation as rep
from convodrive.training.recipe import DataSpec, GraphModule, GraphSpec

TAKES = 2
DIM = rep.FEATURE_DIM


# ------------------------------------------------------------------------ what each graph computes
def _vq_encoder(model: ProbTalk, motion: torch.Tensor) -> torch.Tensor:
    return model.vq.encode(motion)


def _vq_decoder(model: ProbTalk, codes: torch.Tensor) -> torch.Tensor:
    return model.vq.decode(codes)


def _predictor_memory(
    model: ProbTalk, audio: torch.Tensor, known: torch.Tensor, known_mask: torch.Tensor, speaker: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    assert model.predictor is not None
    return model.predictor.memory(model.audio_norm(audio), known, known_mask, speaker)


def _predictor_step(
    model: ProbTalk, tokens: torch.Tensor, keys: torch.Tensor, values: torch.Tensor, styles: torch.Tensor
) -> torch.Tensor:
    assert model.predictor is not None
    return model.predictor.logits(tokens, keys, values, styles)


def _refiner(
    model: ProbTalk, motion: torch.Tensor, audio: torch.Tensor, known_mask: torch.Tensor, speaker: torch.Tensor
) -> torch.Tensor:
    assert model.refiner is not None
    return model.refiner(motion, model.audio_norm(audio), known_mask, speaker)


# ------------------------------------------------------------------ example inputs of the parity check
class _Inputs:
    """Random inputs of the shapes the graphs take, for ``TAKES`` rows."""

    def __init__(self, model: ProbTalk, spec: DataSpec) -> None:
        self.config = model.config
        self.bands = int(spec.info["corpus"]["audio_features"]["bands"])
        self.speakers = max(1, len(spec.info["speakers"]))

    @staticmethod
    def f32(rng: np.random.Generator, *shape: int) -> torch.Tensor:
        return torch.from_numpy(rng.standard_normal(shape).astype(np.float32))

    @staticmethod
    def known_mask(rng: np.random.Generator, frames: int) -> torch.Tensor:
        m = np.zeros((TAKES, frames, 1), np.float32)
        m[0, : int(rng.integers(frames + 1))] = 1.0
        return torch.from_numpy(m)

    def codes(self, rng: np.random.Generator, tokens: int) -> torch.Tensor:
        return torch.from_numpy(rng.integers(self.config.codes, size=(TAKES, tokens, self.config.groups)))

    def speaker(self, rng: np.random.Generator) -> torch.Tensor:
        return torch.from_numpy(rng.integers(self.speakers, size=TAKES))

    def audio(self, rng: np.random.Generator, frames: int) -> torch.Tensor:
        return torch.from_numpy((rng.standard_normal((TAKES, frames, 2, self.bands)) * 3 - 8).astype(np.float32))


# ------------------------------------------------------------------------------------- the graphs
def export_graphs(model: ProbTalk, spec: DataSpec) -> list[GraphSpec]:
    """The graphs of every stage ``model`` has."""
    ex = _Inputs(model, spec)
    f, g = model.config.frames_per_token, model.config.groups
    graphs = [
        GraphSpec(
            "vq_decoder",
            GraphModule(model, _vq_decoder).eval(),
            ("codes",),
            ("motion",),
            lambda n, rng: (ex.codes(rng, n),),
            {"codes": {0: "takes", 1: "tokens"}},
            description=f"(takes, tokens, {g}) codes -> (takes, {f}*tokens, {DIM}) normalised motion",
        )
    ]
    if model.stage == "vq":
        graphs.insert(
            0,
            GraphSpec(
                "vq_encoder",
                GraphModule(model, _vq_encoder).eval(),
                ("motion",),
                ("codes",),
                lambda n, rng: (ex.f32(rng, TAKES, f * n, DIM),),
                {"motion": _token_frames(f)},
                description=f"(takes, frames, {DIM}) normalised motion, frames a multiple of {f} -> (takes, frames/{f}, {g}) codes",
            ),
        )
    if model.predictor is not None:
        graphs += _predictor_graphs(model, ex)
    if model.refiner is not None:
        graphs.append(_refiner_graph(model, ex))
    return graphs


def _token_frames(f: int) -> dict[int, str]:
    """A frames axis of whole tokens: a network that downsamples by ``f`` takes only those."""
    return {0: "takes", 1: f"{f}*tokens"}


def _predictor_graphs(model: ProbTalk, ex: _Inputs) -> list[GraphSpec]:
    config = model.config
    f, g = config.frames_per_token, config.groups
    heads, width, layers = config.heads, config.width, config.layers

    def memory_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        frames = f * n
        return ex.audio(rng, frames), ex.f32(rng, TAKES, frames, DIM), ex.known_mask(rng, frames), ex.speaker(rng)

    def step_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        tokens = rng.integers(config.codes + 1, size=(TAKES, n * g))
        kv = (layers, TAKES, heads, n, width // heads)
        return (
            torch.from_numpy(tokens),
            ex.f32(rng, *kv),
            ex.f32(rng, *kv),
            ex.f32(rng, layers, TAKES, 6, width) * 0.1,
        )

    kv_axes = {1: "takes", 3: "memory"}
    token_frames = _token_frames(f)
    return [
        GraphSpec(
            "predictor_memory",
            GraphModule(model, _predictor_memory).eval(),
            ("audio", "known", "known_mask", "speaker"),
            ("keys", "values", "styles"),
            memory_inputs,
            {"audio": token_frames, "known": token_frames, "known_mask": token_frames, "speaker": {0: "takes"}},
            description=(
                f"once per window: (takes, frames, 2, {ex.bands}) log-mel, (takes, frames, {DIM}) known motion, "
                f"(takes, frames, 1) known mask, (takes,) speaker -> per layer cross-attention keys and values "
                f"({layers}, takes, {heads}, frames/{f}, {width // heads}) and speaker modulation ({layers}, takes, 6, {width})"
            ),
        ),
        GraphSpec(
            "predictor_step",
            GraphModule(model, _predictor_step).eval(),
            ("tokens", "keys", "values", "styles"),
            ("logits",),
            step_inputs,
            {"tokens": {0: "takes", 1: "tokens"}, "keys": kv_axes, "values": kv_axes, "styles": {1: "takes"}},
            description=f"once per MaskGIT pass: (takes, tokens*{g}) ids ({config.mask_id} = masked) and the memory -> (takes, tokens*{g}, {config.codes}) logits",
        ),
    ]


def _refiner_graph(model: ProbTalk, ex: _Inputs) -> GraphSpec:
    f = model.config.frames_per_token

    def refiner_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        frames = f * n + int(rng.integers(f))  # the refiner takes any number of frames
        return ex.f32(rng, TAKES, frames, DIM), ex.audio(rng, frames), ex.known_mask(rng, frames), ex.speaker(rng)

    frames_axes = {0: "takes", 1: "frames"}
    return GraphSpec(
        "refiner",
        GraphModule(model, _refiner).eval(),
        ("motion", "audio", "known_mask", "speaker"),
        ("refined",),
        refiner_inputs,
        {"motion": frames_axes, "audio": frames_axes, "known_mask": frames_axes, "speaker": {0: "takes"}},
        description=f"(takes, frames, {DIM}) coarse motion with known frames in, log-mel, known mask, speaker -> refined motion",
        float_from=("motion",),  # the face's small movements survive only a float input projection
    )
