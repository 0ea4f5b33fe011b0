"""``ProbTalkConfig``: every size and rate of ProbTalk's three networks, checked once."""

from __future__ import annotations

import dataclasses

import numpy as np

from convodrive.motion import representation as rep

REFINER_GROUPS: dict[str, np.ndarray] = {
    "face": np.arange(rep.GROUPS["face"].start, rep.GROUPS["face"].stop),
    "body": np.arange(rep.GROUPS["body"].start, rep.GROUPS["body"].stop),
    "spine": np.arange(rep.SPINE.start, rep.SPINE.stop),
    "body_but_spine": np.setdiff1d(
        np.arange(rep.GROUPS["body"].start, rep.GROUPS["body"].stop), np.arange(rep.SPINE.start, rep.SPINE.stop)
    ),
}
"""The feature columns each name of ``refiner_fd_groups`` and ``refiner_teacher_groups`` stands for."""


@dataclasses.dataclass(frozen=True)
class ProbTalkConfig:
    """Hyper-parameters; defaults are the reference implementation's (the ``paper`` preset)."""

    # PQ-VAE
    groups: int = 4
    """G: sub-codebooks, one per slice of the latent."""
    codes: int = 128
    """K: codes per sub-codebook."""
    code_dim: int = 128
    """Dimensions of one group's slice of the latent."""
    vq_channels: tuple[int, ...] = (256, 256, 512, 1024)
    """Encoder widths: after the input projection, then after each stride-2 step (3 steps: 8 frames a token)."""
    vq_layers: int = 2
    """Conv layers in each residual stack of the encoder and decoder."""
    vq_skip: bool = False
    """A linear path beside the encoder's and the decoder's conv stacks: one conv over each token's 8
    frames and half of each neighbour's, and back by ``OverlapAdd`` (so no steps at token borders),
    added to the stack's output (False: the stacks alone, the reference's). Without it the
    small preset's stacks underfit: trained without quantisation for 1000 steps they reconstruct
    the test split at FD_g body 38.8, where that linear path alone reaches 0.31."""
    vq_sphere: bool = True
    """Quantise each group's slice as a unit vector, by cosine distance (False: as it is, by
    Euclidean distance). The sphere drops each slice's length, which is most of the motion's
    amplitude for a near-linear encoder: with ``vq_skip`` and the small preset's stacks, 1000 steps
    reconstruct the test split (quantised) at FD_g body 15.8 on the sphere and 9.8 off it."""
    commitment: float = 0.25
    ema_decay: float = 0.99
    velocity_weight: float = 1.0
    acceleration_weight: float = 0.0
    """Weight of the PQ-VAE's error on the second difference (0: none, the paper's). The velocity
    term alone left the small preset's reconstruction shivering (5.8 times the corpus's body
    acceleration on the test split): the second difference weighs that frame-to-frame noise four
    times as much as the first does."""
    vq_loss: str = "l1"
    """Reconstruction and velocity error of the PQ-VAE: ``l1`` (the paper's) or ``l2`` (squared)."""
    vq_decoder_from: str = ""
    """A probtalk model folder whose PQ-VAE decoder and codebooks the vq stage takes, frozen, fitting
    only a new encoder to them (``probtalk_decoder``): the refiner of shipped weights whose torch
    checkpoints are gone can then be retrained on their own decoder's reconstructions ("": none)."""
    balance_parts: bool = False
    """Weigh every part of the feature layout alike in the PQ-VAE's and the refiner's error, however many
    channels it has (False: every channel alike, the paper's). Channel-alike lets 180 hand channels
    outvote 12 of the head: the codes go to the hands and the head is left at its mean."""
    eyelid_part: bool = False
    """With ``balance_parts``: the eyelids (eyeBlinkLeft, eyeBlinkRight) count as a part of their own,
    not as 2 of ARKit's 52 channels. Blinks fill 1 frame in 60; weighed as 2 channels of 52 the
    PQ-VAE left them out (its reconstruction's lids never passed a third of the real blink's
    height), and so the sampled codes never blinked. FD_g face of the real validation motion with
    its blinks taken out: 6.7."""
    spine_part: bool = False
    """With ``balance_parts``: spine1..3 (the first 18 channels of the upper body) count as a part of
    their own. Their motion is slow posture drift and breathing, a few hundredths of a radian; as 18
    of the upper body's 66 channels the PQ-VAE left them at their mean, which alone cost 13 of its
    reconstruction's 22.6 FD_g body on the validation split (9.5 without them). Weighed as a part
    (small preset, seed 0) it helped little: validation recon FD_g body 28.7 against 32.0 at step
    3000 of 8000, face 9.7 against 9.2, the spine still about 11 of the body's FD at step 2300; off
    in the presets."""
    # conditions
    dyadic: bool = True
    """Hear the partner's audio as a second stream (False: self only, to measure what it adds)."""
    audio_channels: int = 256
    context_channels: tuple[int, ...] = (128, 128, 256, 512)
    """Motion-context encoder widths: first layer, then after each stride-2 step."""
    # predictor
    width: int = 512
    heads: int = 8
    layers: int = 6
    feedforward: int = 2048
    position: str = "2d"
    """``2d``: time encoding + group encoding of each code (the paper's); ``1d``: one encoding of the flat index."""
    # refiner
    refiner_width: int = 512
    refiner_heads: int = 8
    refiner_layers: int = 6
    refiner_feedforward: int = 2048
    refiner_noise: float = 0.05
    """Noise added to the VQ reconstructions the refiner learns to refine (the reference's 0.05)."""
    refiner_loss: str = "l1"
    """The refiner's error: ``l1`` (the paper's) or ``l2`` (squared). L1 settles each channel on its
    median, and the mouth's brief shapes (tongueOut at a TH, the lower lip rolled in at an F) are
    at rest in most frames: the shipped L1 refiner flattened tongueOut to a tenth of the
    reconstruction's spread (0.02 against 0.18, normalised, on the test split; the corpus 0.78)."""
    refiner_fd: float = 0.0
    """Weight of the Fréchet distance (poses and velocities, ``frechet_loss``) between the batch's
    refined and true frames of each of ``refiner_fd_groups``, beside the refiner's error (0: none,
    the paper's). Squared error leaves what the condition does not pin down at its conditional
    mean: the mouth's brief shapes came out smaller and blended into each other. Off in the presets
    for now. The face's term at 0.1, 3000 steps from the shipped predictor, took the test split's
    FD_g face from 2.11 to 1.01 (7 x 4, seeds 0-3, fp32; knn 1.10) and FD_k face from 1.12 to 0.11,
    but its mouth moved in silence on real voices (worst of 4, mouth shut while only the partner
    speaks 0.984 -> 0.922, the issue asks 0.97) and FD_g body went from 7.36 to 7.82; at 0.02
    the face scored 1.18 (seed 0)."""
    refiner_fd_groups: tuple[str, ...] = ("face",)
    """The groups ``refiner_fd`` weighs, each on its own (``REFINER_GROUPS``; ``face`` and ``body``
    as ``eval compare`` scores them). The body's term (``("face", "body")``, weight 0.1, 3000 steps)
    did worse on both: test split, seed 0, FD_g face 1.31 and body 8.06 against 1.02 and 7.26 with
    the face's alone. The spine's (``("face", "spine")``, the spine's target the truth, not a
    teacher's, and ``refiner_fd_by_speaker``) brings back part of what the codes leave out: the
    spine's mean spread over its channels 0.51 -> 0.62 (the truth's 0.70, normalised; test split,
    seeds 0-1), its FD_g 2.13 -> 1.91 (knn 1.38); spine2's lean still 0.12 against 0.57. Test split,
    7 x 4, seeds 0-7, int8: FD_g body 7.86 -> 7.42, face 0.886 -> 0.925. Tried beside it, a
    slow-noise input for the refiner to draw the spine from: a new draw moved the refined spine by
    0.02 standard deviations, and FD_g body scored 7.48."""
    refiner_fd_by_voice: bool = False
    """``refiner_fd`` apart over the frames where self speaks and where self is silent (``group_frechet``).
    At 0.1 and 3000 steps: FD_g face 1.04 (seed 0), the mouth shut while only the partner speaks on
    0.963 of the worst real dialogue's frames (with the term over all frames: 0.922), but FD_g body
    8.29 (seed 0)."""
    refiner_fd_by_speaker: bool = False
    """``refiner_fd`` on poses taken relative to their speaker's true mean over the batch
    (``relative_to_speaker``): the styles lean apart (spine1's lean on the train split,
    normalised: calm and steady +0.6 to +0.8, the others -0.2 to -0.4), and over the pooled batch
    the spine's distance settled every style on their average. Test split, seeds 0-7, int8, with
    the slow-noise input then tried: FD_g body 8.12 pooled, 7.48 by speaker."""
    refiner_shut: float = 0.0
    """Weight of a one-sided error on ``jawOpen`` in the free frames where self is silent: how far the
    refined jaw opens past the true one (``shut_mouth_error``). Spread learned from ``refiner_fd``
    shows first as a jaw ajar while the partner speaks; the error keeps the opening for self's voice.
    With ``refiner_fd`` 0.1 by voice, 3000 steps, from one vq and predictor (the script's, retrained
    on an AMD EPYC), test split seed 0, fp32, and real voices worst of 4, int8: without it FD_g face
    1.33, body 10.97, real voices with bleed shut where only the partner speaks 0.959, jaw r 0.699;
    at 1.0: 1.24, 9.28, 0.991, 0.73 (all four real-voice targets met, clean and with bleed); at 4.0:
    1.48, 9.61, 0.988. The same vq and predictor with the preset's refiner: 2.52, 10.75, 0.954.
    A second training seed (1) met the real-voice targets without it too (0.989; at 1.0: 0.987), FD_g
    face 1.57 -> 1.34, body 8.77 -> 9.68; at both seeds it kept the corpus's mouth shut where self is
    silent more often (0.967 -> 0.983, 0.963 -> 0.981)."""
    refiner_shown: bool = False
    """The refiner's losses read its motion as the run shows it: ARKit shapes clipped to [0, 1]
    (``shown_motion``). Its distance term then matches the clipped spread, and its error asks only
    that a shape at rest in the truth stays at or below rest. Without it, the refined shapes' small
    excursions around rest, clipped, left the mouth's rare shapes (tongueOut, mouthRollLower) ajar
    in a quarter of the frames: the face's mean was off by 0.22 of its FD_g 1.04 (test split, seeds
    0-1). With ``refiner_fd`` 0.1, ``refiner_shut`` 2.0 and ``refiner_teacher``, 3000 steps, test
    split seeds 0-7, int8: FD_g face 0.886 against 1.105 without it (knn 1.10), body 7.86 against
    7.71. Tried beside it: ``refiner_fd`` 0.05 (seeds 0-3: face 0.915, body 7.82); the taught
    body's error weighed 3 times (seeds 0-7: face 1.03, body 7.74); 1000 steps of it from the
    refiner before (seeds 0-3: face 1.01, body 7.94)."""
    refiner_teacher: str = ""
    """A probtalk model folder whose refiner, run on the same input, gives the target of
    ``refiner_teacher_groups`` in place of the truth (``probtalk_teacher``): a refiner retrained
    for the face keeps what the folder's refiner did for the body ("": none, the truth for all).
    With ``refiner_fd`` 0.1 and ``refiner_shut`` 2.0, 3000 steps on the shipped decoder, test split
    seeds 0-3, int8: FD_g body 7.55 against 7.84 without it (the old refiner's: 7.36), face 1.14
    against 1.27. At ``refiner_fd`` 0.2: body 7.85, face 1.18. Tried beside it and dropped: half the
    windows' input drawn by the folder's own predictor, as at run time (the face's target still the
    truth): body 7.91, face 1.45, the squared error against the truth of a drawn window pulled its
    face to the mean."""
    refiner_teacher_groups: tuple[str, ...] = ("body",)
    """The groups whose target ``refiner_teacher`` gives (``REFINER_GROUPS``)."""
    speaker_dim: int = 512
    """Size of the speaker embedding that modulates every sub-layer."""
    dropout: float = 0.1
    # training windows
    window: int = 184
    """Frames per training window (a multiple of 8: 23 tokens, the paper's 180 frames rounded up)."""
    min_window: int = 48
    """Shortest random crop, so the short windows of ``live`` mode are seen in training."""
    context_frames: int = 30
    """Known frames of the reference's context masks (and of the ``file`` mode's windows)."""

    @property
    def frames_per_token(self) -> int:
        return 2 ** (len(self.vq_channels) - 1)

    @property
    def mask_id(self) -> int:
        """The token id of a masked code (one past the last code)."""
        return self.codes

    def check(self) -> None:
        """ValueError naming the first inconsistent setting."""
        if len(self.vq_channels) < 2 or len(self.context_channels) != len(self.vq_channels):
            raise ValueError("vq_channels and context_channels need the same length, at least 2")
        if self.width % self.heads or self.refiner_width % self.refiner_heads:
            raise ValueError("width must be a multiple of heads (predictor and refiner)")
        for name in ("refiner_fd_groups", "refiner_teacher_groups"):
            if not set(getattr(self, name)) <= set(REFINER_GROUPS):
                raise ValueError(f"{name} may hold {', '.join(REFINER_GROUPS)}; got {getattr(self, name)!r}")
        for name in ("vq_loss", "refiner_loss"):
            if getattr(self, name) not in ("l1", "l2"):
                raise ValueError(f"{name} must be 'l1' or 'l2', got {getattr(self, name)!r}")
        if self.position not in ("2d", "1d"):
            raise ValueError(f"position must be '2d' or '1d', got {self.position!r}")
        f = self.frames_per_token
        if self.window % f or self.min_window % f or not f <= self.min_window <= self.window:
            raise ValueError(f"window and min_window must be multiples of {f} with min_window <= window")
        if not 0 <= self.context_frames < self.window:
            raise ValueError("context_frames must be below window")
