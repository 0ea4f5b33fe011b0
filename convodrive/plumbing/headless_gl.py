"""Headless OpenGL: the one place that knows how a GL platform is tried.

MuJoCo's camera and pyrender both draw offscreen, through EGL (fast; a GPU if there is one, else
Mesa's llvmpipe) or OSMesa (pure software). PyOpenGL binds to one platform the first time it is
imported and cannot switch, so each library picks before its import, by rendering a tiny image
in a child process for each candidate: a broken driver then crashes the child, not the run.
``convodrive.sims.gl`` and ``convodrive.backends.avatar.pyrender_gl`` hold the two probes.
"""

from __future__ import annotations

import os
import subprocess
import sys

CANDIDATES: tuple[str, ...] = ("egl", "osmesa")


def probe_in_child(platform: str, code: str, timeout: float = 60.0) -> str | None:
    """Run ``code`` in a child Python with ``platform`` for both MuJoCo and PyOpenGL.

    Returns None when it works, else the last line the child printed on stderr, as the reason.
    """
    env = dict(os.environ, MUJOCO_GL=platform, PYOPENGL_PLATFORM=platform)
    try:
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timed out"
    except OSError as exc:
        return str(exc)
    if proc.returncode == 0:
        return None
    lines = [ln.strip() for ln in proc.stderr.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit code {proc.returncode}"


def loaded_opengl_platform() -> str | None:
    """The platform an already-imported PyOpenGL is bound to (e.g. by MuJoCo's EGL context)."""
    if "OpenGL.platform" not in sys.modules:
        return None
    name = type(sys.modules["OpenGL.platform"].PLATFORM).__name__.lower()
    for platform in ("egl", "osmesa", "glx"):
        if platform in name:
            return platform
    return name
