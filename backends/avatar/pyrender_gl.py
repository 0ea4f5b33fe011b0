"""Headless OpenGL for pyrender: pick EGL or OSMesa before OpenGL is imported, and patch pyrender.

PyOpenGL binds to one platform (GLX, EGL, OSMesa) the first time ``OpenGL`` is imported, read
from ``PYOPENGL_PLATFORM``; it cannot switch afterwards. So the choice is made once per process,
by rendering a tiny scene in a child process for each candidate (EGL first: it is faster and can
use a GPU; OSMesa is pure software and always works where libOSMesa is installed). A user who
sets ``PYOPENGL_PLATFORM`` gets exactly that platform, checked in this process.

pyrender 0.1.45 pins PyOpenGL==3.1.0, whose EGL/OSMesa bindings MuJoCo cannot use. We install
pyrender with ``--no-deps`` next to PyOpenGL>=3.1.7; its offscreen path works there. It also uses
``np.infty``, removed in NumPy 2.0, so ``import_pyrender`` restores that alias before importing it.
"""

from __future__ import annotations

import os
from types import ModuleType
from typing import Any

from convodrive.plumbing.errors import UserError
from convodrive.plumbing.headless_gl import CANDIDATES, loaded_opengl_platform, probe_in_child

_PROBE = """
import numpy as np
if not hasattr(np, "infty"):
    np.infty = np.inf
import pyrender
r = pyrender.OffscreenRenderer(16, 16)
s = pyrender.Scene(bg_color=[0.0, 1.0, 0.0, 1.0])
s.add(pyrender.PerspectiveCamera(yfov=1.0))
color, _ = r.render(s)
from convodrive.backends.avatar.pyrender_gl import delete_offscreen
delete_offscreen(r)
assert color.shape == (16, 16, 3) and color[8, 8, 1] > 200, "offscreen render returned no image"
"""

_chosen: str | None = None


def _probe(platform: str, timeout: float = 60.0) -> str | None:
    """Render 16x16 in a child process under ``platform``; None when it works, else the reason."""
    return probe_in_child(platform, _PROBE, timeout)


def _probe_here(platform: str) -> str | None:
    """Like ``_probe`` but in this process, for a platform that is already decided."""
    os.environ["PYOPENGL_PLATFORM"] = platform
    try:
        exec(compile(_PROBE, "<gl probe>", "exec"), {})
    except Exception as exc:  # any failure of the GL stack is reported as one line
        return f"{type(exc).__name__}: {exc}".splitlines()[0]
    return None


def select_platform() -> str:
    """Choose and set ``PYOPENGL_PLATFORM`` for this process; raise one ``UserError`` line if none works."""
    global _chosen
    if _chosen is not None:
        return _chosen
    loaded = loaded_opengl_platform()
    if loaded is not None:
        if loaded not in CANDIDATES:
            raise UserError(
                f"render: OpenGL was already loaded for '{loaded}', which cannot render headless; "
                "set PYOPENGL_PLATFORM=egl or osmesa before starting convodrive"
            )
        _chosen = loaded
        os.environ["PYOPENGL_PLATFORM"] = loaded
        return loaded
    requested = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    candidates = (requested,) if requested else CANDIDATES
    failures = []
    for platform in candidates:
        # a platform the user named binds this process anyway: check it here, not in a child
        reason = _probe_here(platform) if requested else _probe(platform)
        if reason is None:
            os.environ["PYOPENGL_PLATFORM"] = platform
            _chosen = platform
            return platform
        failures.append(f"{platform}: {reason}")
    hint = (
        f"unset PYOPENGL_PLATFORM or set it to {' or '.join(CANDIDATES)}"
        if requested and requested not in CANDIDATES
        else "install libegl1 + libgl1-mesa-dri (EGL) or libosmesa6 (OSMesa)"
    )
    raise UserError(f"render: no headless OpenGL works ({'; '.join(failures)}); {hint}")


def delete_offscreen(renderer: Any) -> None:
    """Free a pyrender ``OffscreenRenderer`` without ``eglTerminate``.

    pyrender's own ``delete`` terminates the EGL display, which is one object per device in a
    process: it would kill every other live context on it (a second renderer, MuJoCo's camera).
    So for EGL we destroy only our context; other platforms use pyrender's ``delete``.
    """
    platform = getattr(renderer, "_platform", None)
    if platform is None:
        return
    if type(platform).__name__ != "EGLPlatform":
        renderer.delete()
        return
    from OpenGL import EGL

    platform.make_current()
    renderer._renderer.delete()
    EGL.eglMakeCurrent(platform._egl_display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
    EGL.eglDestroyContext(platform._egl_display, platform._egl_context)
    platform._egl_context = platform._egl_display = None
    renderer._renderer = renderer._platform = None


def import_pyrender() -> ModuleType:
    """Select the platform, apply the NumPy 2 alias pyrender needs, and import pyrender."""
    select_platform()
    import numpy as np

    if not hasattr(np, "infty"):  # pyrender.mesh.Mesh.bounds uses np.infty (removed in NumPy 2.0)
        np.infty = np.inf  # type: ignore[attr-defined]
    import pyrender

    return pyrender
