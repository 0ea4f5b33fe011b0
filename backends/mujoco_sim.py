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

Options: ``MujocoOptions`` below (``convodrive plugins mujoco`` lists them). The MJCF is the
option ``model``, else the robot profile's ``model`` (carried by the target spec), else the
bundled model named like the target.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.base import Backend, RobotOptions, Session
from convodrive.motion.targets import TargetFrame, TargetSpec
from convodrive.plugins.options import PluginOptions, option
from convodrive.plumbing.errors import InputFileError, UserError

log = logging.getLogger(__name__)

NECK_HEAD = ("neck", "head")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:300]}"


def _resolve_model(model: str | None, spec: TargetSpec) -> Path:
    """The MJCF to load: option ``model`` (a path, or a file name in convodrive.sims), else the
    profile's model (``spec.model``), else the bundled model named like the target
    (``servo_head`` -> sims/servo_head.xml). A backend never reads profiles itself."""
    import importlib.resources

    def bundled(name: str) -> Path:
        return Path(str(importlib.resources.files("convodrive.sims").joinpath(name)))

    if model:
        path = Path(str(model)).expanduser()
        if path.is_file():
            return path
        if bundled(str(model)).is_file():
            return bundled(str(model))
        raise UserError(f"backend mujoco: option 'model': {model!r} is neither a file nor a model in convodrive.sims")
    if spec.model is not None:
        return spec.model
    if spec.name and bundled(f"{spec.name}.xml").is_file():
        return bundled(f"{spec.name}.xml")
    raise UserError(f"mujoco backend: no MJCF for target {spec.name!r}; give the option model: PATH")


@dataclasses.dataclass(frozen=True)
class MujocoOptions(RobotOptions):
    model: str | None = option(
        None, help="MJCF path or a file name in convodrive.sims; default: the robot profile's model"
    )
    video: bool = option(True, help="Film the model offscreen into mujoco.mp4 with the audio")
    width: int = option(640, low=16, high=4096, help="Video width in pixels (even)")
    height: int = option(480, low=16, high=4096, help="Video height in pixels (even)")
    camera: str | None = option(
        None, help='A camera of the model, or "free" for one framing it from the front; default "front", else the first'
    )
    msaa: int = option(
        0, choices=(0, 2, 4, 8), help="Multisample anti-aliasing (4 is smoother, ~2.5x slower on CPU GL)"
    )
    shadows: bool = option(False, help="Render shadows and reflections (ten times slower on software GL)")
    viewer: bool = option(False, help="Open a passive MuJoCo viewer when a display exists")
    weld_root: bool = option(True, help="Remove free joints, welding the model where it stands")
    gravcomp: bool = option(False, help="Compensate gravity on every body")
    omega: float = option(
        60.0, low=1, high=1000, help="Natural frequency (rad/s) of the position actuators the backend adds"
    )
    hold_unmapped: bool = option(True, help="Add actuators holding unmapped hinge joints at their rest angle")

    def __post_init__(self) -> None:
        if self.width % 2 or self.height % 2:
            raise ValueError(f"width and height must be even (H.264), got {self.width}x{self.height}")


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
        self.model_path = _resolve_model(self.options.model, spec)
        mspec = load_spec(self.model_path)
        if self.options.weld_root:
            fix_root(mspec)
        if self.options.gravcomp:
            for body in mspec.bodies:
                body.gravcomp = 1.0
        self._add_actuators(mspec, compile_spec(mspec, self.model_path))
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
            self.act[i] = self._position_actuator(jid)
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
                self.viewer_error = _one_line(exc)

    def _position_actuator(self, jid: int) -> int:
        import mujoco

        m = self.model
        for a in range(m.nu):
            if (
                int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                and m.actuator_trnid[a, 0] == jid
                and int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
                and m.actuator_biasprm[a, 1] < 0
            ):
                return a
        raise InputFileError(self.model_path, f"joint {m.joint(jid).name!r} has no position actuator")

    def _add_actuators(self, mspec: Any, model: Any) -> None:
        """Give every driven (and, if asked, every other) hinge a position actuator; drop motors on them."""
        import mujoco

        def is_position(act: Any) -> bool:
            return act.biastype == mujoco.mjtBias.mjBIAS_AFFINE and act.biasprm[1] < 0

        targets = set(self.spec.names)
        if self.options.hold_unmapped:
            # Joints coupled by an equality constraint (a mirrored eye) follow it, not a servo.
            coupled = {n for e in mspec.equalities if e.type == mujoco.mjtEq.mjEQ_JOINT for n in (e.name1, e.name2)}
            targets |= {
                model.joint(j).name
                for j in range(model.njnt)
                if int(model.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
                and model.joint(j).name not in coupled
            }
        has_position = {a.target for a in mspec.actuators if a.trntype == mujoco.mjtTrn.mjTRN_JOINT and is_position(a)}
        needed = [
            n for n in targets if n not in has_position and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) >= 0
        ]
        if not needed:
            return
        for act in list(mspec.actuators):
            if act.trntype == mujoco.mjtTrn.mjTRN_JOINT and act.target in needed:
                mspec.delete(act)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        omega = self.options.omega
        for name in sorted(needed):
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            inertia = full[model.jnt_dofadr[jid], model.jnt_dofadr[jid]]
            act = mspec.add_actuator()
            act.name = f"convodrive_{name}"
            act.trntype = mujoco.mjtTrn.mjTRN_JOINT
            act.target = name
            act.set_to_position(kp=inertia * omega**2, kv=2.0 * inertia * omega)
            if model.jnt_limited[jid]:
                act.ctrllimited = True
                act.ctrlrange = model.jnt_range[jid]
            self.added_actuators.append(name)
        # Stiff servos on light links need the velocity terms integrated implicitly.
        mspec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST

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
            self._drop_video(f"offscreen rendering unavailable ({self.gl}): {_one_line(exc)}")

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
                self._drop_video(f"rendering failed at frame {frame.index}: {_one_line(exc)}")
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
                self._drop_video(f"video could not be finished: {_one_line(exc)}")
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
