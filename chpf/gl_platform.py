"""Choose the headless OpenGL platform (``PYOPENGL_PLATFORM``) before PyOpenGL is imported.

Order: a user-set ``PYOPENGL_PLATFORM`` wins; else ``egl`` when there is no ``DISPLAY`` and
libEGL loads; else ``osmesa`` when libOSMesa loads; else (only when a ``DISPLAY`` is set) ``egl``
if libEGL loads -- pyrender's EGL platform renders offscreen through an EGL device, display or
not; else a ``RenderError`` naming the Debian packages to install.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import warnings

from chpf.errors import RenderError

EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
OSMESA_PACKAGES = "libosmesa6"

_EGL_NAMES = ("libEGL.so.1", "libEGL.so")
_OSMESA_NAMES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def _can_load(names: tuple[str, ...], short: str) -> bool:
    """True if one of the shared libraries ``names`` (or ``find_library(short)``) loads."""
    candidates = list(names)
    found = ctypes.util.find_library(short)
    if found:
        candidates.append(found)
    for name in candidates:
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return True
    return False


def egl_available() -> bool:
    """True if libEGL can be loaded."""
    return _can_load(_EGL_NAMES, "EGL")


def osmesa_available() -> bool:
    """True if libOSMesa can be loaded."""
    return _can_load(_OSMESA_NAMES, "OSMesa")


def select_gl_platform() -> str:
    """Set ``os.environ["PYOPENGL_PLATFORM"]`` (if unset) and return it: "egl" or "osmesa".

    Must run before ``OpenGL`` / ``pyrender`` is imported; if PyOpenGL was already imported the
    variable is still set but a warning says it may have no effect.
    """
    user = os.environ.get("PYOPENGL_PLATFORM", "").strip()
    if user:
        return user
    has_display = bool(os.environ.get("DISPLAY"))
    if not has_display and egl_available():
        platform = "egl"
    elif osmesa_available():
        platform = "osmesa"
    elif has_display and egl_available():
        platform = "egl"
    else:
        raise RenderError(
            "no headless OpenGL found (neither libEGL nor libOSMesa loads): install "
            f"'{EGL_PACKAGES}' (EGL) or '{OSMESA_PACKAGES}' (OSMesa) with apt-get, "
            "or set PYOPENGL_PLATFORM"
        )
    if "OpenGL" in sys.modules:
        warnings.warn(
            f"PyOpenGL was imported before select_gl_platform(); PYOPENGL_PLATFORM={platform} "
            "may have no effect",
            RuntimeWarning,
            stacklevel=2,
        )
    os.environ["PYOPENGL_PLATFORM"] = platform
    return platform
