"""What the ``mujoco`` backend makes of a MuJoCo model before it runs: its options, which MJCF to
load, and the position actuators it adds so that any model can be driven."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.backends.base import RobotOptions
from convodrive.motion.targets import TargetSpec
from convodrive.plugins.options import option
from convodrive.plumbing.errors import InputFileError, UserError


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:300]}"


def resolve_model(model: str | None, spec: TargetSpec) -> Path:
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


def position_actuator(m: Any, jid: int, model_path: Path | None) -> int:
    """The position actuator of joint ``jid`` (InputFileError when it has none)."""
    import mujoco

    for a in range(m.nu):
        if (
            int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            and m.actuator_trnid[a, 0] == jid
            and int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
            and m.actuator_biasprm[a, 1] < 0
        ):
            return a
    raise InputFileError(model_path, f"joint {m.joint(jid).name!r} has no position actuator")


def add_position_actuators(mspec: Any, model: Any, driven: tuple[str, ...], options: MujocoOptions) -> list[str]:
    """Give every driven (and, if asked, every other) hinge a position actuator; drop motors on
    them. Returns the joints that got one."""
    import mujoco

    def is_position(act: Any) -> bool:
        return act.biastype == mujoco.mjtBias.mjBIAS_AFFINE and act.biasprm[1] < 0

    targets = set(driven)
    if options.hold_unmapped:
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
        return []
    for act in list(mspec.actuators):
        if act.trntype == mujoco.mjtTrn.mjTRN_JOINT and act.target in needed:
            mspec.delete(act)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    omega = options.omega
    added = []
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
        added.append(name)
    # Stiff servos on light links need the velocity terms integrated implicitly.
    mspec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return added
