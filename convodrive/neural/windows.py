"""How a learned generator cuts a stream into model calls: fixed windows that overlap by a context.

Window i covers frames ``[i*hop - context, (i+1)*hop)`` with ``hop = window - context``. Its first
``context`` frames are the previous window's output, given to the model as known motion (the
papers' continuation by inpainting); it generates the ``hop`` frames after them. The first window
starts ``context`` frames before the audio (over silence, with nothing known), so that it too
ends ``hop`` frames after its first new frame: once window i has run, every frame before
``(i+1)*hop`` is final, and any frame waits at most ``hop - 1`` frames of audio beyond itself, the
generator's declared look-ahead (plus its audio features' own), from the first frame on.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class WindowPlan:
    window: int
    context: int = 0

    def __post_init__(self) -> None:
        if self.window < 1 or not 0 <= self.context < self.window:
            raise ValueError(
                f"a window plan needs window >= 1 and 0 <= context < window, got {self.window}, {self.context}"
            )

    @property
    def hop(self) -> int:
        return self.window - self.context

    def start(self, index: int) -> int:
        """First frame of window ``index`` (negative for the first window when it has a context)."""
        return index * self.hop - self.context

    @property
    def lookahead_frames(self) -> int:
        """Frames of audio past a frame that its window needs (the worst case: a window's first new frame)."""
        return self.window - self.context - 1

    def windows_for(self, num_frames: int) -> int:
        """Windows that cover ``num_frames`` frames (the last may run past the end, padded)."""
        return max(1, -(-num_frames // self.hop))


def ease_in(motion: np.ndarray, context: np.ndarray, frames: int) -> np.ndarray:
    """``motion`` (K, window, D), its first ``C`` frames the known ``context`` (K, C, D), with its
    first new frames offset so that they continue the context at its own velocity, the offset
    fading linearly to nothing over ``frames``.

    Inpainting pins a window's first frames to the previous window's output, but a model may still
    start its new frames elsewhere: ProbTalk samples the codes of the token holding the seam rather
    than fitting them to the known frames, and a2p's body turned a still wrist 80 degrees in one
    frame at a fifth of its seams. Animation systems smooth such cuts the same way."""
    c = context.shape[1]
    if frames <= 0 or c < 2:
        return motion
    expected = 2 * context[:, -1] - context[:, -2]
    offset = expected - motion[:, c]
    ramp = (1 - np.arange(frames, dtype=np.float32) / frames)[None, :, None]
    out = motion.copy()
    out[:, c : c + frames] += offset[:, None, :] * ramp
    return out


def smooth_new_frames(motion: np.ndarray, keep: int, sigma: float, channels: slice = slice(None)) -> np.ndarray:
    """``motion`` (K, window, D) with its ``channels`` low-passed along time by a Gaussian of
    ``sigma`` frames, its first ``keep`` frames (the known context, already out) unchanged and read
    as the filter's past.

    ProbTalk's PQ-VAE decodes each token through stride-2 transposed convolutions and overlapping
    per-token kernels; its reconstruction of the corpus moves the body with six times the corpus's
    frame-to-frame acceleration, a shiver a servo head would follow. The filter sees only the
    window, so it adds no look-ahead: the window's last frames are filtered against copies of the
    last one."""
    if sigma <= 0 or motion.shape[1] < 2:
        return motion
    from scipy.ndimage import gaussian_filter1d  # here, not at import: `convodrive plugins` stays light

    low = gaussian_filter1d(motion[..., channels], sigma, axis=1, mode="nearest", truncate=3.0)
    out = motion.copy()
    out[:, keep:, channels] = low[:, keep:]
    return out
