"""Comparison harness: simulation, sensing, scenarios, metrics, CLI."""

import os

# Headless by default: MuJoCo picks its OpenGL backend when it is first imported, and its default
# (GLFW) aborts the process without a display. Set before any module of the harness imports it.
os.environ.setdefault("MUJOCO_GL", "egl")

from robots.kernel_cache import use_kernel_cache  # noqa: E402

use_kernel_cache()  # the harness's own kernels share the project's cache (robots.kernel_cache)
