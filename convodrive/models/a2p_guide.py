"""The body guide of a2p: the residual VQ-VAE of 1 fps body poses (``GuideVQ``) and the
autoregressive transformer over its tokens (``GuideTransformer``)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from convodrive.models.a2p_blocks import FiLMLayer
from convodrive.models.a2p_config import A2PConfig


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
