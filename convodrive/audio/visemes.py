"""Visemes: the 15 mouth classes of Oculus/Meta lip sync, from ARPAbet phones or from the spectrum.

Phones come from pocketsphinx (English); the spectral fallback guesses the mouth shape from band
energies so lips still move plausibly for other languages, noise, or when phones lag.
"""

from __future__ import annotations

import numpy as np

VISEMES: tuple[str, ...] = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
NUM_VISEMES = len(VISEMES)
VISEME_INDEX = {name: i for i, name in enumerate(VISEMES)}

PHONE_TO_VISEME: dict[str, str] = {
    "AA": "aa",
    "AE": "aa",
    "AH": "aa",
    "AO": "oh",
    "AW": "aa",
    "AY": "aa",
    "B": "PP",
    "CH": "CH",
    "D": "DD",
    "DH": "TH",
    "EH": "E",
    "ER": "RR",
    "EY": "E",
    "F": "FF",
    "G": "kk",
    "HH": "kk",
    "IH": "ih",
    "IY": "ih",
    "JH": "CH",
    "K": "kk",
    "L": "nn",
    "M": "PP",
    "N": "nn",
    "NG": "kk",
    "OW": "oh",
    "OY": "oh",
    "P": "PP",
    "R": "RR",
    "S": "SS",
    "SH": "CH",
    "T": "DD",
    "TH": "TH",
    "UH": "ou",
    "UW": "ou",
    "V": "FF",
    "W": "ou",
    "Y": "ih",
    "Z": "SS",
    "ZH": "CH",
    "SIL": "sil",
}


def phone_viseme(phone: str) -> int:
    """Viseme index of an ARPAbet phone; fillers and noise (``+NSN+``, ``+SPN+``) are silence."""
    return VISEME_INDEX[PHONE_TO_VISEME.get(phone.upper().rstrip("012"), "sil")]


def spectral_visemes(
    f1_frac: np.ndarray,
    f2_frac: np.ndarray,
    low_frac: np.ndarray,
    hiss_frac: np.ndarray,
    voiced: np.ndarray,
    active: np.ndarray,
) -> np.ndarray:
    """(T, 15) viseme weights from band energies: open (F1 band), wide (F2 band), round (low only), hiss.

    Open vowels put energy at 550-1100 Hz, front vowels at 1600-3000 Hz, rounded vowels keep it
    below 550 Hz; fricatives are unvoiced hiss above 3.5 kHz. Silence where the voice is inactive.
    """
    n = len(f1_frac)
    w = np.zeros((n, NUM_VISEMES))
    vowel = np.where(voiced > 0, 1.0, 0.35)
    w[:, VISEME_INDEX["aa"]] = vowel * np.clip(2.2 * f1_frac, 0, 1.5)
    w[:, VISEME_INDEX["E"]] = vowel * np.clip(2.5 * f2_frac, 0, 1.2)
    w[:, VISEME_INDEX["oh"]] = vowel * np.clip(1.2 * low_frac - f2_frac, 0, 1.0) * 0.6
    w[:, VISEME_INDEX["ou"]] = vowel * np.clip(1.4 * low_frac - 2 * f2_frac - f1_frac, 0, 1.0) * 0.8
    w[:, VISEME_INDEX["SS"]] = np.where(voiced > 0, 0.0, np.clip(2.0 * hiss_frac, 0, 1.0))
    w[:, VISEME_INDEX["DD"]] = 0.15
    total = w.sum(axis=1, keepdims=True)
    w = w / np.maximum(total, 1e-9)
    w[active <= 0] = 0.0
    w[active <= 0, VISEME_INDEX["sil"]] = 1.0
    return w
