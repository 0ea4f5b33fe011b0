"""Streaming phone recognition with pocketsphinx's bundled English model, decoded as a phone loop.

Audio is fed in fixed 50 ms blocks aligned to the stream's start, so the partial hypotheses (and
everything derived from them) are the same however the caller chunks the audio. Blocks are short
so that a frame's phone can be read as soon as the frame's other features are final (see
``audio.analysis``) with at least 50 ms of decoded audio after the frame. 100 ms of quiet (two
quiet blocks) ends the utterance, and quiet blocks outside one are skipped: the decoder only hears
speech, which keeps it fast and bounds the cost of reading back each partial segmentation.

The decoder runs on a cut-down copy of that model (``viseme_model``): 21 phones, one to three
per viseme class, with their 64 heaviest Gaussians each, written once per machine to the user's
cache folder. It decodes 3.5x faster than the full model did and finds the visemes as often.

``viseme_at`` answers, after block b has been decoded, which viseme covers a motion frame, or
``-1`` where the decoder has nothing for that time (not decoded yet, or a skipped quiet block):
the caller falls back to the spectral visemes there.
"""

from __future__ import annotations

import atexit
import bisect
import os
import shutil
import struct
import tempfile
from pathlib import Path

import numpy as np

from convodrive.audio.visemes import phone_viseme
from convodrive.plumbing.atomic import write_bytes_atomic, write_text_atomic
from convodrive.plumbing.cache import cache_key, cached_folder

BLOCK = 800
"""Samples the decoder takes at a time (50 ms at 16 kHz)."""
QUIET_BLOCKS = 2
"""Quiet blocks in a row that end an utterance (100 ms: a stop's closure inside a word does not)."""
_MAX_UTTERANCE_BLOCKS = 300  # 15 s; longer speech is decoded in pieces


def pocketsphinx_available() -> bool:
    try:
        import pocketsphinx  # noqa: F401
    except ImportError:
        return False
    return True


