"""audio2photoreal (Ng et al., CVPR 2024): dyadic face and body motion, one readable file.

Five networks, trained one after another (``STAGES``), then distilled:

1. **Lip regressor** (``LipRegressor``): a small transformer from the voice it hears to the mouth
   (jaw rotation and the ARKit mouth and jaw channels) and that voice's activity. The paper's
   hears self only; ours hears both channels (self first), so partner speech that bleeds into
   self's microphone does not open the mouth. Run with the channels swapped it gives the
   partner's voice activity too.
2. **Face denoiser** (``Denoiser``): a FiLM transformer that predicts clean face motion (x0) from
   noisy face motion, the diffusion step (FiLM on every sub-layer) and the known frames of a
   window (the previous window's last frames: continuation by inpainting), cross-attending to a
   memory of both voices' log-mel plus the lip regressor's output (a second condition).
3. **Residual VQ-VAE** (``GuideVQ``): body poses at 1 fps through a causal conv encoder (receptive
   field 8), ``vq_levels`` EMA codebooks each quantising what the previous left, and a causal
   conv decoder.
4. **Guide transformer** (``GuideTransformer``): autoregressive over the VQ tokens flattened
   time-major (s0q0, s0q1, ..., s1q0, ...), FiLM-modulated by the speaker, cross-attending to
   per-second embeddings of both voices. Each token hears its own second's audio and the
   ``guide_audio_span - 1`` seconds before (second k is the half-open frame span centred on
   frame 30k), never later audio, so its look-ahead is half a second. Self-attention reaches the
   last ``guide_band`` tokens, so sampling carries a KV cache of fixed size across any length
   (``step``): each new token costs one step, not a re-run of its prefix.
5. **Body denoiser**: the face denoiser's network over head, upper body and hands, with a second
   cross-attention to the guide poses (placed at their frames) and the reference's causal conv
   stack on its output.

Classifier-free guidance: every condition (audio, lip, guide poses) is dropped on its own in
training (``cond_drop``); at sampling ``Denoiser.memory`` takes a ``keep`` flag per condition, so
the conditional and unconditional memories are one batch and so is every denoising step.

The memory of a window (each layer's cross-attention keys and values, and the FiLM vector of the
conditions) is computed once (``Denoiser.memory``) and reused by every step (``Denoiser.step``);
the runtime exports the two as graphs. Distillation (``distill`` stage) copies each denoiser into a
student that also hears the guidance scale and learns, by consistency distillation from the guided
teacher's DDIM trajectories, to jump to the clean motion in one to four steps.

Not as the paper: log-mel instead of wav2vec features (aligned with the 30 fps frames, so windows
stream); rotary positions in frame units on the per-head queries and keys (the reference rotates
the un-projected inputs); no time tokens in the cross-attention memory (FiLM carries the step);
the guide's FiLM hears the speaker, not the pooled audio of the whole clip (which a stream has not
heard yet). Shapes: motion (B, T, D) normalised features (``convodrive.motion.representation``),
audio (B, T, 2, bands) log-mel of self and partner. Torch is for training and export only.
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.common import AudioNorm
from convodrive.motion import representation as rep
from convodrive.motion.channels import ARKIT_NAMES

STAGES = ("lip", "face", "vq", "guide", "body", "distill")
FACE = rep.GROUPS["face"]
BODY = rep.GROUPS["body"]
VAD = rep.GROUPS["vad"]
FPS = 30
MOUTH_COLUMNS: tuple[int, ...] = tuple(range(rep.PARTS["jaw"].start, rep.PARTS["jaw"].stop)) + tuple(
    rep.PARTS["arkit"].start + i for i, n in enumerate(ARKIT_NAMES) if n.startswith(("mouth", "jaw"))
)
"""Feature columns of the mouth: the jaw rotation and the ARKit jaw and mouth channels."""
LIP_OUTPUTS = len(MOUTH_COLUMNS) + 1
"""The lip regressor's outputs: the mouth columns, then the voice activity of the voice it hears."""


