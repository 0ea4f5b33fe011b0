"""The retargeter: canonical motion frames in, a robot's joint values out, at 30 fps.

Stages, in order: channel maps (and IK where the profile asks for it), smoothing, then the
limiter (position, velocity, acceleration). Limits are always enforced here, so a backend's own
check is a second guard, never the first. ``__call__`` is the streaming path (stateful, one frame
at a time); ``retarget_clip`` does a whole clip with fresh state, the maps vectorised over time.
"""

from __future__ import annotations

import numpy as np

from convodrive import FPS
from convodrive.motion.clip import MotionClip, MotionFrame
from convodrive.motion.targets import TargetSpec
from convodrive.retargeting.filters import Smoother
from convodrive.retargeting.limits import MotionLimiter
from convodrive.retargeting.maps import ChannelMaps
from convodrive.retargeting.profile import RobotProfile


class Retargeter:
    def __init__(self, profile: RobotProfile, fps: float = FPS) -> None:
        self.profile = profile
        self.spec: TargetSpec = profile.spec
        self.dt = 1.0 / fps
        self.maps = ChannelMaps(profile.joints)
        self._smoother = self._new_smoother()
        self._limiter = MotionLimiter(self.spec)
        self.ik = None
        if profile.ik is not None:
            from convodrive.retargeting.ik import IKSolver  # mujoco and mink only when a profile needs them

            self.ik = IKSolver(profile)

    def _new_smoother(self) -> Smoother:
        return Smoother([j.smoothing for j in self.profile.joints])

    def reset(self) -> None:
        """Forget filter, limiter and IK state (a new run or a jump in time)."""
        self._smoother.reset()
        self._limiter.reset()
        if self.ik is not None:
            self.ik.reset()

    def raw(self, pose: np.ndarray, translation: np.ndarray, face: np.ndarray) -> np.ndarray:
        """(T, J) values from maps and IK, before smoothing and limits."""
        values = self.maps(pose, translation, face)
        if self.ik is not None:
            glob_r, glob_p = self.ik.canonical_fk(pose)
            for t in range(len(values)):
                values[t, self.ik.ik_cols] = self.ik.solve(values[t], glob_r[t], glob_p[t])
        return values

    def __call__(self, frame: MotionFrame) -> np.ndarray:
        raw = self.raw(frame.pose[None], frame.translation[None], frame.face[None])[0]
        return self._limiter(self._smoother(raw, self.dt), self.dt)

    def retarget_clip(self, clip: MotionClip) -> np.ndarray:
        """(T, J) limited values for a whole clip, from fresh state (the streaming state is untouched)."""
        if self.ik is not None:
            self.ik.reset()
        raw = self.raw(clip.pose, clip.translation, clip.face)
        dt = 1.0 / clip.fps
        smoothed = self._new_smoother().batch(raw, dt)
        limiter = MotionLimiter(self.spec)
        out = np.empty_like(raw)
        for t in range(len(raw)):
            out[t] = limiter(smoothed[t], dt)
        if self.ik is not None:
            self.ik.reset()
        return out
