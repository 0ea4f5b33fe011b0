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

import numpy as np
import torch
from torch import nn

from convodrive.models.a2p import A2P
from convodrive.models.a2p_config import BODY, FACE, FPS, LIP_OUTPUTS
from convodrive.models.a2p_denoiser import Denoiser, Memory
from convodrive.training.recipe import DataSpec, GraphSpec

TAKES = 2


class _Graph(nn.Module):
    """One graph's view of the model (its ``forward`` is the graph)."""

    def __init__(self, model: A2P) -> None:
        super().__init__()
        self.model = model


class _Lip(_Graph):
    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        assert self.model.lip is not None
        return self.model.lip(self.model.audio_norm(audio))


class _FaceMemory(nn.Module):
    def __init__(self, model: A2P, net: Denoiser) -> None:
        super().__init__()
        self.model, self.net = model, net

    def forward(
        self, audio: torch.Tensor, lip: torch.Tensor, keep: torch.Tensor, speaker: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        memory = self.net.memory([self.model.audio_norm(audio), lip], keep, speaker)
        return memory.keys[0], memory.values[0], memory.film


class _FaceStep(nn.Module):
    def __init__(self, net: Denoiser) -> None:
        super().__init__()
        self.net = net

    def forward(
        self,
        noisy: torch.Tensor,
        step: torch.Tensor,
        known: torch.Tensor,
        known_mask: torch.Tensor,
        keys: torch.Tensor,
        values: torch.Tensor,
        film: torch.Tensor,
        guidance: torch.Tensor | None = None,
    ) -> torch.Tensor:
        return self.net.step(noisy, step, known, known_mask, Memory([keys], [values], [None], film), guidance)


class _BodyMemory(nn.Module):
    def __init__(self, model: A2P, net: Denoiser) -> None:
        super().__init__()
        self.model, self.net = model, net

    def forward(
        self,
        audio: torch.Tensor,
        guide: torch.Tensor,
        guide_positions: torch.Tensor,
        guide_valid: torch.Tensor,
        keep: torch.Tensor,
        speaker: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        memory = self.net.memory([self.model.audio_norm(audio)], keep, speaker, guide, guide_positions, guide_valid)
        bias = memory.biases[1]
        assert bias is not None
        return memory.keys[0], memory.values[0], memory.keys[1], memory.values[1], bias, memory.film


class _BodyStep(nn.Module):
    def __init__(self, net: Denoiser) -> None:
        super().__init__()
        self.net = net

    def forward(
        self,
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
        return self.net.step(noisy, step, known, known_mask, memory, guidance)


class _GuideAudio(_Graph):
    def forward(self, chunks: torch.Tensor) -> torch.Tensor:
        assert self.model.guide is not None
        b, s, f, c, bands = chunks.shape
        heard = self.model.audio_norm(chunks.reshape(b, s * f, c, bands)).reshape(b, s, f, c * bands)
        return self.model.guide.audio_memory(heard)


class _GuideStep(_Graph):
    def forward(
        self,
        token: torch.Tensor,
        position: torch.Tensor,
        audio: torch.Tensor,
        past_keys: torch.Tensor,
        past_values: torch.Tensor,
        speaker: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        assert self.model.guide is not None
        return self.model.guide.step(token, position, audio, past_keys, past_values, speaker)


class _VQDecoder(_Graph):
    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        assert self.model.vq is not None
        return self.model.vq.decode(codes)


def export_graphs(model: A2P, spec: DataSpec) -> list[GraphSpec]:
    """The graphs of every network ``model`` holds; example sizes count frames (denoisers, lip),
    seconds (guide audio, VQ decoder) or cached positions (guide step)."""
    config = model.config
    bands = int(spec.info["corpus"]["audio_features"]["bands"])
    speakers = max(1, len(spec.info["speakers"]))
    face_dim, body_dim = FACE.stop - FACE.start, BODY.stop - BODY.start

    def f32(rng: np.random.Generator, *shape: int) -> torch.Tensor:
        return torch.from_numpy(rng.standard_normal(shape).astype(np.float32))

    def audio(rng: np.random.Generator, *shape: int) -> torch.Tensor:
        return torch.from_numpy((rng.standard_normal(shape) * 3 - 8).astype(np.float32))

    def speaker(rng: np.random.Generator, n: int = TAKES) -> torch.Tensor:
        return torch.from_numpy(rng.integers(speakers, size=n))

    def keep(rng: np.random.Generator) -> torch.Tensor:
        return torch.from_numpy(rng.integers(2, size=(TAKES, 2)).astype(np.float32))

    def known_mask(rng: np.random.Generator, frames: int) -> torch.Tensor:
        m = np.zeros((TAKES, frames, 1), np.float32)
        m[0, : int(rng.integers(frames + 1))] = 1.0
        return torch.from_numpy(m)

    def steps(rng: np.random.Generator) -> torch.Tensor:
        return torch.from_numpy(rng.integers(config.diffusion_steps, size=TAKES))

    def guides(rng: np.random.Generator, frames: int) -> tuple[torch.Tensor, ...]:
        count = frames // FPS + 2
        positions = (np.arange(count) * FPS - FPS + rng.integers(FPS)).astype(np.float32)
        valid = (rng.random((TAKES, count)) > 0.3).astype(np.float32)
        return (
            f32(rng, TAKES, count, body_dim),
            torch.from_numpy(np.tile(positions, (TAKES, 1))),
            torch.from_numpy(valid),
        )

    frames = {0: "batch", 1: "frames"}
    kv = {1: "batch", 3: "frames"}
    graphs: list[GraphSpec] = []
    if model.lip is not None:
        graphs.append(
            GraphSpec(
                "lip",
                _Lip(model).eval(),
                ("audio",),
                ("lip",),
                lambda n, rng: (audio(rng, TAKES, n, 2, bands),),
                {"audio": frames},
                description=f"(batch, frames, 2, {bands}) log-mel, the voice to read first -> (batch, frames, {LIP_OUTPUTS}) mouth features and its voice activity",
            )
        )
    for name in ("face", "face_student"):
        net = getattr(model, name)
        if net is None:
            continue
        student = net.guidance is not None

        def face_memory_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            return audio(rng, TAKES, n, 2, bands), f32(rng, TAKES, n, LIP_OUTPUTS), keep(rng), speaker(rng)

        def face_step_inputs(
            n: int, rng: np.random.Generator, net: Denoiser = net, student: bool = student
        ) -> tuple[torch.Tensor, ...]:
            heads = net.layers[0].self_attention.heads
            shape = (len(net.layers), TAKES, heads, n, net.width // heads)
            inputs = (
                f32(rng, TAKES, n, face_dim),
                steps(rng),
                f32(rng, TAKES, n, face_dim),
                known_mask(rng, n),
                f32(rng, *shape),
                f32(rng, *shape),
                f32(rng, TAKES, net.width),
            )
            return inputs + ((torch.from_numpy(rng.uniform(1, 5, TAKES).astype(np.float32)),) if student else ())

        step_names = ("noisy", "step", "known", "known_mask", "keys", "values", "film") + (
            ("guidance",) if student else ()
        )
        graphs += [
            GraphSpec(
                f"{name}_memory",
                _FaceMemory(model, net).eval(),
                ("audio", "lip", "keep", "speaker"),
                ("keys", "values", "film"),
                face_memory_inputs,
                {"audio": frames, "lip": frames, "keep": {0: "batch"}, "speaker": {0: "batch"}},
                description="once per window: log-mel, lip regressor output, keep flags (audio, lip), speaker -> cross-attention keys and values per layer, FiLM vector",
            ),
            GraphSpec(
                f"{name}_step",
                _FaceStep(net).eval(),
                step_names,
                ("x0",),
                face_step_inputs,
                {
                    "noisy": frames,
                    "step": {0: "batch"},
                    "known": frames,
                    "known_mask": frames,
                    "keys": kv,
                    "values": kv,
                    "film": {0: "batch"},
                    **({"guidance": {0: "batch"}} if student else {}),
                },
                description=f"once per denoising step: noisy face (batch, frames, {face_dim}) at a step, known frames and mask, the memory"
                + (", the guidance scale" if student else "")
                + " -> x0",
            ),
        ]
    for name in ("body", "body_student"):
        net = getattr(model, name)
        if net is None:
            continue
        student = net.guidance is not None

        def body_memory_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            return (audio(rng, TAKES, n, 2, bands), *guides(rng, n), keep(rng), speaker(rng))

        def body_step_inputs(
            n: int, rng: np.random.Generator, net: Denoiser = net, student: bool = student
        ) -> tuple[torch.Tensor, ...]:
            heads = net.layers[0].self_attention.heads
            count = n // FPS + 3
            shape = (len(net.layers), TAKES, heads, n, net.width // heads)
            gshape = (len(net.layers), TAKES, heads, count, net.width // heads)
            bias = np.where(rng.random((TAKES, 1, 1, count)) > 0.3, 0.0, -1e9).astype(np.float32)
            bias[..., 0] = 0.0
            inputs = (
                f32(rng, TAKES, n, body_dim),
                steps(rng),
                f32(rng, TAKES, n, body_dim),
                known_mask(rng, n),
                f32(rng, *shape),
                f32(rng, *shape),
                f32(rng, *gshape),
                f32(rng, *gshape),
                torch.from_numpy(bias),
                f32(rng, TAKES, net.width),
            )
            return inputs + ((torch.from_numpy(rng.uniform(1, 3, TAKES).astype(np.float32)),) if student else ())

        gkv = {1: "batch", 3: "guide_tokens"}
        step_names = (
            "noisy",
            "step",
            "known",
            "known_mask",
            "audio_keys",
            "audio_values",
            "guide_keys",
            "guide_values",
            "guide_bias",
            "film",
        ) + (("guidance",) if student else ())
        graphs += [
            GraphSpec(
                f"{name}_memory",
                _BodyMemory(model, net).eval(),
                ("audio", "guide", "guide_positions", "guide_valid", "keep", "speaker"),
                ("audio_keys", "audio_values", "guide_keys", "guide_values", "guide_bias", "film"),
                body_memory_inputs,
                {
                    "audio": frames,
                    "guide": {0: "batch", 1: "guides"},
                    "guide_positions": {0: "batch", 1: "guides"},
                    "guide_valid": {0: "batch", 1: "guides"},
                    "keep": {0: "batch"},
                    "speaker": {0: "batch"},
                },
                description=f"once per window: log-mel, guide poses (batch, guides, {body_dim}) at frame positions with valid flags, keep flags (audio, guide), speaker -> keys and values of both cross-attentions, guide score bias, FiLM vector",
            ),
            GraphSpec(
                f"{name}_step",
                _BodyStep(net).eval(),
                step_names,
                ("x0",),
                body_step_inputs,
                {
                    "noisy": frames,
                    "step": {0: "batch"},
                    "known": frames,
                    "known_mask": frames,
                    "audio_keys": kv,
                    "audio_values": kv,
                    "guide_keys": gkv,
                    "guide_values": gkv,
                    "guide_bias": {0: "batch", 3: "guide_tokens"},
                    "film": {0: "batch"},
                    **({"guidance": {0: "batch"}} if student else {}),
                },
                description=f"once per denoising step: noisy body (batch, frames, {body_dim}), step, known frames and mask, the memory"
                + (", the guidance scale" if student else "")
                + " -> x0",
            ),
        ]
    if model.guide is not None:
        guide = model.guide
        head_dim = config.guide_width // config.guide_heads

        def audio_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            return (audio(rng, TAKES, n, FPS, 2, bands),)

        def step_inputs(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            past = min(n, config.guide_band - 1)
            shape = (config.guide_layers, TAKES, config.guide_heads, past, head_dim)
            return (
                torch.from_numpy(rng.integers(guide.codes + 1, size=(TAKES, 1))),
                torch.from_numpy(np.full((TAKES, 1), n + 100, np.int64)),
                f32(rng, TAKES, config.guide_audio_span, config.guide_width),
                f32(rng, *shape),
                f32(rng, *shape),
                speaker(rng),
            )

        cache = {1: "batch", 3: "past"}
        graphs += [
            GraphSpec(
                "guide_audio",
                _GuideAudio(model).eval(),
                ("chunks",),
                ("audio",),
                audio_inputs,
                {"chunks": {0: "batch", 1: "seconds"}},
                description=f"(batch, seconds, {FPS}, 2, {bands}) log-mel of each second (centred on its pose frame) -> (batch, seconds, {config.guide_width}) embeddings",
            ),
            GraphSpec(
                "guide_step",
                _GuideStep(model).eval(),
                ("token", "position", "audio", "past_keys", "past_values", "speaker"),
                ("logits", "keys", "values"),
                step_inputs,
                {
                    "token": {0: "batch"},
                    "position": {0: "batch"},
                    "audio": {0: "batch"},
                    "past_keys": cache,
                    "past_values": cache,
                    "speaker": {0: "batch"},
                },
                description=f"one token: the input token (batch, 1) at its position, the {config.guide_audio_span} seconds of audio it hears, the KV cache ({config.guide_layers}, batch, {config.guide_heads}, past, {head_dim}) -> next-code logits, the cache with this position appended",
            ),
        ]
    if model.vq is not None:

        def codes(n: int, rng: np.random.Generator) -> tuple[torch.Tensor, ...]:
            return (torch.from_numpy(rng.integers(config.vq_codes, size=(TAKES, n, config.vq_levels))),)

        graphs.append(
            GraphSpec(
                "vq_decoder",
                _VQDecoder(model).eval(),
                ("codes",),
                ("poses",),
                codes,
                {"codes": {0: "batch", 1: "seconds"}},
                description=f"(batch, seconds, {config.vq_levels}) codes -> (batch, seconds, {body_dim}) normalised body poses at 1 fps; pose k depends on codes k-7..k",
            )
        )
    return graphs
