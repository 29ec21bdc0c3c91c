"""Test-session settings: one torch thread (on a 2-core machine two threads fight the renderer
and the other test processes; one thread was measured faster under load) and headless EGL."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import torch  # noqa: E402

torch.set_num_threads(1)
