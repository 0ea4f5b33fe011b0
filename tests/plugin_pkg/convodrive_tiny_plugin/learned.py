"""A third-party learned generator on convodrive's base: one ONNX graph, audio + context -> motion.

Imports no torch: it is what a run loads. Its recipe (``training.py``) trains and exports it.
"""

from __future__ import annotations

import numpy as np

from convodrive.generators.learned import LearnedGenerator
from convodrive.neural.windows import WindowPlan

WINDOW, CONTEXT = 30, 6


class TinyLearnedGenerator(LearnedGenerator):
    name = "tiny_learned"
    description = "a tiny conv regressor from both voices' log-mel to motion (learned-generator test)"
    model_kind = "tiny_regressor"

    def window_plan(self) -> WindowPlan:
        return WindowPlan(WINDOW, CONTEXT)

    def run_window(self, audio, context, rngs):
        k = len(rngs)
        dim = self.stats.mean.shape[0]
        known = np.zeros((k, WINDOW, dim), np.float32)
        known_mask = np.zeros((k, WINDOW, 1), np.float32)
        if context is not None:
            known[:, :CONTEXT] = context
            known_mask[:, :CONTEXT] = 1.0
        batch_audio = np.repeat(audio[None].astype(np.float32), k, axis=0)
        out = self.graph("step")(audio=batch_audio, known=known, known_mask=known_mask)["motion"]
        noise = np.stack([r.standard_normal((WINDOW, dim)).astype(np.float32) for r in rngs]) * 0.05
        return out + noise
