"""MuJoCo's OpenGL backend for offscreen rendering: chosen once per process, checked once.

mujoco and dm_control read `MUJOCO_GL` when they are imported, so the choice is made
when `env_server` is imported, before either is. A `MUJOCO_GL` the user set is kept
(`disable` turns MuJoCo rendering off). Otherwise the first headless backend whose
libraries are installed is used: `egl` (libEGL with a vendor library: a GPU driver, or
Mesa's software renderer from libegl-mesa0), then `osmesa` (libOSMesa from libosmesa6).
Neither opens a display. When neither is installed the choice is `disable`, and
`require()` refuses with what to install. Worker processes inherit the choice with the
environment.

Deep Sea Treasure draws its frames with numpy and needs none of this.
"""

from __future__ import annotations

import ctypes.util
import glob
import os

from env_server.errors import FailedPrecondition

#: What makes rendering available when no backend works.
INSTALL_HINT = (
    "install Mesa's software OpenGL (as root: apt-get install libegl-mesa0 libosmesa6; "
    "scripts/setup.sh does this) and restart the server, or set MUJOCO_GL=egl or osmesa "
    "to a backend that works on this machine"
)
_EGL_VENDOR_DIRS = ("/usr/share/glvnd/egl_vendor.d", "/etc/glvnd/egl_vendor.d")
_OFF = ("disable", "disabled", "off", "false", "0")

_checked: str | None = None  # "" once a context was made, else why none could be


def _egl_installed() -> bool:
    vendors = [f for d in _EGL_VENDOR_DIRS for f in glob.glob(os.path.join(d, "*.json"))]
    return bool(vendors) and ctypes.util.find_library("EGL") is not None


def _osmesa_installed() -> bool:
    return ctypes.util.find_library("OSMesa") is not None


def detect() -> str:
    """The first headless backend whose libraries are installed, else "disable"."""
    if _egl_installed():
        return "egl"
    if _osmesa_installed():
        return "osmesa"
    return "disable"


def choose() -> str:
    """Set MUJOCO_GL (and PyOpenGL's platform to match) unless the user set it; returns it."""
    backend = os.environ.get("MUJOCO_GL")
    if backend is None:
        backend = os.environ["MUJOCO_GL"] = detect()
    if backend in ("egl", "osmesa"):
        # PyOpenGL picks its platform once, on first import; mujoco and dm_control need it to match.
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def backend() -> str:
    return os.environ.get("MUJOCO_GL", "")


def problem() -> str:
    """ "" when MuJoCo can render in this process, else why not (what to install or set).

    The first call makes and frees a 1 x 1 context (about 10 ms with EGL or OSMesa);
    later calls return the remembered answer.
    """
    global _checked
    if _checked is not None:
        return _checked
    name = backend()
    if name.lower() in _OFF:
        _checked = f"MuJoCo rendering is off in this server (MUJOCO_GL={name}); {INSTALL_HINT}"
        return _checked
    try:
        import mujoco

        context = mujoco.GLContext(1, 1)
        context.make_current()
        context.free()
        _checked = ""
    except Exception as exc:  # any failure to get a context means the same thing to a client
        _checked = (
            f"MuJoCo rendering needs OpenGL, and MUJOCO_GL={name or '(unset)'} could not make a context "
            f"({type(exc).__name__}: {exc}); {INSTALL_HINT}"
        )
    return _checked


def require() -> None:
    """Raise FailedPrecondition naming the missing piece unless MuJoCo can render here."""
    reason = problem()
    if reason:
        raise FailedPrecondition(reason)
