"""The sensing pipelines the loop uses: depth (render → filter → distance) and geometric.

Both produce :class:`~compare.sensing.results.DistanceResult` and both offer an
``update(t, kin)`` source matching ``compare.loop.closed_loop.ObstacleSource``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from compare.sensing.camera import DepthNoise, valid_fraction
from compare.sensing.depth_distance import DepthDistance
from compare.sensing.exceptions import SensingError
from compare.sensing.frames import DepthFrame
from compare.sensing.fusion import DepthFusion, FusionSettings
from compare.sensing.geometric_distance import GeometricDistance
from compare.sensing.ground_truth import GroundTruth
from compare.sensing.renderer import DepthCamera
from compare.sensing.results import DistanceResult, ObstacleReading
from compare.sensing.scene import control_point_positions
from compare.sensing.self_filter import SelfFilter, StaticBackground
from robots import Kinematics


@dataclass(frozen=True)
class DepthSensingSettings:
    """Parameters of the depth pipeline (names as in ``compare.config.SensorConfig``).

    Attributes:
        rho_m: Half side ρ of the surveillance cubes [m].
        self_filter_margin_m: Inflation of the arm geoms removed from the image [m].
        background_margin_m: How much nearer than the static background a pixel must be [m].
        noise_std_m: Gaussian depth noise σ [m] (at 1 m when ``noise_proportional``).
        noise_proportional: σ grows linearly with depth.
        dropout: Fraction of pixels without return.
        blind_fraction: Valid fraction of the raw frame under which the sensor is blind.
        min_support: k-th smallest pixel distance reported (1 = minimum, Flacco).
        noise_allowance: Filters widen their margins by this many σ(d).
        seed: Seed of the noise.
        camera: Camera name in the scene.
        robot_root_body: Root body of the arm (self-filter); None = the work cell's arm
            (``robots.Robot.base_body``, found from the model's first joint).
        occluded_margin_m: A reading nearer than every measured point by more than this is
            ``occluded`` (``DepthDistance``; ``[sensor] fusion_step_m``).
    """

    rho_m: float = 0.5
    self_filter_margin_m: float = 0.03
    background_margin_m: float = 0.04
    noise_std_m: float = 0.0
    noise_proportional: bool = False
    dropout: float = 0.0
    blind_fraction: float = 0.3
    min_support: int = 1
    noise_allowance: float = 5.0
    seed: int = 0
    camera: str = "depth_camera"
    robot_root_body: str | None = None
    occluded_margin_m: float = 0.01

    @classmethod
    def from_sensor_config(cls, sensor: Any, seed: int = 0, **overrides: Any) -> DepthSensingSettings:
        """From a ``compare.config.SensorConfig`` (noise, dropout, ρ, self-filter margin, blind fraction, support)."""
        values = {
            "rho_m": sensor.rho_m,
            "self_filter_margin_m": sensor.self_filter_margin_m,
            "noise_std_m": sensor.noise_std_m,
            "dropout": sensor.dropout,
            "blind_fraction": sensor.blind_fraction,
            "min_support": sensor.min_support,
            "seed": seed,
            "occluded_margin_m": sensor.fusion_step_m,
        }
        values.update(overrides)
        return cls(**values)

    @property
    def noise(self) -> DepthNoise:
        """The noise model."""
        return DepthNoise(self.noise_std_m, self.noise_proportional, self.dropout)

    @classmethod
    def for_cameras(cls, sensor: Any, seed: int = 0, **overrides: Any) -> list[DepthSensingSettings]:
        """One settings object per camera of ``sensor.cameras`` (``compare.config.SensorConfig``).

        A camera's ``noise_std_m``, ``dropout`` and ``self_filter_margin_m`` default to the
        ``[sensor]`` values; camera ``i`` > 0 draws its noise from its own stream (seed
        ``SeedSequence([seed, i])``), camera 0 from ``seed`` as a lone camera does. No cameras:
        the scene's one camera, as :meth:`from_sensor_config`.
        """
        base = cls.from_sensor_config(sensor, seed=seed, **overrides)
        out = []
        for i, cam in enumerate(sensor.cameras):
            values: dict[str, Any] = {"camera": cam.name}
            for key in ("noise_std_m", "dropout", "self_filter_margin_m"):
                if getattr(cam, key) is not None:
                    values[key] = getattr(cam, key)
            if i > 0:
                values["seed"] = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
            out.append(replace(base, **values))
        return out or [base]


class DepthPipeline:
    """Simulated depth sensing: render, remove the static scene and the arm, depth-space distance.

    Args:
        model: Work-cell model (``compare.sensing.scene.load_workcell``).
        settings: Pipeline parameters.

    Attributes:
        renderer: The :class:`DepthCamera` (its ``camera`` is the :class:`CameraModel`).
        background: Static-scene removal, captured from ``model`` at construction.
        self_filter: Arm removal.
        distance: Depth-space distance.
    """

    def __init__(self, model: mujoco.MjModel, settings: DepthSensingSettings | None = None) -> None:
        s = settings or DepthSensingSettings()
        self.settings = s
        self.model = model
        noise = s.noise
        self.renderer = DepthCamera(model, s.camera, noise=noise, seed=s.seed)
        self.camera = self.renderer.camera
        self.background = StaticBackground.capture(
            self.renderer, model, margin_m=s.background_margin_m, noise=noise, noise_allowance=s.noise_allowance
        )
        self.self_filter = SelfFilter(
            model,
            self.camera,
            margin_m=s.self_filter_margin_m,
            noise=noise,
            noise_allowance=s.noise_allowance,
            root_body=s.robot_root_body,
        )
        self.distance = DepthDistance(
            self.camera, s.rho_m, s.blind_fraction, s.min_support, name=s.camera, occluded_margin_m=s.occluded_margin_m
        )

    def render(self, data: mujoco.MjData, stamp_s: float | None = None) -> DepthFrame:
        """A raw (noisy) depth frame of ``data``; usable as ``SimRobotIO(depth_camera=...)``."""
        return self.renderer.render(data, stamp_s)

    __call__ = render

    def filter(self, frame: DepthFrame, q: np.ndarray | None = None, data: mujoco.MjData | None = None) -> DepthFrame:
        """Remove the static scene and the arm (at ``q`` [rad], or as in ``data``) from ``frame``.

        Returns a new frame; NaN pixels (no return) stay NaN, which no later stage reads as obstacle.
        """
        depth = self.background.without(frame.depth_m)
        self.self_filter.apply_inplace(depth, q=q, data=data)
        return DepthFrame(depth, frame.stamp_s, frame.camera)

    def process(
        self,
        frame: DepthFrame,
        control_points: Mapping[str, np.ndarray],
        q: np.ndarray | None = None,
        data: mujoco.MjData | None = None,
    ) -> DistanceResult:
        """Filter ``frame`` and compute the distance of every control point (base frame [m])."""
        vf = valid_fraction(frame)
        return self.distance.compute(self.filter(frame, q=q, data=data), control_points, vf)

    def sense(self, data: mujoco.MjData, control_points: Mapping[str, np.ndarray]) -> DistanceResult:
        """Render ``data`` and process the frame (the arm's pose taken from ``data``)."""
        return self.process(self.render(data), control_points, data=data)

    def source(self, read_frame: Callable[[], DepthFrame | None], frames: Iterable[str]) -> DepthObstacleSource:
        """An ``update(t, kin)`` obstacle source reading frames from ``read_frame`` (e.g. ``io.read_depth``)."""
        return DepthObstacleSource(self, read_frame, frames)

    def close(self) -> None:
        """Free the renderer's GL resources."""
        self.renderer.close()


def _blind(frames: Iterable[str], t: float) -> DistanceResult:
    return DistanceResult({n: ObstacleReading.nothing() for n in frames}, 0.0, True, t)


class DepthObstacleSource:
    """``compare.loop.closed_loop.ObstacleSource`` in depth mode.

    Each update takes the latest frame from ``read_frame``, removes the arm at the current
    joint positions ``kin.q`` (in simulation the frame was rendered in the same control step),
    and computes the distances of the control points at ``kin``. A frame already filtered is
    not filtered again (only the distances are recomputed); no frame yet → blind.

    Args:
        pipeline: The depth pipeline.
        read_frame: Returns the latest :class:`DepthFrame`, or None.
        frames: Control point frame names.
    """

    def __init__(
        self,
        pipeline: DepthPipeline,
        read_frame: Callable[[], DepthFrame | None],
        frames: Iterable[str],
    ) -> None:
        self.pipeline = pipeline
        self.read_frame = read_frame
        self.frames = tuple(frames)
        self._last: tuple[DepthFrame, DepthFrame, float] | None = None

    def update(self, t: float, kin: Kinematics) -> DistanceResult:
        """Sense at time ``t`` [s] with the arm at ``kin.q``."""
        frame = self.read_frame()
        if frame is None:
            return _blind(self.frames, t)
        if self._last is not None and self._last[0] is frame:
            filtered, vf = self._last[1], self._last[2]
        else:
            vf = valid_fraction(frame)
            filtered = self.pipeline.filter(frame, q=kin.q)
            self._last = (frame, filtered, vf)
        return self.pipeline.distance.compute(filtered, control_point_positions(kin, self.frames), vf)


class DepthRig:
    """Several depth cameras, their distances fused into one reading per control point.

    A :class:`DepthPipeline` per camera (its own noise, background and self-filter margin) and
    :class:`~compare.sensing.fusion.DepthFusion` (:mod:`compare.sensing.fusion`).

    Args:
        model: Work-cell model holding every camera (``compare.sensing.rig.load_rig_workcell``).
        settings: One :class:`DepthSensingSettings` per camera (same ρ), in order.
        fusion: Fusion parameters.

    Attributes:
        pipelines: The per-camera pipelines.
        fusion: The :class:`~compare.sensing.fusion.DepthFusion`.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        settings: Sequence[DepthSensingSettings],
        fusion: FusionSettings | None = None,
    ) -> None:
        if len(settings) < 2:
            raise SensingError("a rig needs at least two cameras (one camera: DepthPipeline)")
        self.model = model
        self.pipelines: list[DepthPipeline] = []
        try:
            for s in settings:
                self.pipelines.append(DepthPipeline(model, s))
        except Exception:
            self.close()
            raise
        self.fusion = DepthFusion([p.distance for p in self.pipelines], [s.noise for s in settings], fusion)

    @property
    def names(self) -> list[str]:
        """Camera names, in order."""
        return [p.settings.camera for p in self.pipelines]

    def render(self, data: mujoco.MjData) -> tuple[DepthFrame, ...]:
        """A raw frame of every camera."""
        return tuple(p.render(data) for p in self.pipelines)

    def filter(
        self, frames: Sequence[DepthFrame], q: np.ndarray | None = None, data: mujoco.MjData | None = None
    ) -> list[DepthFrame]:
        """Each camera's frame without the static scene and the arm (its own margins)."""
        return [p.filter(f, q=q, data=data) for p, f in zip(self.pipelines, frames, strict=True)]

    def process(
        self,
        frames: Sequence[DepthFrame],
        control_points: Mapping[str, np.ndarray],
        q: np.ndarray | None = None,
        data: mujoco.MjData | None = None,
    ) -> DistanceResult:
        """Filter every camera's frame and fuse the distances of the control points (base frame [m])."""
        vfs = [valid_fraction(f) for f in frames]
        return self.fusion.compute(self.filter(frames, q=q, data=data), control_points, vfs, raw_frames=frames)

    def sense(self, data: mujoco.MjData, control_points: Mapping[str, np.ndarray]) -> DistanceResult:
        """Render every camera and process the frames (the arm's pose taken from ``data``)."""
        return self.process(self.render(data), control_points, data=data)

    def source(
        self, read_frames: Callable[[], Sequence[DepthFrame | None]], frames: Iterable[str]
    ) -> RigObstacleSource:
        """An ``update(t, kin)`` obstacle source reading every camera's latest frame (``io.read_depth_frames``)."""
        return RigObstacleSource(self, read_frames, frames)

    def close(self) -> None:
        """Free every renderer."""
        for p in self.pipelines:
            p.close()


class RigObstacleSource:
    """``compare.loop.closed_loop.ObstacleSource`` with several cameras (see :class:`DepthObstacleSource`).

    Each camera's latest frame is filtered once (at the joint positions of the update that
    first sees it); a camera without a frame yet makes the update blind.
    """

    def __init__(
        self,
        rig: DepthRig,
        read_frames: Callable[[], Sequence[DepthFrame | None]],
        frames: Iterable[str],
    ) -> None:
        self.rig = rig
        self.read_frames = read_frames
        self.frames = tuple(frames)
        self._last: list[tuple[DepthFrame, DepthFrame, float] | None] = [None] * len(rig.pipelines)

    def update(self, t: float, kin: Kinematics) -> DistanceResult:
        """Sense at time ``t`` [s] with the arm at ``kin.q``."""
        latest = tuple(self.read_frames())
        if len(latest) != len(self.rig.pipelines):
            raise SensingError(f"the rig has {len(self.rig.pipelines)} cameras but {len(latest)} frames came in")
        raw = [f for f in latest if f is not None]
        if len(raw) != len(latest):  # a camera without a frame yet: blind
            return _blind(self.frames, t)
        filtered, fractions = [], []
        for c, frame in enumerate(raw):
            last = self._last[c]
            if last is None or last[0] is not frame:
                last = (frame, self.rig.pipelines[c].filter(frame, q=kin.q), valid_fraction(frame))
                self._last[c] = last
            filtered.append(last[1])
            fractions.append(last[2])
        points = control_point_positions(kin, self.frames)
        return self.rig.fusion.compute(filtered, points, fractions, raw_frames=raw)


class GeometricObstacleSource:
    """``compare.loop.closed_loop.ObstacleSource`` in geometric mode: exact distances to the person's capsules.

    Args:
        distance: The geometric distance (its ρ decides "in range").
        data: The simulation state whose geom poses are read (kept current by ``mj_step``).
        frames: Control point frame names.
    """

    def __init__(self, distance: GeometricDistance, data: mujoco.MjData, frames: Iterable[str]) -> None:
        self.distance = distance
        self.data = data
        self.frames = tuple(frames)
        self._points = np.empty((len(self.frames), 3))  # the control points of an update [m]

    def update(self, t: float, kin: Kinematics) -> DistanceResult:
        """Closest points at time ``t`` [s] for the control points at ``kin``."""
        kin.frame_positions(self.frames, self._points)
        return self.distance.compute_at(self.data, self.frames, self._points, stamp_s=t)


def truth_function(model: mujoco.MjModel, data: mujoco.MjData, frames: Iterable[str]) -> GroundTruth:
    """``truth(kin)`` for ``compare.loop.closed_loop.run_loop``: true distance per control point [m] (no ρ cut).

    A :class:`~compare.sensing.ground_truth.GroundTruth`: the loop records its steps and computes them at the end.
    """
    return GroundTruth(model, data, frames)
