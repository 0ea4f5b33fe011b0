"""The training corpus: one on-disk format for made and imported conversations (NumPy only).

Layout of a corpus folder (format ``convodrive.corpus``, version 1)::

    manifest.json              written last: format, version, fps (30), sample rate (16000), the
                               audio feature spec, the source (command, options, seed), speakers,
                               split counts, shards (path, bytes, conversations) and one entry per
                               conversation: id, split, group, speaker, frames, takes, shard,
                               audio, missing_joints, missing_face, metadata (language, voices, ...),
                               stratum (the maker's kind of conversation; absent or empty if imported)
    audio/<id>.wav             16 kHz stereo 16-bit PCM: channel 0 self, channel 1 the partner
    shards/shard-NNNNN.npz     uncompressed npz, per conversation <id>/<array>:
        pose (K, T, 55, 3) float32      K takes of local axis-angle rotations (canonical skeleton)
        translation (K, T, 3) float32   root displacement, metres
        face (K, T, 52) float32         ARKit channels in [0, 1]
        vad (K, T, 2) float32, state (K, T) int8   voice activity and conversation state
        mel (T, 2, bands) float32       log-mel of self and partner (``convodrive.audio.logmel``),
                                        computed from the stored 16-bit audio

A conversation is seen from one side: channel 0 is the person whose motion is stored, the
"speaker" label names their style or identity. Both sides of one dyad are two conversations in one
``group``; splits (train / val / test) are drawn per group, so no conversation leaks across them,
and within each ``stratum``, so adding one kind of conversation moves no other kind's.
Channels a source lacks are listed by name (``missing_joints``, ``missing_face``) and stored as
zeros; ``representation.feature_mask`` turns them into the per-feature mask that statistics and
losses use.

``CorpusWriter`` writes (temporary files renamed into place, manifest last, everything removed on
failure); ``Corpus.open`` reads, with one-line errors naming the file for a missing or truncated
shard, a bad manifest, or audio whose length disagrees with its motion.
"""

from convodrive.corpus.manifest import FORMAT_VERSION, SPLITS, ConversationInfo
from convodrive.corpus.reader import Corpus, Window
from convodrive.corpus.writer import CorpusWriter, Recording

__all__ = ["FORMAT_VERSION", "SPLITS", "ConversationInfo", "Corpus", "CorpusWriter", "Recording", "Window"]
