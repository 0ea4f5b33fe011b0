"""Loading MJCF files for the simulator and for IK, with the edits both need.

A conversational body stays in its chair: a model whose root is a free joint (most humanoids that
packages ship are built to walk) gets that joint removed, which welds the root body to the world
where it stands. Errors in a user's MJCF become one-line ``InputFileError``s.
"""

from __future__ import annotations

from pathlib import Path

from convodrive.sims.gl import select_gl

select_gl()  # must precede the first import of mujoco in this process

import mujoco  # noqa: E402

from convodrive.plumbing.errors import InputFileError  # noqa: E402


def load_spec(path: str | Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_file(str(path))
    except (ValueError, OSError) as exc:
        raise InputFileError(path, f"cannot load MJCF: {str(exc).splitlines()[0] if str(exc) else exc}") from None


def fix_root(spec: mujoco.MjSpec) -> list[str]:
    """Delete free joints, welding their bodies in place; returns the deleted joints' names."""
    free = [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_FREE]
    names = [j.name for j in free]
    for joint in free:
        spec.delete(joint)
    return names


def compile_spec(spec: mujoco.MjSpec, path: str | Path) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        raise InputFileError(path, f"cannot compile MJCF: {str(exc).splitlines()[0]}") from None


def load_model(path: str | Path, weld_root: bool = True) -> mujoco.MjModel:
    spec = load_spec(path)
    if weld_root:
        fix_root(spec)
    return compile_spec(spec, path)


def hinge_qpos_addresses(model: mujoco.MjModel, names: tuple[str, ...] | list[str], source: str | Path) -> list[int]:
    """qpos index of each named hinge or slide joint; a missing joint is the profile's mistake."""
    out = []
    for name in names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise InputFileError(source, f"joints.{name}: no joint of that name in the model")
        if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise InputFileError(source, f"joints.{name}: model joint is not a hinge or slide")
        out.append(int(model.jnt_qposadr[jid]))
    return out