@dataclasses.dataclass(frozen=True)
class A2PConfig:
    """Hyper-parameters; defaults are the reference implementation's (the ``paper`` preset)."""

    # face denoiser
    face_width: int = 512
    face_layers: int = 8
    face_heads: int = 8
    face_feedforward: int = 1024
    face_cond_layers: int = 2
    """Transformer layers over the condition tokens before the face denoiser attends to them."""
    # body denoiser
    body_width: int = 256
    body_layers: int = 6
    body_heads: int = 8
    body_feedforward: int = 1024
    body_post_layers: int = 6
    """Causal dilated convs on the body denoiser's output (the reference's post_pose_layers)."""
    # lip regressor (the reference: 2 encoder + 4 decoder layers, 512-d, 4 heads)
    lip_width: int = 512
    lip_layers: int = 6
    lip_heads: int = 4
    lip_feedforward: int = 1024
    # residual VQ-VAE of 1 fps body poses
    vq_codes: int = 1024
    vq_levels: int = 4
    vq_width: int = 64
    vq_decay: float = 0.99
    vq_commit: float = 0.02
    vq_residual: bool = False
    """Each causal conv of the VQ-VAE adds its output to its input (the reference's stack does not).
    Without it the small preset's VQ-VAE learned a latent that held the hands but not the arms and
    head: its encoder's continuous output reconstructed the test split's 1 fps poses no better than
    its codes (FD_g body 21; 32 principal components of the poses give 1.5), so the guide poses
    kept a third of the real variance of the head and upper body. With it: FD_g body 6.0 (1500 steps)."""
    # guide transformer
    guide_width: int = 64
    guide_layers: int = 6
    guide_heads: int = 4
    guide_feedforward: int = 1024
    guide_band: int = 80
    """Tokens a token's self-attention reaches (itself included): the KV cache's length (20 s)."""
    guide_audio_span: int = 4
    """Seconds of audio a token hears: its own and those before it."""
    guide_seconds: int = 20
    """Seconds per training sequence of the guide (the reference's 600 frames)."""
    top_p: float = 0.94
    # diffusion
    diffusion_steps: int = 1000
    cond_drop: float = 0.2
    """Probability that a training example loses each condition (classifier-free guidance)."""
    face_velocity_weight: float = 0.0
    body_velocity_weight: float = 2.0
    # windows
    window: int = 600
    """Longest training window, and the ``file`` mode's window (frames)."""
    min_window: int = 240
    context: int = 60
    """Known frames a window continues from (the previous window's last ones); trained up to this."""
    dropout: float = 0.1
    # distillation
    distill_skip: int = 20
    """Diffusion steps between neighbouring points of the consistency-distillation grid."""
    distill_ema: float = 0.95
    face_student_steps: int = 0
    """The face student's steps when the generator's ``face_steps`` is 0; 0: as the body's ``steps``."""
    face_guidance_max: float = 10.0
    body_guidance_max: float = 4.0
    """Students learn every guidance scale in [1, max] (the reference samples face 10, body 2)."""

    def check(self) -> None:
        """ValueError naming the first inconsistent setting."""
        for part in ("face", "body", "lip", "guide"):
            if getattr(self, f"{part}_width") % (2 * getattr(self, f"{part}_heads")):
                raise ValueError(f"{part}_width must be a multiple of twice {part}_heads (rotary halves)")
        if not 0 < self.min_window <= self.window or not 0 <= self.context < self.min_window:
            raise ValueError("need 0 <= context < min_window <= window")
        if self.guide_band < 2 or self.guide_audio_span < 1 or self.guide_seconds < 2:
            raise ValueError("guide_band >= 2, guide_audio_span >= 1 and guide_seconds >= 2 are needed")
        if self.diffusion_steps % self.distill_skip:
            raise ValueError("diffusion_steps must be a multiple of distill_skip")


