"""The default generator: conversational motion from dyadic audio by rules, with no model weights.

Audio analysis (``convodrive.audio.analysis``) gives per-frame features of both voices and self's
visemes with 3 frames (100 ms) of look-ahead; ``CueTracker`` holds them ``anticipation`` frames
longer to see the partner's pauses and self's turn starts coming. Per take, ``ListenerSynth``
decides how self listens (nods, smiles, blinks, glances), ``PostureSynth`` the slow layer (posture
shifts, arm rest, breathing, the in-breath before a turn), and ``FaceSynth`` and ``BodySynth`` turn
all of it into face channels and joint rotations. Every stage is chunk-invariant (state carried
between batches, randomness indexed by absolute frame and seed), so streaming equals offline
generation exactly.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from convodrive.audio.analysis import LOOKAHEAD_FRAMES, LOOKAHEAD_SAMPLES, DyadicAnalyzer, FrameBatch
from convodrive.audio.phones import pocketsphinx_available
from convodrive.audio.source import ANALYSIS_RATE, AudioChunk, DyadicAudio, motion_frames_for
from convodrive.audio.voice_tracker import VoiceParams
from convodrive.generators.base import Generator, take_seed
from convodrive.generators.procedural.body import BodySynth, yxz_axis_angle
from convodrive.generators.procedural.conversation import ConversationOverlay
from convodrive.generators.procedural.cues import CueBatch, CueTracker
from convodrive.generators.procedural.face import FaceSynth, gaze_channels
from convodrive.generators.procedural.listener import ListenerSynth
from convodrive.generators.procedural.options import ProceduralOptions
from convodrive.generators.procedural.posture import PostureSynth
from convodrive.motion.channels import ConversationState
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.motion.skeleton import JOINT_INDEX as J

__all__ = ["ProceduralGenerator", "ProceduralOptions"]


class ProceduralGenerator(Generator):
    name = "procedural"
    description = (
        "Rule-based talking and listening motion from both voices (visemes, blinks, gaze, nods, "
        "beat gestures); no weights needed"
    )

    Options = ProceduralOptions
    options: ProceduralOptions
    live_options = {"anticipation": 0.0}  # a live partner waits 115 ms for the motion, not 415

    @property
    def anticipation_frames(self) -> int:
        """Frames of features held back to see pauses and turn starts coming (see ``cues``)."""
        return int(round(self.options.anticipation * 30))

    @property
    def lookahead_frames(self) -> int:
        return LOOKAHEAD_FRAMES + self.anticipation_frames

    @property
    def lookahead_seconds(self) -> float:
        held_back = -(-self.anticipation_frames * ANALYSIS_RATE // 30)  # the cues' frames, rounded up
        return (LOOKAHEAD_SAMPLES + held_back) / ANALYSIS_RATE

    # -- public API ----------------------------------------------------------------------------
    def stream(self, chunks: Iterable[AudioChunk], seed: int = 0) -> Iterator[MotionFrame]:
        for takes in self.stream_takes(chunks, [seed]):
            yield takes[0]

    def stream_takes(self, chunks: Iterable[AudioChunk], seeds: Sequence[int]) -> Iterator[tuple[MotionFrame, ...]]:
        """Analyse the audio once (the analysis ignores the seed) and synthesise every take from it."""
        analyzer = self._analyzer()
        cues = CueTracker(self.anticipation_frames)
        synths = [_Synth(self.options, s, ConversationOverlay(self.options, s, self.conversation)) for s in seeds]
        events = synths[0].overlay
        received = 0
        try:
            for chunk in chunks:
                received += len(chunk)
                voice = chunk.self_voice
                silent = events.self_silent(chunk.start, len(voice), ANALYSIS_RATE)
                if silent is not None:  # interrupted or paused: that voice will never be heard
                    voice = np.where(silent, 0.0, voice).astype(np.float32)
                ready = cues.push(analyzer.push(voice, chunk.other_voice))
                if ready is not None:
                    yield from zip(*(_frames(synth(ready)) for synth in synths))
            ready = cues.push(analyzer.finish(motion_frames_for(received / ANALYSIS_RATE)), final=True)
            if ready is not None:
                yield from zip(*(_frames(synth(ready)) for synth in synths))
        finally:
            analyzer.close()

    def generate(self, audio: DyadicAudio, seed: int = 0, num_samples: int = 1) -> list[MotionClip]:
        """Analyse once, synthesise each take; equal to streaming (the analysis ignores the seed)."""
        features = CueTracker(self.anticipation_frames).push(self.analyse(audio), final=True)
        assert features is not None
        clips = []
        for i in range(num_samples):
            s = take_seed(seed, i)
            arrays = _Synth(self.options, s)(features)
            clips.append(
                MotionClip(
                    pose=arrays["pose"],
                    translation=arrays["translation"],
                    face=arrays["face"],
                    vad=arrays["vad"],
                    state=arrays["state"],
                    metadata={
                        "generator": self.name,
                        "seed": s,
                        "take": i,
                        "phones": bool(self.options.phones and pocketsphinx_available()),
                    },
                )
            )
        return clips

    def analyse(self, audio: DyadicAudio) -> FrameBatch:
        analyzer = self._analyzer()
        try:
            parts = [analyzer.push(audio.self_voice, audio.other_voice), analyzer.finish(audio.num_frames)]
        finally:
            analyzer.close()
        return FrameBatch.concat([p for p in parts if p is not None])

    def _analyzer(self) -> DyadicAnalyzer:
        params = VoiceParams(vad_on_db=self.options.vad_on_db, vad_off_db=self.options.vad_off_db)
        return DyadicAnalyzer(params, phones=self.options.phones and pocketsphinx_available())


class _Synth:
    """Features to motion for one take; call it on consecutive batches."""

    def __init__(self, options: ProceduralOptions, seed: int, overlay: ConversationOverlay | None = None) -> None:
        self.overlay = overlay
        """The conversation's events, in a live session; None offline."""
        self.listener = ListenerSynth(options, seed)
        self.posture = PostureSynth(options, seed)
        self.face = FaceSynth(options, seed)
        self.body = BodySynth(options, seed)

    def __call__(self, batch: CueBatch) -> dict[str, np.ndarray]:
        features = batch.features
        s, o = features.self_voice, features.other_voice
        listener = self.listener.step(batch, s, o)
        posture = self.posture.step(batch.first, s["vad"], o["vad"], batch.cues["breath"])
        face, jaw, eyes = self.face.step(batch.first, s, o, features.visemes, listener, posture["inhale"])
        overlay = self.overlay if self.overlay is not None and self.overlay.active else None
        if overlay is not None:
            states = overlay.states(batch.first, len(batch))
            eyes = overlay.gaze(batch.first, states, eyes)
            face = gaze_channels(face, eyes)
        pose = self.body.step(batch.first, s, o, eyes, listener, posture)
        pose[:, J["jaw"], 0] = jaw
        if overlay is not None:
            overlay.body(states, pose, face)
        # Yaw about +Y (positive looks to the character's left), then pitch about +X (positive looks down).
        eye_rot = yxz_axis_angle(np.stack([eyes[:, 0], eyes[:, 1], np.zeros(len(eyes))], axis=1))
        pose[:, J["left_eye_smplhf"]] = eye_rot
        pose[:, J["right_eye_smplhf"]] = eye_rot
        vad = np.stack([s["vad"], o["vad"]], axis=1)
        state = (vad[:, 0] > 0).astype(np.int8) * int(ConversationState.SPEAKING)
        state = np.where(
            (vad[:, 1] > 0) & (vad[:, 0] > 0),
            int(ConversationState.OVERLAP),
            np.where(vad[:, 1] > 0, int(ConversationState.LISTENING), state),
        ).astype(np.int8)
        n = len(batch)
        return {
            "first": batch.first,
            "pose": pose.astype(np.float32),
            "translation": np.zeros((n, 3), np.float32),
            "face": face.astype(np.float32),
            "vad": vad.astype(np.float32),
            "state": state,
        }


def _frames(arrays: dict[str, np.ndarray]) -> Iterator[MotionFrame]:
    first = arrays["first"]
    for j in range(len(arrays["pose"])):
        yield MotionFrame(
            time=(first + j) / 30.0,
            pose=arrays["pose"][j],
            translation=arrays["translation"][j],
            face=arrays["face"][j],
            vad=arrays["vad"][j],
            state=ConversationState(int(arrays["state"][j])),
        )
