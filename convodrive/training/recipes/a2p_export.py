"""The ONNX graphs of an ``a2p`` stage: what ``convodrive.generators.a2p`` runs in ONNX Runtime.

Per denoiser (``face``, ``body``, and their distilled ``*_student``) two graphs: ``*_memory``, the
window's conditions -> each layer's cross-attention keys and values and the FiLM vector (once per
window, for the conditional and unconditional rows at once), and ``*_step``, noisy motion at a
diffusion step + that memory -> x0 (once per step). Then ``lip`` (the lip regressor),
``guide_audio`` (per-second audio embeddings), ``guide_step`` (one autoregressive step, the KV
cache in and out) and ``vq_decoder`` (codes -> 1 fps body poses). Audio enters every graph as the
corpus stores it (log-mel, both voices); the graphs standardise it themselves.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import BODY, FACE, FPS, LIP_OUTPUTS
from convodrive.models.a2p_denoiser import Denoiser, Memory
from convodrive.training.recipe import DataSpec, GraphModule, GraphSpec

TAKES = 2
FACE_DIM, BODY_DIM = FACE.stop - FACE.start, BODY.stop - BODY.start
FRAMES = {0: "batch", 1: "frames"}
KV = {1: "batch", 3: "frames"}
BATCH = {0: "batch"}


# ------------------------------------------------------------------------ what each graph computes
def _lip(model: A2P, audio: torch.Tensor) -> torch.Tensor:
    assert model.lip is not None
    return model.lip(model.audio_norm(audio))


def _face_memory(
    name: str, model: A2P, audio: torch.Tensor, lip: torch.Tensor, keep: torch.Tensor, speaker: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    memory = getattr(model, name).memory([model.audio_norm(audio), lip], keep, speaker)
    return memory.keys[0], memory.values[0], memory.film


def _face_step(
    net: Denoiser,
    noisy: torch.Tensor,
    step: torch.Tensor,
    known: torch.Tensor,
    known_mask: torch.Tensor,
    keys: torch.Tensor,
    values: torch.Tensor,
    film: torch.Tensor,
    guidance: torch.Tensor | None = None,
) -> torch.Tensor:
    return net.step(noisy, step, known, known_mask, Memory([keys], [values], [None], film), guidance)


def _body_memory(
    name: str,
    model: A2P,
    audio: torch.Tensor,
    guide: torch.Tensor,
    guide_positions: torch.Tensor,
    guide_valid: torch.Tensor,
    keep: torch.Tensor,
    speaker: torch.Tensor,
) -> tuple[torch.Tensor, ...]:
    net = getattr(model, name)
    memory = net.memory([model.audio_norm(audio)], keep, speaker, guide, guide_positions, guide_valid)
    bias = memory.biases[1]
    assert bias is not None
    return memory.keys[0], memory.values[0], memory.keys[1], memory.values[1], bias, memory.film


def _body_step(
    net: Denoiser,
    noisy: torch.Tensor,
    step: torch.Tensor,
    known: torch.Tensor,
    known_mask: torch.Tensor,
    audio_keys: torch.Tensor,
    audio_values: torch.Tensor,
    guide_keys: torch.Tensor,
    guide_values: torch.Tensor,
    guide_bias: torch.Tensor,
    film: torch.Tensor,
    guidance: torch.Tensor | None = None,
) -> torch.Tensor:
    memory = Memory([audio_keys, guide_keys], [audio_values, guide_values], [None, guide_bias], film)
    return net.step(noisy, step, known, known_mask, memory, guidance)


def _guide_audio(model: A2P, chunks: torch.Tensor) -> torch.Tensor:
    assert model.guide is not None
    b, s, f, c, bands = chunks.shape
    heard = model.audio_norm(chunks.reshape(b, s * f, c, bands)).reshape(b, s, f, c * bands)
    return model.guide.audio_memory(heard)


def _guide_step(model: A2P, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """token, position, audio, past_keys, past_values, speaker -> logits, keys, values."""
    assert model.guide is not None
    return model.guide.step(*inputs)


def _vq_decoder(model: A2P, codes: torch.Tensor) -> torch.Tensor:
    assert model.vq is not None
    return model.vq.decode(codes)


# ------------------------------------------------------------------ example inputs of the parity check
class _Inputs:
    """Random inputs of the shapes the graphs take, for ``TAKES`` rows."""

    def __init__(self, model: A2P, spec: DataSpec) -> None:
        self.config = model.config
        self.bands = int(spec.info["corpus"]["audio_features"]["bands"])
        self.speakers = max(1, len(spec.info["speakers"]))

    @staticmethod
    def f32(rng: np.random.Generator, *shape: int) -> torch.Tensor:
        return torch.from_numpy(rng.standard_normal(shape).astype(np.float32))

    @staticmethod
    def audio(rng: np.random.Generator, *shape: int) -> torch.Tensor:
        return torch.from_numpy((rng.standard_normal(shape) * 3 - 8).astype(np.float32))

    def speaker(self, rng: np.random.Generator, n: int = TAKES) -> torch.Tensor:
        return torch.from_numpy(rng.integers(self.speakers, size=n))

    @staticmethod
    def keep(rng: np.random.Generator) -> torch.Tensor:
        return torch.from_numpy(rng.integers(2, size=(TAKES, 2)).astype(np.float32))

    @staticmethod
    def known_mask(rng: np.random.Generator, frames: int) -> torch.Tensor:
        m = np.zeros((TAKES, frames, 1), np.float32)
        m[0, : int(rng.integers(frames + 1))] = 1.0
        return torch.from_numpy(m)

    def steps(self, rng: np.random.Generator) -> torch.Tensor:
        return torch.from_numpy(rng.integers(self.config.diffusion_steps, size=TAKES))

    def guides(self, rng: np.random.Generator, frames: int) -> tuple[torch.Tensor, ...]:
        count = frames // FPS + 2
        positions = (np.arange(count) * FPS - FPS + rng.integers(FPS)).astype(np.float32)
        valid = (rng.random((TAKES, count)) > 0.3).astype(np.float32)
        return (
            self.f32(rng, TAKES, count, BODY_DIM),
            torch.from_numpy(np.tile(positions, (TAKES, 1))),
            torch.from_numpy(valid),
        )

    def step_start(self, rng: np.random.Generator, n: int, dim: int) -> tuple[torch.Tensor, ...]:
        """A denoiser step's first inputs: noisy motion, step, known motion, known mask."""
        return self.f32(rng, TAKES, n, dim), self.steps(rng), self.f32(rng, TAKES, n, dim), self.known_mask(rng, n)

    def kv(self, rng: np.random.Generator, net: Denoiser, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        heads = net.layers[0].self_attention.heads
        shape = (len(net.layers), TAKES, heads, n, net.width // heads)
        return self.f32(rng, *shape), self.f32(rng, *shape)

    @staticmethod
    def guidance(rng: np.random.Generator, high: float, student: bool) -> tuple[torch.Tensor, ...]:
        return (torch.from_numpy(rng.uniform(1, high, TAKES).astype(np.float32)),) if student else ()


# ------------------------------------------------------------------------------------- the graphs
def export_graphs(model: A2P, spec: DataSpec) -> list[GraphSpec]:
    """The graphs of every network ``model`` holds; example sizes count frames (denoisers, lip),
    seconds (guide audio, VQ decoder) or cached positions (guide step)."""
    ex = _Inputs(model, spec)
    graphs: list[GraphSpec] = []
    if model.lip is not None:
        graphs.append(
            GraphSpec(
                "lip",
                GraphModule(model, _lip).eval(),
                ("audio",),
                ("lip",),
                lambda n, rng: (ex.audio(rng, TAKES, n, 2, ex.bands),),
                {"audio": FRAMES},
                description=f"(batch, frames, 2, {ex.bands}) log-mel, the voice to read first -> (batch, frames, {LIP_OUTPUTS}) mouth features and its voice activity",
            )
        )
    for name in ("face", "face_student"):
        if getattr(model, name) is not None:
            graphs += _face_graphs(model, name, ex)
    for name in ("body", "body_student"):
        if getattr(model, name) is not None:
            graphs += _body_graphs(model, name, ex)
    if model.guide is not None:
        graphs += _guide_graphs(model, ex)
    if model.vq is not None:
        config = model.config

        def codes(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            return (torch.from_numpy(rng.integers(config.vq_codes, size=(TAKES, n, config.vq_levels))),)

        graphs.append(
            GraphSpec(
                "vq_decoder",
                GraphModule(model, _vq_decoder).eval(),
                ("codes",),
                ("poses",),
                codes,
                {"codes": {0: "batch", 1: "seconds"}},
                description=f"(batch, seconds, {config.vq_levels}) codes -> (batch, seconds, {BODY_DIM}) normalised body poses at 1 fps; pose k depends on codes k-7..k",
            )
        )
    return graphs


def _face_graphs(model: A2P, name: str, ex: _Inputs) -> list[GraphSpec]:
    net: Denoiser = getattr(model, name)
    student = net.guidance is not None

    def memory_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        return ex.audio(rng, TAKES, n, 2, ex.bands), ex.f32(rng, TAKES, n, LIP_OUTPUTS), ex.keep(rng), ex.speaker(rng)

    def step_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        start = ex.step_start(rng, n, FACE_DIM)
        return (*start, *ex.kv(rng, net, n), ex.f32(rng, TAKES, net.width), *ex.guidance(rng, 5, student))

    guidance = ("guidance",) if student else ()
    return [
        GraphSpec(
            f"{name}_memory",
            GraphModule(model, functools.partial(_face_memory, name)).eval(),
            ("audio", "lip", "keep", "speaker"),
            ("keys", "values", "film"),
            memory_inputs,
            {"audio": FRAMES, "lip": FRAMES, "keep": BATCH, "speaker": BATCH},
            description="once per window: log-mel, lip regressor output, keep flags (audio, lip), speaker -> cross-attention keys and values per layer, FiLM vector",
        ),
        GraphSpec(
            f"{name}_step",
            GraphModule(net, _face_step).eval(),
            ("noisy", "step", "known", "known_mask", "keys", "values", "film", *guidance),
            ("x0",),
            step_inputs,
            {
                "noisy": FRAMES,
                "step": BATCH,
                "known": FRAMES,
                "known_mask": FRAMES,
                "keys": KV,
                "values": KV,
                "film": BATCH,
                **{g: BATCH for g in guidance},
            },
            description=f"once per denoising step: noisy face (batch, frames, {FACE_DIM}) at a step, known frames and mask, the memory"
            + (", the guidance scale" if student else "")
            + " -> x0",
        ),
    ]


def _body_graphs(model: A2P, name: str, ex: _Inputs) -> list[GraphSpec]:
    net: Denoiser = getattr(model, name)
    student = net.guidance is not None

    def memory_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        return (ex.audio(rng, TAKES, n, 2, ex.bands), *ex.guides(rng, n), ex.keep(rng), ex.speaker(rng))

    def step_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        heads = net.layers[0].self_attention.heads
        count = n // FPS + 3
        bias = np.where(rng.random((TAKES, 1, 1, count)) > 0.3, 0.0, -1e9).astype(np.float32)
        bias[..., 0] = 0.0
        start = ex.step_start(rng, n, BODY_DIM)
        audio_kv = ex.kv(rng, net, n)
        gshape = (len(net.layers), TAKES, heads, count, net.width // heads)
        guide_kv = ex.f32(rng, *gshape), ex.f32(rng, *gshape)
        film = ex.f32(rng, TAKES, net.width)
        return (*start, *audio_kv, *guide_kv, torch.from_numpy(bias), film, *ex.guidance(rng, 3, student))

    guides = {0: "batch", 1: "guides"}
    gkv = {1: "batch", 3: "guide_tokens"}
    guidance = ("guidance",) if student else ()
    step_names = ("noisy", "step", "known", "known_mask", "audio_keys", "audio_values", "guide_keys", "guide_values")
    return [
        GraphSpec(
            f"{name}_memory",
            GraphModule(model, functools.partial(_body_memory, name)).eval(),
            ("audio", "guide", "guide_positions", "guide_valid", "keep", "speaker"),
            ("audio_keys", "audio_values", "guide_keys", "guide_values", "guide_bias", "film"),
            memory_inputs,
            {
                "audio": FRAMES,
                "guide": guides,
                "guide_positions": guides,
                "guide_valid": guides,
                "keep": BATCH,
                "speaker": BATCH,
            },
            description=f"once per window: log-mel, guide poses (batch, guides, {BODY_DIM}) at frame positions with valid flags, keep flags (audio, guide), speaker -> keys and values of both cross-attentions, guide score bias, FiLM vector",
        ),
        GraphSpec(
            f"{name}_step",
            GraphModule(net, _body_step).eval(),
            (*step_names, "guide_bias", "film", *guidance),
            ("x0",),
            step_inputs,
            {
                "noisy": FRAMES,
                "step": BATCH,
                "known": FRAMES,
                "known_mask": FRAMES,
                "audio_keys": KV,
                "audio_values": KV,
                "guide_keys": gkv,
                "guide_values": gkv,
                "guide_bias": {0: "batch", 3: "guide_tokens"},
                "film": BATCH,
                **{g: BATCH for g in guidance},
            },
            description=f"once per denoising step: noisy body (batch, frames, {BODY_DIM}), step, known frames and mask, the memory"
            + (", the guidance scale" if student else "")
            + " -> x0",
        ),
    ]


def _guide_graphs(model: A2P, ex: _Inputs) -> list[GraphSpec]:
    guide, config = model.guide, model.config
    assert guide is not None
    head_dim = config.guide_width // config.guide_heads

    def audio_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        return (ex.audio(rng, TAKES, n, FPS, 2, ex.bands),)

    def step_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
        past = min(n, config.guide_band - 1)
        shape = (config.guide_layers, TAKES, config.guide_heads, past, head_dim)
        return (
            torch.from_numpy(rng.integers(guide.codes + 1, size=(TAKES, 1))),
            torch.from_numpy(np.full((TAKES, 1), n + 100, np.int64)),
            ex.f32(rng, TAKES, config.guide_audio_span, config.guide_width),
            ex.f32(rng, *shape),
            ex.f32(rng, *shape),
            ex.speaker(rng),
        )

    cache = {1: "batch", 3: "past"}
    return [
        GraphSpec(
            "guide_audio",
            GraphModule(model, _guide_audio).eval(),
            ("chunks",),
            ("audio",),
            audio_inputs,
            {"chunks": {0: "batch", 1: "seconds"}},
            description=f"(batch, seconds, {FPS}, 2, {ex.bands}) log-mel of each second (centred on its pose frame) -> (batch, seconds, {config.guide_width}) embeddings",
        ),
        GraphSpec(
            "guide_step",
            GraphModule(model, _guide_step).eval(),
            ("token", "position", "audio", "past_keys", "past_values", "speaker"),
            ("logits", "keys", "values"),
            step_inputs,
            {
                "token": BATCH,
                "position": BATCH,
                "audio": BATCH,
                "past_keys": cache,
                "past_values": cache,
                "speaker": BATCH,
            },
            description=f"one token: the input token (batch, 1) at its position, the {config.guide_audio_span} seconds of audio it hears, the KV cache ({config.guide_layers}, batch, {config.guide_heads}, past, {head_dim}) -> next-code logits, the cache with this position appended",
        ),
    ]
