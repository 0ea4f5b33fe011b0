"""``a2p``: audio2photoreal's face and body diffusion with guide poses, streaming in ONNX Runtime + NumPy.

Each window of audio becomes motion in this order (graphs of ``convodrive.training.recipes.a2p_export``):

1. ``lip`` on both voices, then with the channels swapped: self's mouth (a condition of the face)
   and the voice activity of self and of the partner;
2. the face: ``face_memory`` once (the conditional and, for DDIM with guidance, the
   unconditional rows in one batch), then a sampling loop in NumPy (``convodrive.neural.diffusion``)
   around ``face_step``: the teacher by DDIM or DPM-Solver++ with classifier-free guidance, both
   halves one batch, or the distilled student (guidance built in, one call a step): by
   DPM-Solver++ as the teachers if it learned by guidance distillation, else by its own
   consistency sampler (model.json's ``distillation``);
3. the guide poses (``guide.GuidePoses``): one body pose a second, sampled by the residual-VQ
   transformer as the audio arrives;
4. the body, as the face, conditioned on the audio and the guide poses near the window.

Windows overlap by ``context`` frames: each continues the previous one's last frames, which its
networks see and its samplers pin (continuation by inpainting), so a stream of any length is one
motion. K takes (``--samples K``) are the batch of the same calls. ``file`` mode uses the model's
long windows, ``live`` mode 2 s windows that advance 12 frames, so a frame waits for 0.4 s of
audio. The per-stream state (audio of the seconds not yet guided, the guide's cache and codes,
the poses near the next window) has a fixed size, so memory stays constant however long the stream.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from convodrive.generators.a2p.guidance import (
    DDIM_GUIDANCE_BODY,
    DDIM_GUIDANCE_HEAD,
    GUIDANCE_EYES,
    GUIDANCE_FACE,
    STUDENT_GUIDANCE_BODY,
    STUDENT_GUIDANCE_LIDS,
    Guidance,
)
from convodrive.generators.a2p.guide import GuidePoses, GuideState
from convodrive.generators.learned import LearnedGenerator, LearnedOptions
from convodrive.motion import representation as rep
from convodrive.neural.diffusion import (
    consistency_sample,
    cosine_schedule,
    ddim_sample,
    ddim_timesteps,
    distinct_scales,
    dpm_solver_sample,
    guided,
    log_snr_timesteps,
    noise_like,
    scaled_by_input,
)
from convodrive.neural.windows import WindowPlan
from convodrive.plugins.options import option
from convodrive.plumbing.errors import UserError

LIVE = (60, 48)
"""Window and context frames of ``live`` mode: a 12-frame hop."""
FILE_CONTEXT = 30
DISTILLED_STEPS = 4
DDIM_STEPS = 10
"""The body's DDIM steps: 20 moved its scores on the test split within the draws' noise."""
DDIM_FACE_STEPS = {"file": 50, "live": 20}
"""The face's DDIM steps by mode. The face keeps improving with steps (FD_g face on the test split
9.6 at 1 distilled step, 6.4 at 10, 4.4 at 20, 2.9 at 50); live mode stops at 20 to keep its
latency (look-ahead plus a window's compute) under 0.5 s on 2 cores."""
DPM_STEPS, DPM_FACE_STEPS = 4, 8
"""DPM-Solver++(2M)'s steps of the teachers: on the test split the body's 4 (on DDIM's trailing
steps) and the face's 8 (evenly in log-SNR, down to step 0) score FD_g 8.42 and 1.11 against
DDIM's 7.97 and 1.19 in 10 and 50 (model card). The face on trailing steps scored 4.9 at 8, on
steps even in time 5.7: it needs its last steps near 0 and the extrapolation even in log-SNR.
In live mode (2 s windows, 1.6 s of them known) the face is worse by dpm: FD_g 5.28 against
DDIM 20's 2.01."""
GUIDE_TEMPERATURE = 1.2
"""The guide poses' sampling temperature. At 1 the guide's poses, and the body that follows them,
keep 0.89 of the corpus's spread on the upper body (median over its channels, test split): the
body diffusion is no narrower than its guides, the guide transformer is. At 1.2, on the test split
(7 x 4, seeds 0-5), FD_g body is 7.42 against 7.94 (the takes' 5.11: 1.45x against 1.55x), though
not at every seed (gains of 0.6 to 2.3 at three, losses of 0.1 to 0.5 at the others); at 1.5,
7.47 at seed 0 (6.79 at 1.2, 7.70 at 1). The head moves more while talking: 2.35 / 2.21 times its
listening speed on the bundled dialogue (seeds 0 / 1; 1.94 / 2.05 at 1). The face is sampled
before the guide and does not change."""
FACE = rep.GROUPS["face"]
BODY = rep.GROUPS["body"]
VAD = rep.GROUPS["vad"]
GRAPHS = ("lip", "face_memory", "face_step", "body_memory", "body_step", "guide_audio", "guide_step", "vq_decoder")
STUDENT_GRAPHS = ("face_student_memory", "face_student_step", "body_student_memory", "body_student_step")


@dataclasses.dataclass(frozen=True)
class A2POptions(LearnedOptions):
    mode: str = option(
        "file",
        choices=("file", "live"),
        help="file: the model's long windows; live: 2 s windows advancing 0.4 s (0.4 s look-ahead)",
    )
    sampler: str = option(
        "ddim",
        choices=("distilled", "ddim", "dpm"),
        help="ddim: the teachers with classifier-free guidance; dpm: the same teachers by DPM-Solver++(2M), "
        f"{DPM_STEPS} body and {DPM_FACE_STEPS} face steps for DDIM's quality in file mode; distilled: the students "
        "(guidance built in, one call a step): guidance-distilled ones (the shipped) by DPM-Solver++ as the teachers, "
        "consistency-distilled ones by their own sampler",
    )
    steps: int = option(
        0,
        low=0,
        high=1000,
        help=f"denoising steps of the body; 0: {DDIM_STEPS} with ddim, {DPM_STEPS} with dpm, {DISTILLED_STEPS} distilled",
    )
    eta: float = option(
        0.0, low=0.0, high=1.0, help="ddim's fresh noise at each step (0: deterministic DDIM, 1: as DDPM)"
    )
    face_steps: int = option(
        0,
        low=0,
        high=1000,
        help=f"the face's denoising steps; 0: with ddim {DDIM_FACE_STEPS['file']} ({DDIM_FACE_STEPS['live']} in live mode, for its latency), with dpm {DPM_FACE_STEPS}, distilled the model's own (model.json's face_student_steps)",
    )
    guidance_face: float = option(
        GUIDANCE_FACE, low=1.0, high=20.0, help="classifier-free guidance scale of the face (1: none)"
    )
    guidance_gaze: float = option(
        0.0,
        low=0.0,
        high=20.0,
        help=f"the guidance of the gaze (the eyeballs and the look channels); 0: {GUIDANCE_EYES:g} with the teachers, "
        "the face's for the students (another scale costs guidance-distilled students a pass of the face)",
    )
    guidance_lids: float = option(
        0.0,
        low=0.0,
        high=20.0,
        help=f"the guidance of the eyelids (blinks, squint, wide); 0: {GUIDANCE_EYES:g} with the teachers, "
        f"{STUDENT_GUIDANCE_LIDS:g} for guidance-distilled students (a second pass of their face)",
    )
    guidance_body: float = option(
        0.0,
        low=0.0,
        high=20.0,
        help=f"classifier-free guidance scale of the body (1: none); 0: {DDIM_GUIDANCE_BODY:g} with the teachers, "
        f"{STUDENT_GUIDANCE_BODY:g} for guidance-distilled students, 1 for consistency ones",
    )
    guidance_head: float = option(
        0.0,
        low=0.0,
        high=20.0,
        help=f"with the teachers, the guidance of the head and neck (1: none); 0: {DDIM_GUIDANCE_HEAD:g} at the default "
        "body guidance, else the body's (students learned one scale for all)",
    )
    guidance_body_on: str = option(
        "audio",
        choices=("audio", "all"),
        help="with the teachers, what the body's guidance amplifies: audio (the unconditional pass keeps the guide poses) or all (it drops them too, as the paper); students learned one (guidance-distilled audio, consistency all)",
    )
    top_p: float = option(
        1.0,
        low=0.01,
        high=1.0,
        help="nucleus of the guide-pose codes (lower: safer poses, less varied; the reference's 0.94 "
        "cost the shipped model 1 to 1.6 of FD_g body, its model card says)",
    )
    guide_temperature: float = option(
        GUIDE_TEMPERATURE,
        low=0.1,
        high=5.0,
        help="the guide-pose codes' logits are divided by it before nucleus sampling (above 1: bolder, more varied poses)",
    )
    speaker: str = option("", help="speaker style the model learned (its model card lists them); empty: the first")


@dataclasses.dataclass
class _Stream:
    """What a stream carries from window to window (all of a fixed size)."""

    guide: GuideState
    index: int = 0


class A2PGenerator(LearnedGenerator):
    name = "a2p"
    description = (
        "audio2photoreal: face diffusion with a lip regressor, body diffusion guided by 1 fps VQ poses "
        "(learned, ONNX Runtime, distilled)"
    )
    Options: ClassVar[type[LearnedOptions]] = A2POptions
    model_kind = "a2p"
    shipped_model: ClassVar[Path | None] = Path(__file__).with_name("model")

    options: A2POptions

    def __init__(self, options: A2POptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        wanted = GRAPHS + (STUDENT_GRAPHS if self.options.sampler == "distilled" else ())
        self.folder.require_graphs(wanted, "export the distill stage")
        arch = self.folder.spec["architecture"]
        self.arch = arch
        self.skip = int(arch["distill_skip"])
        self.alpha_bar = cosine_schedule(int(arch["diffusion_steps"]))
        speakers = list(self.folder.spec["features"].get("speakers", []))
        wanted_speaker = self.options.speaker or (speakers[0] if speakers else "")
        if wanted_speaker not in speakers:
            raise UserError(
                f"generator a2p: speaker '{wanted_speaker}' is not one the model learned ({', '.join(speakers)})"
            )
        self.speaker = np.array([speakers.index(wanted_speaker)], np.int64)
        distilled = self.options.sampler == "distilled"
        self.consistency = distilled and arch.get("distillation", "consistency") == "consistency"
        """Consistency students: their own sampler on the distillation grid, guidance on all conditions."""
        self.steps, self.face_steps = self._step_counts(arch)
        self.dpm_times = (
            self._dpm_times() if self.options.sampler == "dpm" or (distilled and not self.consistency) else {}
        )
        self.guidance = Guidance.of(self.options, distilled, self.consistency)
        prefix = "_student" if distilled else ""
        self.lip = self.graph("lip")
        self.face_memory, self.face_step = self.graph(f"face{prefix}_memory"), self.graph(f"face{prefix}_step")
        self.body_memory, self.body_step = self.graph(f"body{prefix}_memory"), self.graph(f"body{prefix}_step")
        guide_graphs = {name: self.graph(name) for name in ("guide_audio", "guide_step", "vq_decoder")}
        self.guides = GuidePoses(
            guide_graphs, arch, self.speaker, self._silence, self.options.top_p, self.options.guide_temperature
        )
        self.windows = 0

    def _step_counts(self, arch: Mapping[str, Any]) -> tuple[int, int]:
        """The body's and the face's steps: the options', else the sampler's defaults; checked
        against what the sampler can take."""
        sampler = self.options.sampler
        own_steps = {"distilled": DISTILLED_STEPS, "ddim": DDIM_STEPS, "dpm": DPM_STEPS}[sampler]
        steps = self.options.steps or own_steps
        own_face = {
            "distilled": int(arch.get("face_student_steps", 0)),
            "ddim": DDIM_FACE_STEPS[self.options.mode],
            "dpm": DPM_FACE_STEPS,
        }[sampler]
        face_steps = self.options.face_steps or own_face or steps
        limit = int(arch["diffusion_steps"]) // (self.skip if self.consistency else 1)
        for name, value in (("steps", steps), ("face_steps", face_steps)):
            if value > limit:
                raise UserError(f"generator a2p: {name} must be at most {limit} with the {sampler} sampler")
        return steps, face_steps

    def _dpm_times(self) -> dict[int, np.ndarray]:
        """The dpm sampler's steps by part (its first feature): see ``DPM_STEPS``."""
        try:
            face = log_snr_timesteps(self.face_steps, self.alpha_bar)
        except ValueError as error:
            raise UserError(
                f"generator a2p: face_steps {self.face_steps} is too many for the dpm sampler ({error})"
            ) from None
        return {FACE.start: face, BODY.start: ddim_timesteps(self.steps, len(self.alpha_bar))}

    def window_plan(self) -> WindowPlan:
        if self.options.mode == "live":
            return WindowPlan(*LIVE)
        return WindowPlan(int(self.folder.spec["architecture"]["window"]), FILE_CONTEXT)

    def stream_state(self, takes: int) -> _Stream:
        return _Stream(self.guides.state(takes))

    # -- one window --------------------------------------------------------------------------------
    def run_window(
        self, audio: np.ndarray, context: np.ndarray | None, rngs: Sequence[np.random.Generator], state: Any = None
    ) -> np.ndarray:
        assert isinstance(state, _Stream)
        takes, window = len(rngs), len(audio)
        start = self.plan.start(state.index)
        audio = audio.astype(np.float32)
        lip = self.lip(audio=np.stack([audio, audio[:, ::-1]]))["lip"]
        out = np.zeros((takes, window, rep.FEATURE_DIM), np.float32)
        out[..., VAD.start] = lip[0, :, -1]
        out[..., VAD.start + 1] = lip[1, :, -1]
        conditional = {"audio": audio[None], "lip": lip[:1]}
        out[..., FACE] = self._sample(
            self.face_memory,
            self.face_step,
            conditional,
            False,
            FACE,
            context,
            rngs,
            self.guidance.face_scales,
            self.face_steps,
            np.zeros(2, np.float32),
        )
        self.guides.hear(state.guide, audio, start)
        self.guides.sample(state.guide, start + window, rngs)
        guide, positions, valid = self.guides.near(state.guide, start, window, takes)
        conditional = {
            "audio": np.repeat(audio[None], takes, axis=0),
            "guide": guide,
            "guide_positions": positions,
            "guide_valid": valid,
        }
        out[..., BODY] = self._sample(
            self.body_memory,
            self.body_step,
            conditional,
            True,
            BODY,
            context,
            rngs,
            self.guidance.body_scales,
            self.steps,
            self.guidance.body_unconditional,
        )
        state.index += 1
        self.windows += 1
        return out

    def _sample(
        self,
        memory_graph: Any,
        step_graph: Any,
        conditions: dict[str, np.ndarray],
        per_take: bool,
        part: slice,
        context: np.ndarray | None,
        rngs: Sequence[np.random.Generator],
        guidance: float | np.ndarray,
        steps: int,
        unconditional: np.ndarray,
    ) -> np.ndarray:
        """(K, window, part dims) from one denoiser: its memory once, then the sampling loop.
        ``conditions`` hold one row for all takes, or one per take (``per_take``); with guidance,
        ``unconditional`` (2,) says which conditions the unconditional pass keeps (1) or drops (0)."""
        takes = len(rngs)
        window = conditions["audio"].shape[1]
        dim = part.stop - part.start
        rows = takes if per_take else 1
        distilled = self.options.sampler == "distilled"
        cfg = not distilled and bool(np.any(np.asarray(guidance) != 1.0))
        keep = np.ones((rows, 2), np.float32)
        if cfg:
            conditions = {k: np.concatenate([v, v]) for k, v in conditions.items()}
            keep = np.concatenate([keep, np.broadcast_to(unconditional, keep.shape)])
        speaker = np.repeat(self.speaker, len(keep))
        memory = memory_graph(conditions, keep=keep, speaker=speaker)
        if not per_take:  # one row per take, conditional rows first (the order ``guided`` batches)
            memory = {k: _repeat_rows(v, takes, _batch_axis(k)) for k, v in memory.items()}
        passes = len(distinct_scales(guidance)[0]) if distilled and not self.consistency else 1
        if passes > 1:  # a student at one scale a channel: the rows once a scale (``scaled_by_input``)
            memory = {k: np.concatenate([v] * passes, axis=_batch_axis(k)) for k, v in memory.items()}
        known = np.zeros((takes, window, dim), np.float32)
        known_mask = np.zeros((takes, window, 1), np.float32)
        if context is not None:
            known[:, : context.shape[1]] = context[..., part]
            known_mask[:, : context.shape[1]] = 1.0

        def x0(x: np.ndarray, steps: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
            times = len(x) // takes
            feed = {
                "noisy": x,
                "step": steps,
                "known": np.concatenate([known] * times),
                "known_mask": np.concatenate([known_mask] * times),
                **memory,
            }
            if distilled:
                feed["guidance"] = np.full(len(x), guidance, np.float32) if scale is None else scale
            return step_graph(feed)["x0"]

        noise = noise_like(rngs, (window, dim))
        if self.consistency:
            return consistency_sample(x0, noise, steps, self.alpha_bar, self.skip, rngs, known, known_mask)
        x0_fn = guided(x0, guidance) if cfg else scaled_by_input(x0, guidance) if distilled else x0
        if self.dpm_times:
            return dpm_solver_sample(x0_fn, noise, self.dpm_times[part.start], self.alpha_bar, known, known_mask)
        return ddim_sample(x0_fn, noise, steps, self.alpha_bar, known, known_mask, self.options.eta, rngs)

    def report(self) -> dict[str, Any]:
        return {
            "model": str(self.folder.path),
            "mode": self.options.mode,
            "sampler": self.options.sampler,
            "steps": self.steps,
            "face_steps": self.face_steps,
            "guidance": self.guidance.report(),
            "body_guidance_on": self.guidance.body_on,
            "top_p": self.options.top_p,
            "guide_temperature": self.options.guide_temperature,
            "window": self.plan.window,
            "context": self.plan.context,
            "windows": self.windows,
        }


def _batch_axis(name: str) -> int:
    """The batch axis of a memory graph's output: the attention caches hold their layers first."""
    return 1 if "keys" in name or "values" in name else 0


def _repeat_rows(array: np.ndarray, times: int, axis: int) -> np.ndarray:
    """Each row of ``array`` along ``axis`` repeated ``times`` times in place (c, c, u, u)."""
    return np.repeat(array, times, axis=axis)
