"""Choose MuJoCo's headless OpenGL backend before ``mujoco`` is imported.

``MUJOCO_GL`` set by the user is respected. Otherwise EGL is used when libEGL is found (GPU or
Mesa), then OSMesa; :func:`gl_error_hint` explains what to install when neither works.
"""

from __future__ import annotations

import ctypes.util
import os


def select_backend() -> str | None:
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    for backend, lib in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(lib):
            os.environ["MUJOCO_GL"] = backend
            if backend == "osmesa":
                os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
            return backend
    return None


def gl_error_hint(err: BaseException) -> RuntimeError:
    backend = os.environ.get("MUJOCO_GL", "<unset>")
    return RuntimeError(
        f"headless rendering failed with MUJOCO_GL={backend!r}: {type(err).__name__}: {err}. "
        "Install the GL libraries (Debian: apt-get install -y libegl1 libegl-mesa0 "
        "libgl1-mesa-dri libosmesa6; scripts/setup.sh does this) or set MUJOCO_GL=egl|osmesa."
    )