# ------------------------------------------------------------------------------------ attention
def rotate(x: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """Rotary position embedding of (B, H, T, dh) at ``positions`` (B, T), in any unit (frames here)."""
    half = x.shape[-1] // 2
    inverse = torch.exp(
        torch.arange(half, dtype=torch.float32, device=x.device) * (-2.0 * math.log(10000.0) / x.shape[-1])
    )
    angle = (positions.to(torch.float32)[..., None] * inverse)[:, None]
    cos, sin = angle.cos(), angle.sin()
    a, b = x[..., :half], x[..., half:]
    return torch.cat([a * cos - b * sin, a * sin + b * cos], dim=-1)


class Attention(nn.Module):
    """Multi-head attention with rotary positions; keys and values can be made once and reused.
    No dropout on the attention weights: on a CPU it costs a quarter of a training step (the
    fused attention kernel cannot run with it), and the residual branches drop out anyway."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.query = nn.Linear(width, width)
        self.key_value = nn.Linear(width, 2 * width)
        self.out = nn.Linear(width, width)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        return x.reshape(b, t, self.heads, d // self.heads).transpose(1, 2)

    def keys_values(self, memory: torch.Tensor, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, H, S, dh) keys (rotated) and values of ``memory`` (B, S, d)."""
        k, v = self.key_value(memory).chunk(2, dim=-1)
        return rotate(self._split(k), positions), self._split(v)

    def attend(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        keys: torch.Tensor,
        values: torch.Tensor,
        bias: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``x`` (B, T, d) at ``positions`` (B, T) attends to keys and values; ``bias`` is added to
        the scores (0 or -inf, broadcast to (B, H, T, S))."""
        q = rotate(self._split(self.query(x)), positions)
        y = F.scaled_dot_product_attention(q, keys, values, attn_mask=bias)
        b, _, t, _ = y.shape
        return self.out(y.transpose(1, 2).reshape(b, t, -1))

    def forward(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        memory: torch.Tensor,
        memory_positions: torch.Tensor,
        bias: torch.Tensor | None = None,
    ) -> torch.Tensor:
        keys, values = self.keys_values(memory, memory_positions)
        return self.attend(x, positions, keys, values, bias)


class FiLM(nn.Module):
    """Feature-wise linear modulation by a conditioning vector: ``x * (1 + scale) + shift``."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.block = nn.Sequential(nn.Mish(), nn.Linear(width, 2 * width))

    def forward(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        scale, shift = self.block(condition)[:, None].chunk(2, dim=-1)
        return x * (1 + scale) + shift


def feedforward(width: int, hidden: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(nn.Linear(width, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, width))


class EncoderLayer(nn.Module):
    """Pre-norm self-attention and feed-forward (the lip regressor, the face condition encoder)."""

    def __init__(self, width: int, heads: int, hidden: int, dropout: float) -> None:
        super().__init__()
        self.norm1, self.norm2 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.attention = Attention(width, heads)
        self.feedforward = feedforward(width, hidden, dropout)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        h = self.norm1(x)
        x = x + self.drop(self.attention(h, positions, h, positions))
        return x + self.drop(self.feedforward(self.norm2(x)))


class CrossAttention(nn.Module):
    """One cross-attention sub-layer of a FiLM layer: its norm, attention and modulation."""

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.attention = Attention(width, heads)
        self.film = FiLM(width)


class FiLMLayer(nn.Module):
    """The reference's FiLMTransformerDecoderLayer, pre-norm: self-attention, one cross-attention
    per memory, feed-forward; each sub-layer's output modulated by the FiLM vector, then added."""

    def __init__(self, width: int, heads: int, hidden: int, dropout: float, memories: int) -> None:
        super().__init__()
        self.norm1, self.norm3 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.self_attention = Attention(width, heads)
        self.film1, self.film3 = FiLM(width), FiLM(width)
        self.cross = nn.ModuleList(CrossAttention(width, heads) for _ in range(memories))
        self.feedforward = feedforward(width, hidden, dropout)
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        x: torch.Tensor,
        positions: torch.Tensor,
        film: torch.Tensor,
        memories: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]],
        self_bias: torch.Tensor | None = None,
        cache: tuple[torch.Tensor, torch.Tensor] | None = None,
        cross_positions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """``memories``: per cross-attention (keys, values, bias); its queries sit at
        ``cross_positions`` (default ``positions``). ``cache``: earlier keys and values of the
        self-attention (autoregressive steps). Returns the output and the self-attention's keys
        and values (the cache with this call's appended)."""
        h = self.norm1(x)
        keys, values = self.self_attention.keys_values(h, positions)
        if cache is not None:
            keys, values = torch.cat([cache[0], keys], dim=2), torch.cat([cache[1], values], dim=2)
        x = x + self.drop(self.film1(self.self_attention.attend(h, positions, keys, values, self_bias), film))
        cross = positions if cross_positions is None else cross_positions
        for sub, (k, v, bias) in zip(self.cross, memories):
            x = x + self.drop(sub.film(sub.attention.attend(sub.norm(x), cross, k, v, bias), film))
        x = x + self.drop(self.film3(self.feedforward(self.norm3(x)), film))
        return x, (keys, values)


def sinusoid(values: torch.Tensor, dim: int) -> torch.Tensor:
    """(B,) -> (B, dim) sinusoidal embedding (diffusion steps, guidance scales)."""
    half = dim // 2
    freqs = torch.exp(torch.arange(half, dtype=torch.float32, device=values.device) * (-math.log(10000.0) / (half - 1)))
    angle = values.to(torch.float32)[:, None] * freqs
    return torch.cat([angle.sin(), angle.cos()], dim=-1)


def frame_positions(batch: int, length: int, device: torch.device) -> torch.Tensor:
    return torch.arange(length, device=device, dtype=torch.float32)[None].expand(batch, length)


# -------------------------------------------------------------------------------- lip regressor
class LipRegressor(nn.Module):
    """Audio (B, T, 2*bands) normalised, the voice whose mouth it predicts first -> (B, T,
    ``LIP_OUTPUTS``): the mouth columns (normalised features) and that voice's activity."""

    def __init__(self, bands: int, config: A2PConfig) -> None:
        super().__init__()
        w = config.lip_width
        self.input = nn.Linear(2 * bands, w)
        self.layers = nn.ModuleList(
            EncoderLayer(w, config.lip_heads, config.lip_feedforward, config.dropout) for _ in range(config.lip_layers)
        )
        self.norm = nn.LayerNorm(w)
        self.output = nn.Linear(w, LIP_OUTPUTS)

    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        positions = frame_positions(audio.shape[0], audio.shape[1], audio.device)
        x = self.input(audio)
        for layer in self.layers:
            x = layer(x, positions)
        return self.output(self.norm(x))


# ------------------------------------------------------------------------------------ denoisers
@dataclasses.dataclass
class Memory:
    """What a denoiser attends to, made once per window: per layer and cross-attention the keys
    and values (layers, B, H, S, dh) and the score bias, and the FiLM vector of the conditions."""

    keys: list[torch.Tensor]
    values: list[torch.Tensor]
    biases: list[torch.Tensor | None]
    film: torch.Tensor


class PostConv(nn.Module):
    """The reference's post_pose_layers: causal dilated convs (k=3) on the predicted motion,
    averaged with their input; their last projection starts at zero, so training starts from
    the transformer's output."""

    def __init__(self, dim: int, layers: int) -> None:
        super().__init__()
        self.dilations = [(1, 2, 3)[i % 3] for i in range(layers)]
        self.convs = nn.ModuleList(nn.Conv1d(dim, dim, 3, dilation=d) for d in self.dilations)
        self.final = nn.Conv1d(dim, dim, 1)
        nn.init.zeros_(self.final.weight)
        nn.init.zeros_(self.final.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x.transpose(1, 2)
        for conv, d in zip(self.convs, self.dilations):
            h = 0.5 * (h + F.leaky_relu(conv(F.pad(h, (2 * d, 0))), 0.2))
        return x + self.final(h).transpose(1, 2)


class Denoiser(nn.Module):
    """The FiLM transformer denoiser (face or body): x0 from a noisy window.

    Conditions (memory 0): a list of per-frame inputs (audio; for the face also the lip
    regressor's output), each projected and summed into one token per frame; a dropped condition
    is a learned null vector instead. The face runs ``cond_layers`` transformer layers over the
    tokens. The body adds memory 1: its guide poses (B, K, dim) at frame positions, with a learned
    always-present token so that a window without guide poses still attends to something.
    The FiLM vector is the diffusion step's embedding plus the pooled condition tokens, the
    speaker's embedding and, for a distilled student, the guidance scale's embedding.
    """

    def __init__(
        self,
        dim: int,
        conditions: tuple[int, ...],
        width: int,
        layers: int,
        heads: int,
        hidden: int,
        dropout: float,
        speakers: int,
        cond_layers: int = 0,
        guide_dim: int = 0,
        post_layers: int = 0,
        student: bool = False,
    ) -> None:
        super().__init__()
        self.dim, self.width = dim, width
        self.input = nn.Linear(2 * dim + 1, width)
        self.time = nn.Sequential(nn.Linear(width, 4 * width), nn.Mish(), nn.Linear(4 * width, width))
        self.speaker = nn.Embedding(max(1, speakers), width)
        self.condition = nn.ModuleList(nn.Linear(c, width) for c in conditions)
        self.null = nn.Parameter(torch.randn(len(conditions), width) * 0.02)
        self.cond_encoder = nn.ModuleList(EncoderLayer(width, heads, hidden, dropout) for _ in range(cond_layers))
        self.pool = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))
        self.memory_norm = nn.LayerNorm(width)
        self.guided = guide_dim > 0
        if self.guided:
            self.guide_input = nn.Linear(guide_dim, width)
            self.guide_norm = nn.LayerNorm(width)
            self.guide_sink = nn.Parameter(torch.randn(1, 1, width) * 0.02)
        self.layers = nn.ModuleList(
            FiLMLayer(width, heads, hidden, dropout, 2 if self.guided else 1) for _ in range(layers)
        )
        self.norm = nn.LayerNorm(width)
        self.output = nn.Linear(width, dim)
        self.post = PostConv(dim, post_layers) if post_layers else None
        self.guidance: nn.Linear | None = None
        if student:
            self.guidance = nn.Linear(width, width)
            nn.init.zeros_(self.guidance.weight)
            nn.init.zeros_(self.guidance.bias)

    @property
    def conditions(self) -> int:
        return len(self.condition)

    def memory(
        self,
        conditions: list[torch.Tensor],
        keep: torch.Tensor,
        speaker: torch.Tensor,
        guide: torch.Tensor | None = None,
        guide_positions: torch.Tensor | None = None,
        guide_valid: torch.Tensor | None = None,
    ) -> Memory:
        """``conditions`` each (B, T, c_i); ``keep`` (B, n) 1 to hear condition i, 0 to drop it
        (the body's last column drops the guide poses); guide poses (B, K, dim) at
        ``guide_positions`` (B, K) frames of the window, ``guide_valid`` (B, K) 1 where known."""
        b, t = conditions[0].shape[:2]
        tokens = torch.zeros(b, t, self.width, device=conditions[0].device)
        for i, (project, c) in enumerate(zip(self.condition, conditions)):
            k = keep[:, i, None, None]
            tokens = tokens + k * project(c) + (1 - k) * self.null[i]
        positions = frame_positions(b, t, tokens.device)
        for layer in self.cond_encoder:
            tokens = layer(tokens, positions)
        film = self.pool(tokens.mean(dim=1)) + self.speaker(speaker)
        tokens = self.memory_norm(tokens)
        keys, values, biases = [], [], []
        audio_kv = [layer.cross[0].attention.keys_values(tokens, positions) for layer in self.layers]
        keys.append(torch.stack([k for k, _ in audio_kv]))
        values.append(torch.stack([v for _, v in audio_kv]))
        biases.append(None)
        if self.guided:
            assert guide is not None and guide_positions is not None and guide_valid is not None
            sink = self.guide_sink.expand(b, 1, self.width)
            poses = torch.cat([sink, self.guide_input(guide)], dim=1)
            poses = self.guide_norm(poses)
            pos = torch.cat([torch.zeros(b, 1, device=poses.device), guide_positions.to(torch.float32)], dim=1)
            valid = torch.cat([torch.ones(b, 1, device=poses.device), guide_valid * keep[:, -1:]], dim=1)
            guide_kv = [layer.cross[1].attention.keys_values(poses, pos) for layer in self.layers]
            keys.append(torch.stack([k for k, _ in guide_kv]))
            values.append(torch.stack([v for _, v in guide_kv]))
            biases.append(((valid - 1) * 1e9)[:, None, None, :])
        return Memory(keys, values, biases, film)

    def step(
        self,
        noisy: torch.Tensor,
        step: torch.Tensor,
        known: torch.Tensor,
        known_mask: torch.Tensor,
        memory: Memory,
        guidance: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """x0 (B, T, dim) from ``noisy`` (B, T, dim) at diffusion ``step`` (B,), ``known`` frames
        (B, T, dim) where ``known_mask`` (B, T, 1) is 1, and the window's memory."""
        b, t, _ = noisy.shape
        x = self.input(torch.cat([noisy, known * known_mask, known_mask], dim=-1))
        film = self.time(sinusoid(step, self.width)) + memory.film
        if self.guidance is not None:
            assert guidance is not None
            film = film + self.guidance(sinusoid(guidance * 100.0, self.width))
        positions = frame_positions(b, t, x.device)
        for i, layer in enumerate(self.layers):
            memories = [(k[i], v[i], bias) for k, v, bias in zip(memory.keys, memory.values, memory.biases)]
            x, _ = layer(x, positions, film, memories)
        out = self.output(self.norm(x))
        return self.post(out) if self.post is not None else out


# -------------------------------------------------------------------------- residual VQ-VAE
class CausalConvs(nn.Module):
    """1x1 projection, then 4 causal convs (k=2, dilations 1, 2, 3, 1: receptive field 8) with
    LeakyReLU, then a 1x1 projection: the reference's TemporalVertexEncoder/Decoder."""

    DILATIONS = (1, 2, 3, 1)

    def __init__(self, cin: int, width: int, cout: int, residual: bool = False) -> None:
        super().__init__()
        self.residual = residual
        self.input = nn.Conv1d(cin, width, 1)
        self.convs = nn.ModuleList(nn.Conv1d(width, width, 2, dilation=d) for d in self.DILATIONS)
        self.output = nn.Conv1d(width, cout, 1)

    @classmethod
    def receptive_field(cls) -> int:
        return 1 + sum(cls.DILATIONS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, K, cin) -> (B, K, cout); output k depends on inputs k-7..k only."""
        h = self.input(x.transpose(1, 2))
        for conv, d in zip(self.convs, self.DILATIONS):
            step = conv(F.pad(F.leaky_relu(h, 0.2), (d, 0)))
            h = h + step if self.residual else step
        return self.output(F.leaky_relu(h, 0.2)).transpose(1, 2)


class Codebook(nn.Module):
    """One level of the residual quantiser: nearest code by Euclidean distance; codes follow the
    vectors assigned to them by exponential moving average, and codes used less than
    ``DEAD`` times on average are moved to random vectors of the batch (the reference's EMA
    codebook, from Encodec). Its first batch initialises it with random vectors of that batch."""

    DEAD = 2.0
    EPSILON = 1e-5

    def __init__(self, codes: int, dim: int, decay: float) -> None:
        super().__init__()
        self.decay = decay
        self.register_buffer("inited", torch.zeros(()))
        self.register_buffer("embed", torch.randn(codes, dim) * 0.1)
        self.register_buffer("cluster_size", torch.ones(codes))
        self.register_buffer("embed_avg", self.embed.clone())

    def nearest(self, z: torch.Tensor) -> torch.Tensor:
        """(N, dim) -> (N,) code indices."""
        d = (z**2).sum(-1, keepdim=True) - 2 * z @ self.embed.t() + (self.embed**2).sum(-1)[None]
        return d.argmin(dim=-1)

    @torch.no_grad()
    def update(self, z: torch.Tensor, codes: torch.Tensor, generator: torch.Generator | None) -> None:
        """One EMA step from the (N, dim) vectors ``z`` assigned to ``codes`` (summed over DDP ranks)."""
        n = self.embed.shape[0]
        onehot = F.one_hot(codes, n).to(z.dtype)
        count, total = onehot.sum(0), onehot.t() @ z
        samples = z[torch.randint(len(z), (n,), generator=generator).to(z.device)]
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            for tensor in (count, total):
                torch.distributed.all_reduce(tensor)
            torch.distributed.broadcast(samples, 0)
        if not bool(self.inited):
            self.embed.copy_(samples)
            self.embed_avg.copy_(samples)
            self.cluster_size.fill_(1.0)
            self.inited.fill_(1.0)
            return
        self.cluster_size.mul_(self.decay).add_(count, alpha=1 - self.decay)
        self.embed_avg.mul_(self.decay).add_(total, alpha=1 - self.decay)
        size = self.cluster_size.sum()
        smoothed = (self.cluster_size + self.EPSILON) / (size + n * self.EPSILON) * size
        self.embed.copy_(self.embed_avg / smoothed[:, None])
        dead = self.cluster_size < self.DEAD
        if bool(dead.any()):
            self.embed[dead] = samples[dead]
            self.embed_avg[dead] = samples[dead]
            self.cluster_size[dead] = self.DEAD


class GuideVQ(nn.Module):
    """Residual VQ-VAE of (B, K, dim) normalised body poses at 1 fps; codes (B, K, levels)."""

    def __init__(self, dim: int, config: A2PConfig) -> None:
        super().__init__()
        self.encoder = CausalConvs(dim, config.vq_width, config.vq_width, config.vq_residual)
        self.decoder = CausalConvs(config.vq_width, config.vq_width, dim, config.vq_residual)
        self.levels = nn.ModuleList(
            Codebook(config.vq_codes, config.vq_width, config.vq_decay) for _ in range(config.vq_levels)
        )
        self.commit = config.vq_commit

    def quantise(
        self, latent: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Codes (B, K, levels) and the quantised latent; in training the codebooks learn."""
        b, k, d = latent.shape
        residual = latent.reshape(-1, d)
        quantised = torch.zeros_like(residual)
        codes = []
        for book in self.levels:
            idx = book.nearest(residual)
            if self.training:
                book.update(residual, idx, generator)
                idx = book.nearest(residual)
            chosen = book.embed[idx]
            quantised = quantised + chosen
            residual = residual - chosen
            codes.append(idx)
        return torch.stack(codes, dim=-1).reshape(b, k, -1), quantised.reshape(b, k, d)

    def encode(self, poses: torch.Tensor) -> torch.Tensor:
        return self.quantise(self.encoder(poses))[0]

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """(B, K, levels) codes -> (B, K, dim) poses; pose k depends on codes k-7..k."""
        latent = sum(book.embed[codes[..., i]] for i, book in enumerate(self.levels))
        assert isinstance(latent, torch.Tensor)
        return self.decoder(latent)

    def loss(
        self, poses: torch.Tensor, mask: torch.Tensor, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        latent = self.encoder(poses)
        codes, quantised = self.quantise(latent, generator)
        commitment = F.mse_loss(latent, quantised.detach())
        decoded = self.decoder(latent + (quantised - latent).detach())  # straight-through
        rec = (F.smooth_l1_loss(decoded, poses, reduction="none") * mask).sum() / (mask.expand_as(poses).sum() + 1e-8)
        used = torch.stack([torch.unique(codes[..., i]).numel() * torch.ones(()) for i in range(codes.shape[-1])])
        return rec + self.commit * commitment, {
            "reconstruction": rec.detach(),
            "commitment": commitment.detach(),
            "codes_used": used.float().mean(),
        }


# ---------------------------------------------------------------------------- guide transformer
class SecondEncoder(nn.Module):
    """The 30 log-mel frames of each second (B, S, 30, 2*bands) -> one embedding per second
    (B, S, width): a per-frame projection, then strided convs over 5 and 6 frames."""

    def __init__(self, cin: int, width: int) -> None:
        super().__init__()
        self.frame = nn.Linear(cin, width)
        self.conv1 = nn.Conv1d(width, width, 5, stride=5)
        self.conv2 = nn.Conv1d(width, width, 6, stride=6)

    def forward(self, chunks: torch.Tensor) -> torch.Tensor:
        b, s, f, c = chunks.shape
        h = F.gelu(self.frame(chunks.reshape(b * s, f, c))).transpose(1, 2)
        h = self.conv2(F.gelu(self.conv1(h)))
        return h.reshape(b, s, -1)


class GuideTransformer(nn.Module):
    """Next-token model of the guide-pose codes (time-major, one shared vocabulary of
    ``codes`` plus a start token) given per-second audio embeddings and the speaker."""

    def __init__(self, bands: int, speakers: int, config: A2PConfig) -> None:
        super().__init__()
        w = config.guide_width
        self.codes, self.levels = config.vq_codes, config.vq_levels
        self.band, self.span, self.heads = config.guide_band, config.guide_audio_span, config.guide_heads
        self.token = nn.Embedding(config.vq_codes + 1, w)
        self.level = nn.Embedding(config.vq_levels, w)
        self.audio = SecondEncoder(2 * bands, w)
        self.null_audio = nn.Parameter(torch.randn(w) * 0.02)
        self.audio_norm = nn.LayerNorm(w)
        self.speaker = nn.Embedding(max(1, speakers), w)
        self.layers = nn.ModuleList(
            FiLMLayer(w, config.guide_heads, config.guide_feedforward, config.dropout, 1)
            for _ in range(config.guide_layers)
        )
        self.norm = nn.LayerNorm(w)
        self.head = nn.Linear(w, config.vq_codes)

    @property
    def start_token(self) -> int:
        return self.codes

    def audio_memory(self, chunks: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """(B, S, 30, 2*bands) normalised audio of S seconds -> (B, S, width); ``keep`` (B,) 0
        replaces an example's audio by the learned null (classifier-free training)."""
        memory = self.audio(chunks)
        if keep is not None:
            memory = keep[:, None, None] * memory + (1 - keep[:, None, None]) * self.null_audio
        return self.audio_norm(memory)

    def _embed(self, tokens: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        return self.token(tokens) + self.level(positions % self.levels)

    def forward(self, tokens: torch.Tensor, memory: torch.Tensor, speaker: torch.Tensor) -> torch.Tensor:
        """Logits (B, N, codes) for every position of a sequence from its first second, by teacher
        forcing: ``tokens`` (B, N) are the inputs (the start token, then the codes shifted by
        one); ``memory`` (B, span - 1 + N/levels, width) embeds the span - 1 seconds before the
        sequence and its own seconds. Masks as in sampling: self-attention to the last ``band``
        positions, audio of the token's second and the span - 1 before."""
        b, n = tokens.shape
        device = tokens.device
        index = torch.arange(n, device=device)
        x = self._embed(tokens, index[None].expand(b, n))
        gap = index[:, None] - index[None, :]
        self_bias = torch.where((gap >= 0) & (gap < self.band), 0.0, -1e9).to(torch.float32)
        second = index // self.levels + self.span - 1  # memory index of each token's own second
        cols = torch.arange(memory.shape[1], device=device)
        ahead = second[:, None] - cols[None, :]
        cross_bias = torch.where((ahead >= 0) & (ahead < self.span), 0.0, -1e9).to(torch.float32)
        positions = index[None].expand(b, n).to(torch.float32)
        query_seconds = second[None].expand(b, n).to(torch.float32)
        memory_seconds = cols[None].expand(b, -1).to(torch.float32)
        film = self.speaker(speaker)
        for layer in self.layers:
            k, v = layer.cross[0].attention.keys_values(memory, memory_seconds)
            # self-attention rotates by sequence position, cross-attention by second
            x, _ = layer(x, positions, film, [(k, v, cross_bias)], self_bias, cross_positions=query_seconds)
        return self.head(self.norm(x))

    def step(
        self,
        token: torch.Tensor,
        position: torch.Tensor,
        audio: torch.Tensor,
        past_keys: torch.Tensor,
        past_values: torch.Tensor,
        speaker: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One autoregressive step with a KV cache: the input ``token`` (B, 1) at sequence
        ``position`` (B, 1), the audio embeddings of its second and the span - 1 before
        (B, span, width), and the self-attention keys and values of up to ``band - 1`` earlier
        positions (layers, B, heads, P, dh) -> the next code's logits (B, codes) and the cache
        with this position appended (layers, B, heads, P + 1, dh)."""
        b = token.shape[0]
        x = self._embed(token, position)
        positions = position.to(torch.float32)
        s = audio.shape[1]
        memory_seconds = torch.arange(s, device=audio.device, dtype=torch.float32)[None].expand(b, s)
        query_seconds = torch.full((b, 1), float(s - 1), device=audio.device)
        film = self.speaker(speaker)
        new_keys, new_values = [], []
        for i, layer in enumerate(self.layers):
            k, v = layer.cross[0].attention.keys_values(audio, memory_seconds)
            x, (keys, values) = layer(
                x, positions, film, [(k, v, None)], None, (past_keys[i], past_values[i]), query_seconds
            )
            new_keys.append(keys)
            new_values.append(values)
        logits = self.head(self.norm(x))[:, 0]
        return logits, torch.stack(new_keys), torch.stack(new_values)

    def empty_cache(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        shape = (len(self.layers), batch, self.heads, 0, self.token.embedding_dim // self.heads)
        return torch.zeros(shape), torch.zeros(shape)


# ------------------------------------------------------------------------------------- the model
NETWORKS: dict[str, tuple[str, ...]] = {
    "lip": ("lip",),
    "face": ("lip", "face"),
    "vq": ("vq",),
    "guide": ("vq", "guide"),
    "body": ("vq", "guide", "body"),
    "distill": (
        "lip",
        "face",
        "vq",
        "guide",
        "body",
        "face_student",
        "body_student",
        "face_target",
        "body_target",
    ),
}
"""The networks each stage holds. The face side (lip, face) and the body side (vq, guide, body)
are trained apart, so the two can run at once; ``distill`` starts from both (``--init`` twice)."""
TRAINS: dict[str, tuple[str, ...]] = {"distill": ("face_student", "body_student")}
"""The networks a stage trains (default: the one it is named after); the others stay frozen."""
DERIVED = ("face_target", "body_target")
"""Networks a stage makes from its own (the students' moving averages), not from earlier runs."""


class A2P(nn.Module):
    """The networks of one training stage: those it trains and, frozen, those of earlier stages."""

    def __init__(self, config: A2PConfig, bands: int, speakers: int, stage: str) -> None:
        super().__init__()
        if stage not in STAGES:
            raise ValueError(f"unknown stage {stage!r} (stages: {', '.join(STAGES)})")
        self.config, self.stage = config, stage
        face_dim, body_dim = FACE.stop - FACE.start, BODY.stop - BODY.start
        self.audio_norm = AudioNorm(bands, flatten_voices=True)
        self.lip: LipRegressor | None = None
        self.face: Denoiser | None = None
        self.vq: GuideVQ | None = None
        self.guide: GuideTransformer | None = None
        self.body: Denoiser | None = None
        self.face_student: Denoiser | None = None
        self.body_student: Denoiser | None = None
        self.face_target: Denoiser | None = None
        self.body_target: Denoiser | None = None

        def face(student: bool) -> Denoiser:
            return Denoiser(
                face_dim,
                (2 * bands, LIP_OUTPUTS),
                config.face_width,
                config.face_layers,
                config.face_heads,
                config.face_feedforward,
                config.dropout,
                speakers,
                cond_layers=config.face_cond_layers,
                student=student,
            )

        def body(student: bool) -> Denoiser:
            return Denoiser(
                body_dim,
                (2 * bands,),
                config.body_width,
                config.body_layers,
                config.body_heads,
                config.body_feedforward,
                config.dropout,
                speakers,
                guide_dim=body_dim,
                post_layers=config.body_post_layers,
                student=student,
            )

        makers = {
            "lip": lambda: LipRegressor(bands, config),
            "face": lambda: face(False),
            "vq": lambda: GuideVQ(body_dim, config),
            "guide": lambda: GuideTransformer(bands, speakers, config),
            "body": lambda: body(False),
            "face_student": lambda: face(True),
            "body_student": lambda: body(True),
            "face_target": lambda: face(True),
            "body_target": lambda: body(True),
        }
        for name in NETWORKS[stage]:
            setattr(self, name, makers[name]())
        for name in self.frozen_names:
            getattr(self, name).requires_grad_(False)

    @property
    def trained_names(self) -> tuple[str, ...]:
        return TRAINS.get(self.stage, (self.stage,))

    @property
    def frozen_names(self) -> tuple[str, ...]:
        """The networks trained by earlier stages, which this stage keeps as they are."""
        return tuple(n for n in NETWORKS[self.stage] if n not in self.trained_names)

    @property
    def inherited_names(self) -> tuple[str, ...]:
        """The frozen networks that come from the runs a stage starts from (``--init``)."""
        return tuple(n for n in self.frozen_names if n not in DERIVED)

    def train(self, mode: bool = True) -> A2P:
        super().train(mode)
        for name in self.frozen_names:  # frozen networks stay deterministic (no dropout, no EMA)
            getattr(self, name).eval()
        return self
