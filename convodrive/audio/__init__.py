"""Audio input (files, chunked, resampled) and the speech features generators read."""

from convodrive.audio.source import (
    ANALYSIS_RATE,
    CHUNK_SAMPLES,
    AudioChunk,
    AudioDecodeError,
    AudioInfo,
    AudioSource,
    ChannelMap,
    DyadicAudio,
    SilentSource,
    motion_frames_for,
    probe_audio,
)

__all__ = [
    "ANALYSIS_RATE",
    "CHUNK_SAMPLES",
    "AudioChunk",
    "AudioDecodeError",
    "AudioInfo",
    "AudioSource",
    "ChannelMap",
    "DyadicAudio",
    "SilentSource",
    "motion_frames_for",
    "probe_audio",
]
