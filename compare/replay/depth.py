"""Depth point clouds of a replayed run: each of its cameras re-rendered at the replayed state.

The frames are rendered again, noise-free, from the recorded arm and the scripted person (the
run's own frames, with their noise, are not stored). A frame is split as the pipeline sees it:
the static background (rendered once with the person and the arm left out) and the foreground,
the pixels nearer than the background by more than the pipeline's background margin (the person
and the arm). Pixels are taken every ``stride_px`` rows and columns to keep recordings small.
"""

from __future__ import annotations

import mujoco
import numpy as np

from compare.replay.run_data import ReplayRun
from compare.sensing.camera import normalized_coordinates, sensor_to_base
from compare.sensing.frames import CameraModel
from compare.sensing.pipeline import DepthSensingSettings
from compare.sensing.renderer import DepthCamera

DEFAULT_STRIDE_PX = 4
"""Every 4th row and column: 1/16 of the pixels (a 512x424 frame gives at most 13,568 points)."""


class DepthClouds:
    """The run's depth cameras, rendering noise-free point clouds of a scene state.

    Args:
        model: The replay's work cell (with the run's cameras).
        run: The loaded run (its camera names and rates).
        stride_px: Keep every ``stride_px``-th row and column.
    """

    def __init__(self, model: mujoco.MjModel, run: ReplayRun, stride_px: int = DEFAULT_STRIDE_PX) -> None:
        sensor = run.config.sensor
        settings = DepthSensingSettings.for_cameras(sensor)
        self.names = [s.camera for s in settings]
        default_rate = run.config.scenario.sensing_rate_hz
        self.rates_hz = [(cam.rate_hz or default_rate) for cam in sensor.cameras] or [default_rate]
        self.margin_m = settings[0].background_margin_m
        self.stride = max(1, int(stride_px))
        self.cameras = [DepthCamera(model, name) for name in self.names]
        self._static: list[np.ndarray | None] = [None] * len(self.cameras)

    def camera_models(self) -> list[CameraModel]:
        """Intrinsics and pose of each camera."""
        return [c.camera for c in self.cameras]

    def background(self, index: int, data: mujoco.MjData) -> np.ndarray:
        """Points [m] of camera ``index``'s static scene in the base frame. Shape (N, 3)."""
        static = self._static_depth(index, data)
        return self._points(index, static, static > 0.0)

    def foreground(self, index: int, data: mujoco.MjData) -> np.ndarray:
        """Points [m] of camera ``index`` nearer than the static scene (person, arm) at ``data``. Shape (N, 3)."""
        static = self._static_depth(index, data)
        depth = self.cameras[index].render_depth(data, noisy=False)[:: self.stride, :: self.stride]
        near = (depth > 0.0) & ((static <= 0.0) | (depth < static - self.margin_m))
        return self._points(index, depth, near)

    def _static_depth(self, index: int, data: mujoco.MjData) -> np.ndarray:
        cached = self._static[index]
        if cached is None:
            cached = self.cameras[index].render_static(data)[:: self.stride, :: self.stride]
            self._static[index] = cached
        return cached

    def _points(self, index: int, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
        camera = self.cameras[index].camera
        xn, yn = normalized_coordinates(camera)
        rows, cols = np.nonzero(mask)
        d = depth[rows, cols].astype(float)
        sensor = np.column_stack([xn[:: self.stride][cols] * d, yn[:: self.stride][rows] * d, d])
        return sensor_to_base(camera, sensor).reshape(-1, 3)

    def close(self) -> None:
        """Free the cameras' GL resources."""
        for camera in self.cameras:
            camera.close()
