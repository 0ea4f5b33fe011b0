"""The ``mujoco`` backend: target frames drive a MuJoCo model's position actuators, filmed offscreen.

Each frame sets the actuator targets and advances physics by exactly 1/30 s of simulated time at
the model's own timestep, so simulation stays in lock step with the 30 fps clock (offline runs go
as fast as the CPU allows; real-time runs are paced by the scheduler). Tracking error, commanded
versus simulated joint angle, is accumulated per joint and reported in degrees.

Any MJCF works: a model's free root joint is removed (welding it in its chair), and a joint the
profile drives without a position actuator gets one, its gain set from the joint's effective
inertia so that every joint tracks at about the same natural frequency. Rendering is optional
equipment: if no headless GL works, or the renderer fails mid-run, physics and the tracking
report carry on and the report says why there is no video.

Options: ``mujoco_setup.MujocoOptions`` (``convodrive plugins mujoco`` lists them). The MJCF is the
option ``model``, else the robot profile's ``model`` (carried by the target spec), else the
bundled model named like the target.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, Session
from convodrive.backends.mujoco_setup import (
    MujocoOptions,
    add_position_actuators,
    one_line,
    position_actuator,
    resolve_model,
)
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions
from convodrive.plumbing.errors import InputFileError, UserError

log = logging.getLogger(__name__)

NECK_HEAD = ("neck", "head")


class MujocoBackend(Backend):
    name = "mujoco"
    description = "MuJoCo physics: position-controlled humanoid or servo-head twin, offscreen mp4, tracking report"
    realtime = False
    may_run_in_process = True
    default_profile = "convo_humanoid"
    requires = ("mujoco",)
    extra = "sim"
    Options = MujocoOptions
    options: MujocoOptions

    def __init__(self, options: PluginOptions | Mapping[str, Any] | None = None) -> None:
        super().__init__(options)
        self.width = self.options.width
        self.height = self.options.height
        self.model: Any = None
        self.data: Any = None
        self.model_path: Path | None = None
        self.frames = 0
        self.refused = 0
        self.physics_seconds = 0.0
        self.sim_seconds = 0.0
        self.steps_total = 0
        self.render_seconds = 0.0
        self.video_path: Path | None = None
        self.video_error: str | None = None
        self.gl: str | None = None
        self.added_actuators: list[str] = []
        self._writer: Any = None
        self._renderer: Any = None
        self._viewer: Any = None
        self._camera: Any = None
        self._gl_thread: Any = None
        self.viewer_error: str | None = None

    # -- setup -----------------------------------------------------------------------------
    def open(self, spec: TargetSpec, session: Session) -> None:
        super().open(spec, session)
        import mujoco

        from convodrive.sims.gl import select_gl
        from convodrive.sims.mjcf import compile_spec, fix_root, load_spec

        self.gl, gl_reason = select_gl()
        self.model_path = resolve_model(self.options.model, spec)
        mspec = load_spec(self.model_path)
        if self.options.weld_root:
            fix_root(mspec)
        if self.options.gravcomp:
            for body in mspec.bodies:
                body.gravcomp = 1.0
        self.added_actuators = add_position_actuators(
            mspec, compile_spec(mspec, self.model_path), spec.names, self.options
        )
        self.model = compile_spec(mspec, self.model_path)
        self.data = mujoco.MjData(self.model)
        m = self.model

        self.qadr = np.zeros(len(spec.names), dtype=int)
        self.act = np.zeros(len(spec.names), dtype=int)
        for i, name in enumerate(spec.names):
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise InputFileError(self.model_path, f"has no joint {name!r}, which target {spec.name!r} drives")
            self.qadr[i] = m.jnt_qposadr[jid]
            self.act[i] = position_actuator(m, jid, self.model_path)
        self.sq_err = np.zeros(len(spec.names))
        self.max_err = np.zeros(len(spec.names))
        self.frames = 0

        if self.options.video:
            if self.gl is None:
                self.video_error = gl_reason
                log.warning("mujoco: no video: %s", gl_reason)
            else:
                self._open_video(session)
        if self.options.viewer and not os.environ.get("DISPLAY"):
            self.viewer_error = "no display (DISPLAY is not set)"
        elif self.options.viewer:
            try:
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(m, self.data)
            except Exception as exc:  # a viewer is a convenience, never a reason to fail the run
                self._viewer = None
                self.viewer_error = one_line(exc)

    def _on_gl_thread(self, fn: Any, *args: Any) -> Any:
        """Run ``fn`` on the one thread that owns the GL context.

        A GL context is current in one thread at a time, and the scheduler opens, feeds and closes
        a backend from different threads; so every GL call goes through this single worker.
        """
        if self._gl_thread is None:
            from concurrent.futures import ThreadPoolExecutor

            self._gl_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mujoco-gl")
        return self._gl_thread.submit(fn, *args).result()

    def _make_renderer(self) -> Any:
        import mujoco

        renderer = mujoco.Renderer(self.model, self.height, self.width)
        if not self.options.shadows:  # software GL: shadows cost ~10x the frame time
            for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
                renderer.scene.flags[flag] = 0
        return renderer

    def _render(self) -> np.ndarray:
        self._renderer.update_scene(self.data, camera=self._camera)
        return self._renderer.render()

    def _open_video(self, session: Session) -> None:
        import mujoco

        from convodrive.plumbing.video import VideoWriter

        try:
            m = self.model
            m.vis.global_.offwidth = max(m.vis.global_.offwidth, self.width)
            m.vis.global_.offheight = max(m.vis.global_.offheight, self.height)
            m.vis.quality.offsamples = self.options.msaa  # 4x MSAA costs ~2.5x on software GL
            self._renderer = self._on_gl_thread(self._make_renderer)
            cam = self.options.camera
            if cam == "free":
                cam = None
            elif cam is None and m.ncam:
                cam = "front" if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "front") >= 0 else m.camera(0).name
            if cam is not None:
                if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, str(cam)) < 0:
                    raise UserError(f"backend mujoco: option 'camera': no camera {cam!r} in {self.model_path}")
                self._camera = str(cam)
            else:
                self._camera = self._free_camera()
            self.video_path = Path(session.out_dir) / "mujoco.mp4"
            self._writer = VideoWriter(
                self.video_path, self.width, self.height, fps=session.fps, audio_path=session.audio_path
            )
        except UserError:
            raise
        except Exception as exc:
            self._drop_video(f"offscreen rendering unavailable ({self.gl}): {one_line(exc)}")

    def _free_camera(self) -> Any:
        """A camera looking at the model's upper half from the front (+X), for models with none."""
        import mujoco

        cam = mujoco.MjvCamera()
        mujoco.mj_forward(self.model, self.data)
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        points = self.data.xpos[1:] if self.model.nbody > 1 else self.data.xpos  # bodies, not the floor
        lo, hi = points.min(axis=0), points.max(axis=0)
        cam.lookat[:] = (lo + hi) / 2.0
        cam.distance = 1.8 * max(float(np.max(hi - lo)), 0.2)
        cam.azimuth, cam.elevation = 180.0, -10.0
        return cam

    def _drop_video(self, reason: str) -> None:
        self.video_error = reason
        log.warning("mujoco: video dropped: %s", reason)
        if self._writer is not None:
            self._writer.abort()
        self._writer = None
        self.video_path = None
        self._close_renderer()

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            try:
                self._on_gl_thread(self._renderer.close)
            except Exception:
                pass
            self._renderer = None
        if self._gl_thread is not None:
            self._gl_thread.shutdown(wait=True)
            self._gl_thread = None

    # -- per frame ------------------------------------------------------------------------
    def send(self, frame: TargetFrame) -> None:
        import mujoco

        values = np.asarray(frame.values, np.float64)
        if (
            values.shape != (len(self.spec.names),)
            or not np.all(np.isfinite(values))
            or not self.spec.within_limits(values, 1e-6)
        ):
            self.refused += 1  # second guard: the retargeter enforces limits, a bad frame is not applied
            values = None
        m, d = self.model, self.data
        t0 = time.perf_counter()
        if values is not None:
            if self.frames == 0:
                d.qpos[self.qadr] = values  # start where the motion starts, not at the model's rest pose
                d.qvel[:] = 0.0
                mujoco.mj_forward(m, d)
            d.ctrl[self.act] = values
        # Lock step with the clock: simulate up to the end of this frame's 1/30 s, so whole
        # timesteps that do not divide 1/30 s (17 x 2 ms = 34 ms) never drift from the audio.
        target = (frame.index + 1) / self.session.fps
        steps = max(0, int(round((target - self.sim_seconds) / m.opt.timestep)))
        for _ in range(steps):
            mujoco.mj_step(m, d)
        self.steps_total += steps
        self.sim_seconds += steps * m.opt.timestep
        self.physics_seconds += time.perf_counter() - t0
        if values is not None:
            err = d.qpos[self.qadr] - values
            self.sq_err += err * err
            self.max_err = np.maximum(self.max_err, np.abs(err))
            self.frames += 1
        if self._writer is not None:
            t1 = time.perf_counter()
            try:
                self._writer.append(self._on_gl_thread(self._render))
            except Exception as exc:
                self._drop_video(f"rendering failed at frame {frame.index}: {one_line(exc)}")
            self.render_seconds += time.perf_counter() - t1
        if self._viewer is not None:
            try:
                if self._viewer.is_running():
                    self._viewer.sync()
            except Exception:
                self._viewer = None

    def close(self) -> None:
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception as exc:
                self._drop_video(f"video could not be finished: {one_line(exc)}")
            self._writer = None
        self._close_renderer()
        if self._viewer is not None:
            try:
                self._viewer.close()
            except Exception:
                pass
            self._viewer = None

    # -- reporting ------------------------------------------------------------------------
    def tracking(self) -> dict[str, dict[str, float]]:
        """Per joint: RMS and max of commanded minus simulated angle, degrees (rad joints only)."""
        n = max(self.frames, 1)
        out = {}
        for i, name in enumerate(self.spec.names):
            scale = math.degrees(1.0) if self.spec.units[i] == "rad" else 1.0
            out[name] = {"rms": float(np.sqrt(self.sq_err[i] / n) * scale), "max": float(self.max_err[i] * scale)}
        return out

    def _summary(self) -> dict[str, Any]:
        track = self.tracking()
        neck_head = [v["rms"] for k, v in track.items() if k.startswith(NECK_HEAD)]
        worst = max(track.items(), key=lambda kv: kv[1]["rms"]) if track else (None, {"rms": 0.0})
        sim_time = self.sim_seconds
        return {
            "frames": self.frames,
            "refused_frames": self.refused,
            "neck_head_rms_deg": max(neck_head) if neck_head else None,
            "worst_joint": worst[0],
            "worst_rms_deg": worst[1]["rms"],
            "physics_x_realtime": sim_time / self.physics_seconds if self.physics_seconds > 0 else None,
        }

    def health(self) -> dict[str, Any]:
        summary = self._summary()
        reasons = []
        if self.options.video and self.video_error is not None:
            reasons.append(f"no video: {self.video_error}")
        if self.refused:
            reasons.append(f"{self.refused} frames refused (outside the joint limits or not finite)")
        out = {"status": "degraded" if reasons else "ok", **summary, "video_error": self.video_error}
        if reasons:
            out["reason"] = "; ".join(reasons)
        return out

    def report(self) -> dict[str, Any]:
        return {
            "model": str(self.model_path) if self.model_path else None,
            "timestep": float(self.model.opt.timestep) if self.model is not None else None,
            "physics_steps": self.steps_total,
            "sim_seconds": round(self.sim_seconds, 4),
            "gl": self.gl,
            "video": str(self.video_path) if self.video_path else None,
            "video_error": self.video_error,
            "render_fps": self.frames / self.render_seconds if self.render_seconds > 0 else None,
            "added_actuators": self.added_actuators,
            "viewer_error": self.viewer_error,
            **self._summary(),
            "tracking_deg": self.tracking(),
        }

    def outputs(self) -> list[Path]:
        return [self.video_path] if self.video_path is not None and self.video_path.exists() else []