class PhoneTracker:
    """Phone-loop decoding of one voice, block by block; results as a 10 ms viseme timeline."""

    def __init__(self, silence_db: float = -48.0) -> None:
        self.silence_db = silence_db
        self._decoder = _acquire_decoder()  # every stream starts from the same normalisation
        self._in_utt = False
        self._utt_start = 0  # in 10 ms frames
        self._utt_blocks = 0
        self._quiet = 0  # quiet blocks in a row
        # Committed timeline (finished utterances): parallel lists of start, end (10 ms frames), viseme.
        self._starts: list[int] = []
        self._ends: list[int] = []
        self._vis: list[int] = []
        self._partial: list[tuple[int, int, int]] = []

    def feed_block(self, index: int, block: np.ndarray) -> None:
        """Decode block ``index`` (``BLOCK`` samples at 16 kHz, float; shorter only at the end)."""
        d = self._decoder
        sub = block[: len(block) // 160 * 160].reshape(-1, 160) if len(block) >= 160 else block.reshape(1, -1)
        loudest = (
            10 * np.log10(np.max(np.mean(np.square(sub, dtype=np.float64), axis=1)) + 1e-10) if len(block) else -100.0
        )
        self._quiet = self._quiet + 1 if loudest < self.silence_db else 0
        if self._quiet and not self._in_utt:
            return
        if self._quiet >= QUIET_BLOCKS:
            self._end_utterance()
            return
        if not self._in_utt:
            d.start_utt()
            self._in_utt = True
            self._utt_start = index * BLOCK // 160
            self._utt_blocks = 0
        pcm = (np.clip(block, -1.0, 1.0) * 32767.0).astype(np.int16)
        d.process_raw(pcm.tobytes(), False, False)
        self._utt_blocks += 1
        if self._utt_blocks >= _MAX_UTTERANCE_BLOCKS:
            self._end_utterance()
        else:
            self._partial = self._segments()

    def finish(self) -> None:
        if self._in_utt:
            self._end_utterance()

    def _segments(self) -> list[tuple[int, int, int]]:
        base = self._utt_start
        segments = self._decoder.seg() or ()  # None before the first hypothesis
        return [(base + s.start_frame, base + s.end_frame + 1, _VISEME_OF[s.word]) for s in segments]

    def _end_utterance(self) -> None:
        self._decoder.end_utt()
        for s, e, v in self._segments():
            self._starts.append(s)
            self._ends.append(e)
            self._vis.append(v)
        self._partial = []
        self._in_utt = False
        # Older segments are never asked for again once a later utterance ended; keep the list short.
        if len(self._starts) > 400:
            del self._starts[:200], self._ends[:200], self._vis[:200]

    def viseme_at(self, frames_10ms: np.ndarray) -> np.ndarray:
        """Viseme covering each 10 ms frame, or -1 where nothing was decoded (yet): not reached by
        the decoder, or a block skipped as quiet (where the voice tracker may still hear speech)."""
        out = np.full(len(frames_10ms), -1, np.int64)
        for j, t in enumerate(frames_10ms.tolist()):
            if self._in_utt and t >= self._utt_start:
                out[j] = _lookup(self._partial, t)
                continue
            i = bisect.bisect_right(self._starts, t) - 1
            if i >= 0 and t < self._ends[i]:
                out[j] = self._vis[i]
        return out

    def close(self) -> None:
        """Give the decoder back to the pool; the tracker is unusable afterwards."""
        if self._decoder is not None:
            if self._in_utt:
                self._decoder.end_utt()
            _POOL.append(self._decoder)
            self._decoder = None


class _VisemeOf(dict):
    def __missing__(self, phone: str) -> int:
        self[phone] = phone_viseme(phone)
        return self[phone]


_VISEME_OF = _VisemeOf()


def _lookup(segments: list[tuple[int, int, int]], t: int) -> int:
    for s, e, v in reversed(segments):
        if s <= t < e:
            return v
    return -1


_POOL: list = []


def _acquire_decoder():
    """A decoder from the pool, reset to the initial normalisation; loading one takes 0.03 s."""
    try:
        decoder = _POOL.pop()
    except IndexError:
        decoder = None
    if decoder is not None:
        decoder.reinit_feat()  # forget the normalisation the last stream adapted
        return decoder
    from pocketsphinx import Decoder, get_model_path

    model = viseme_model()
    words = model / "dict" if (model / "dict").exists() else Path(get_model_path("en-us/cmudict-en-us.dict"))
    decoder = Decoder(hmm=str(model), dict=str(words), lm=None, loglevel="FATAL", **DECODER_SETTINGS)
    # An unweighted phone loop: the phone trigram bought no viseme accuracy on espeak-ng speech but
    # cost a third of the search time (42 successors' scores looked up for every phone that ends).
    decoder.add_allphone_file("loop", None)
    decoder.activate_search("loop")
    return decoder


DECODER_SETTINGS = {"beam": 1e-8, "pbeam": 1e-5, "pip": 0.1, "lw": 1.0, "ds": 2, "topn": 2}
"""Phone-loop search settings: acoustic scores on every second frame (``ds``) from the two best
Gaussians per codebook (``topn``). Chosen, with ``VISEME_PHONES`` and ``DENSITIES``, on the
visemes the streaming analysis gives per 30 fps frame against a forced alignment of espeak-ng
sentences (``bench/bench_procedural.py --phone-accuracy``: 44.9 % of frames right against 43.4 %
with the former decoder, all 42 phones with 128 Gaussians each and the phone trigram; lips-closed
``PP`` frames found 25 % of the time against 15 %, and right 46 % of the times it says ``PP``
against 49 %), at 3.5x the speed. On a larger set (62 utterances) the frames right were about
the same: 43.9 % against 44.7 %."""

VISEME_PHONES = (
    "SIL",
    "M",
    "P",
    "B",
    "F",
    "DH",
    "T",
    "K",
    "SH",
    "S",
    "N",
    "L",
    "R",
    "AH",
    "AA",
    "EH",
    "IH",
    "IY",
    "OW",
    "UW",
    "W",
)
"""The phones the decoder tells apart: one to three per viseme class. Scoring a phone's Gaussians
is most of the decoding time and every phone of the loop is scored on every frame, so the other
21 of the model's 42 (``D`` sounds like ``T``, ``Z`` like ``S``, ``AE`` like ``AA``...) are left
out, with the same viseme either way."""

DENSITIES = 64
"""Gaussians kept per phone and feature stream, of the model's 128: those that some senone of the
phone weighs most. Fewer Gaussians to score make decoding about 1.6x faster."""

_MODEL_PHONES = (
    "+NSN+ +SPN+ AA AE AH AO AW AY B CH D DH EH ER EY F G HH IH IY JH K L M N NG OW OY P R S SH "
    "SIL T TH UH UW V W Y Z ZH"
).split()
_MODEL_DIR: Path | None = None


def viseme_model() -> Path:
    """pocketsphinx's English model cut down to ``VISEME_PHONES``, made once per machine in the
    user's cache (``convodrive.plumbing.cache``: no temporary folder to leak when a run is killed);
    in a temporary folder removed at exit where the cache cannot be written; the full model where
    its files are not laid out as expected."""
    global _MODEL_DIR
    from pocketsphinx import get_model_path

    source = Path(get_model_path("en-us/en-us"))
    if _MODEL_DIR is None:
        try:
            key = cache_key([_REDUCED_FORMAT, VISEME_PHONES, DENSITIES, *map(_identity, sorted(source.iterdir()))])
            _MODEL_DIR = cached_folder("phones", key, lambda dest: _write_reduced_model(source, dest, VISEME_PHONES))
        except OSError:
            _MODEL_DIR = _temporary_model(source)
        except (ValueError, struct.error):
            _MODEL_DIR = source
    return _MODEL_DIR


_REDUCED_FORMAT = 1
"""Bump when ``_write_reduced_model`` writes something else, so cached models are made anew."""


def _identity(path: Path) -> tuple[str, int, int]:
    stat = path.stat()
    return path.name, stat.st_size, stat.st_mtime_ns


def _temporary_model(source: Path) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="convodrive-phones-"))
    atexit.register(_remove, folder, os.getpid())
    try:
        _write_reduced_model(source, folder, VISEME_PHONES)
        return folder
    except (OSError, ValueError, struct.error):
        shutil.rmtree(folder, True)
        return source


