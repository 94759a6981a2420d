"""Choosing MuJoCo's headless OpenGL backend, without importing MuJoCo.

MuJoCo fixes its backend from `MUJOCO_GL` when it is first imported; unset, it takes GLFW,
which needs a display. `choose_gl` sets `MUJOCO_GL` to EGL, else OSMesa, whichever library
the system has, so `ncs_lite/__init__.py` calls it before anything can import MuJoCo.
"""
from __future__ import annotations

import ctypes.util
import os
import sys

GL_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
# whether MuJoCo was imported before the kit could choose (then its default stands)
MUJOCO_IMPORTED_FIRST = False


def choose_gl() -> str | None:
    """Set MUJOCO_GL to the first headless backend whose library exists, unless it is set
    already or MuJoCo was imported already (which fixed it). Returns the value in force."""
    global MUJOCO_IMPORTED_FIRST
    if "MUJOCO_GL" in os.environ:
        return os.environ["MUJOCO_GL"]
    if "mujoco" in sys.modules:
        MUJOCO_IMPORTED_FIRST = True
        return None
    for backend, lib in GL_LIBRARIES.items():
        if ctypes.util.find_library(lib):
            os.environ["MUJOCO_GL"] = backend
            return backend
    return None


def render_failure_advice() -> str:
    """What to install or set, for the message of a failed renderer."""
    found = {b: bool(ctypes.util.find_library(lib)) for b, lib in GL_LIBRARIES.items()}
    advice = (f"It needs EGL (libEGL, found: {found['egl']}) or OSMesa (libOSMesa, found: {found['osmesa']}): "
              "install Mesa's (e.g. `apt install libegl1` or `libosmesa6`) and set MUJOCO_GL=egl or "
              "MUJOCO_GL=osmesa before Python starts")
    if MUJOCO_IMPORTED_FIRST and "MUJOCO_GL" not in os.environ:
        advice += ("; here mujoco was imported before ncs_lite, so it kept its display-bound default: "
                   "import ncs_lite first, or set MUJOCO_GL")
    return advice
