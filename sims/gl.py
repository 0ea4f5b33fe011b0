"""Headless OpenGL selection for MuJoCo, made once per process before ``import mujoco``.

MuJoCo and PyOpenGL fix their GL platform when first imported, so the choice must precede the
import: an explicit ``MUJOCO_GL`` wins, then an explicit ``PYOPENGL_PLATFORM`` (so MuJoCo agrees
with another renderer in the same process), else EGL is probed, then OSMesa, each in a short
subprocess so that a broken driver cannot crash this one. Neither working leaves rendering off,
with the reason kept for the run report; physics never depends on it.
"""

from __future__ import annotations

import os
import sys

from convodrive.plumbing.headless_gl import CANDIDATES, probe_in_child

_PROBE = "import mujoco; c = mujoco.GLContext(16, 16); c.make_current(); c.free()"
_choice: tuple[str | None, str] | None = None


def _rebind(platform: str) -> None:
    """mujoco was imported first and bound its default (GLFW, which needs a display): re-import
    its GL context module now that MUJOCO_GL names a headless platform. Renderers created from
    here on use it."""
    import importlib

    try:
        from mujoco.rendering.classic import gl_context

        importlib.reload(gl_context)
    except Exception:  # keep whatever mujoco had; a render failure will say why
        pass


def select_gl() -> tuple[str | None, str]:
    """(platform or None, reason). Sets MUJOCO_GL and PYOPENGL_PLATFORM when it can still matter."""
    global _choice
    if _choice is not None:
        return _choice
    late = "mujoco" in sys.modules
    if late and os.environ.get("MUJOCO_GL", "").lower() in ("egl", "osmesa", "glx", "glfw"):
        _choice = (os.environ["MUJOCO_GL"], "chosen before mujoco was imported")
        return _choice
    explicit = os.environ.get("MUJOCO_GL") or os.environ.get("PYOPENGL_PLATFORM")
    if explicit:
        os.environ["MUJOCO_GL"] = explicit
        if explicit in ("egl", "osmesa"):
            os.environ.setdefault("PYOPENGL_PLATFORM", explicit)
            if late:  # e.g. pyrender chose the platform after mujoco was imported
                _rebind(explicit)
        _choice = (explicit, "set by the environment")
        return _choice
    failures = []
    for platform in CANDIDATES:
        why = probe_in_child(platform, _PROBE)
        if why is None:
            os.environ["MUJOCO_GL"] = platform
            os.environ.setdefault("PYOPENGL_PLATFORM", platform)
            if late:
                _rebind(platform)
            _choice = (platform, "probed")
            return _choice
        failures.append(f"{platform}: {why}")
    os.environ["MUJOCO_GL"] = "disable"
    _choice = (None, "no headless OpenGL (MUJOCO_GL=egl or osmesa) works here: " + "; ".join(failures))
    return _choice