def _remove(folder: Path, owner: int) -> None:
    if os.getpid() == owner:  # not from a forked child that exits normally
        shutil.rmtree(folder, True)


def _write_reduced_model(source: Path, dest: Path, phones: tuple[str, ...], densities: int = DENSITIES) -> None:
    """Keep the context-independent models of ``phones`` with the ``densities`` heaviest Gaussians
    of each: their codebooks (PTM: one per phone, in the model's phone order), the mixture weights
    of their three senones each (CI senones are numbered 3 * phone index + state), and a text
    model definition listing them."""
    keep = sorted(_MODEL_PHONES.index(p) for p in phones)
    senones = np.array([3 * i + k for i in keep for k in range(3)])
    raw = (source / "sendump").read_bytes()
    n_feat, n_density, n_sen = 3, 128, 5126
    start = len(raw) - n_feat * n_density * n_sen  # 8-bit -log weights: features x codewords x senones
    if start < 8 or struct.unpack("<2i", raw[start - 8 : start]) != (n_density, n_sen):
        raise ValueError("unexpected sendump layout")
    mixw = np.frombuffer(raw, np.uint8, offset=start).reshape(n_feat, n_density, n_sen)
    mixw = mixw[:, :, senones].reshape(n_feat, n_density, len(keep), 3)
    # Per phone and feature stream, the Gaussians some senone of the phone weighs most (smallest -log).
    chosen = np.sort(np.argsort(mixw.min(axis=3), axis=1, kind="stable")[:, :densities], axis=1)
    mixw = np.take_along_axis(mixw, chosen[..., None], axis=1)  # (feat, densities, phone, state)
    write_bytes_atomic(
        dest / "sendump",
        raw[: start - 8]
        + struct.pack("<2i", densities, len(senones))
        + np.ascontiguousarray(mixw.reshape(n_feat, densities, -1)).tobytes(),
    )
    per_phone = chosen.transpose(2, 0, 1)[..., None]  # (phone, feat, densities, 1)
    for name in ("means", "variances"):
        header, data = _read_gauden(source / name)
        write_bytes_atomic(dest / name, header + _pack_gauden(np.take_along_axis(data[keep], per_phone, axis=2)))
    rows = [
        f"{_MODEL_PHONES[i]}\t-\t-\t-\t{'filler' if _MODEL_PHONES[i] == 'SIL' else 'n/a'}\t{i}\t"
        f"{3 * j}\t{3 * j + 1}\t{3 * j + 2}\tN"
        for j, i in enumerate(keep)
    ]
    n = len(keep)
    write_text_atomic(
        dest / "mdef",
        "\n".join(
            [
                "0.3",
                f"{n} n_base",
                "0 n_tri",
                f"{4 * n} n_state_map",
                f"{3 * n} n_tied_state",
                f"{3 * n} n_tied_ci_state",
                f"{len(_MODEL_PHONES)} n_tied_tmat",
                "#",
                "#base lft rt p attrib tmat state ids",
                *rows,
            ]
        )
        + "\n",
    )
    for name in ("feat.params", "transition_matrices"):
        write_bytes_atomic(dest / name, (source / name).read_bytes())
    write_text_atomic(dest / "noisedict", "<s> SIL\n</s> SIL\n<sil> SIL\n")
    write_text_atomic(dest / "dict", "sil SIL\n")


def _read_gauden(path: Path) -> tuple[bytes, np.ndarray]:
    """A SphinxTrain Gaussian file: (header, (codebooks, features, densities, dims) float32)."""
    raw = path.read_bytes()
    end = raw.index(b"endhdr\n") + 7
    magic, n_cb, n_feat, n_density = struct.unpack("<4i", raw[end : end + 16])
    dims = struct.unpack(f"<{n_feat}i", raw[end + 16 : end + 16 + 4 * n_feat])
    if magic != 0x11223344 or n_cb != len(_MODEL_PHONES) or len(set(dims)) != 1:
        raise ValueError(f"unexpected layout of {path.name}")
    at = end + 16 + 4 * n_feat + 4
    data = np.frombuffer(raw, "<f4", count=n_cb * n_feat * n_density * dims[0], offset=at)
    return b"s3\nversion 1.0\n" + b" " * 18 + b"endhdr\n", data.reshape(n_cb, n_feat, n_density, dims[0])


def _pack_gauden(data: np.ndarray) -> bytes:
    n_cb, n_feat, n_density, dim = data.shape
    head = struct.pack(f"<{4 + n_feat}i", 0x11223344, n_cb, n_feat, n_density, *([dim] * n_feat))
    return head + struct.pack("<i", data.size) + np.ascontiguousarray(data, "<f4").tobytes()
