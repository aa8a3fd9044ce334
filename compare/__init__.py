"""Comparison harness: simulation, sensing, scenarios, metrics, CLI."""

import os

# Headless by default: MuJoCo picks its OpenGL backend when it is first imported, and its default
# (GLFW) aborts the process without a display. Set before any module of the harness imports it.
os.environ.setdefault("MUJOCO_GL", "egl")
# Mesa's software rasterizer (llvmpipe, the headless renderer without a GPU) draws the depth
# frames in the calling thread: the same images for less CPU than with its worker threads
# (docs/benchmarks.md, "Depth-sensed campaigns: one rendering thread, no colour, noise drawn
# once per run"), and a campaign runs its runs in parallel anyway. Only Mesa reads it, when the
# first GL context opens.
os.environ.setdefault("LP_NUM_THREADS", "0")

from robots.kernel_cache import use_kernel_cache  # noqa: E402

use_kernel_cache()  # the harness's own kernels share the project's cache (robots.kernel_cache)
