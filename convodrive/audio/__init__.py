"""Audio input (files, chunked, resampled) and the speech features generators read."""

from convodrive.audio.source import (
    ANALYSIS_RATE,
    CHUNK_SAMPLES,
    AudioChunk,
    AudioInfo,
    AudioSource,
    ChannelMap,
    DyadicAudio,
    motion_frames_for,
    probe_audio,
)

__all__ = [
    "ANALYSIS_RATE",
    "CHUNK_SAMPLES",
    "AudioChunk",
    "AudioInfo",
    "AudioSource",
    "ChannelMap",
    "DyadicAudio",
    "motion_frames_for",
    "probe_audio",
]
