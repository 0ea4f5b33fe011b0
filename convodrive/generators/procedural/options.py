"""Options of the procedural generator (``-G KEY=VALUE`` or ``generator: {procedural: {...}}``)."""

from __future__ import annotations

import dataclasses

from convodrive.plugins.options import PluginOptions, option


@dataclasses.dataclass(frozen=True)
class ProceduralOptions(PluginOptions):
    expressiveness: float = option(
        1.0, low=0, high=3, help="Amplitude of head, brow, body and gesture motion (0 still, 2 animated)"
    )
    variability: float = option(
        1.0, low=0, high=3, help="How much takes differ: jitter of timing, amplitude and choice (0 least)"
    )
    phones: bool = option(
        True,
        help="Recognise English phones with pocketsphinx for the visemes; false uses the spectral "
        "fallback only (any language, about three times faster)",
    )
    gestures: bool = option(True, help="Beat gestures of the arms and hands on stressed syllables")
    gaze_aversion: float = option(
        1.0,
        low=0,
        high=3,
        help="How often self looks away from the partner: at a turn's start, now and then mid-turn, and in "
        "the listener's glances (0 never: the eyes stay on the partner with small saccades; 2 twice as often)",
    )
    gaze_range: float = option(
        1.0, low=0.25, high=2, help="How far those looks away go, as a factor on their angles (0.5 half as far)"
    )
    vad_on_db: float = option(
        -40.0, low=-100, high=0, help="Loudness (dBFS) at which a voice starts to count as speech"
    )
    vad_off_db: float = option(
        -48.0, low=-100, high=0, help="Loudness (dBFS) below which speech ends (at most vad_on_db)"
    )
    anticipation: float = option(
        0.3,
        low=0,
        high=1,
        help="Seconds of look-ahead beyond the audio analysis' 115 ms, to see the partner's pauses (nods) and "
        "self's turn starts (the in-breath and lean before speaking) coming; the declared look-ahead grows by as "
        "much. 0 gives the lowest latency (live use)",
    )

    def __post_init__(self) -> None:
        if self.vad_off_db > self.vad_on_db:
            raise ValueError(f"vad_off_db ({self.vad_off_db:g}) must not exceed vad_on_db ({self.vad_on_db:g})")
