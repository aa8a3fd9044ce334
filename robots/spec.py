"""What a robot is made of: its description file and the few facts a description does not carry.

A :class:`RobotSpec` is everything :func:`robots.register` needs to add a robot. The description
file (MJCF or URDF) is the single source of truth for the kinematics, read by MuJoCo *and*
pinocchio; the spec only names frames and gives what the file cannot say (docs/design.md §4):

* which frame is the end effector and which frames are the default obstacle control points;
* the home configuration (a keyframe of an MJCF, or joint values);
* the joint velocity limits when the description has none (MJCF has no such attribute): they are
  never guessed from actuators (a position servo's ``ctrlrange`` is a position, a motor's a
  torque);
* where ``package://`` URIs of a URDF's meshes are found, and how a simulated work cell drives
  the joints (armature, servo gain) when the robot is dropped into the shared work cell.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from robots.description import PACKAGE_URI, package_search_path, resolve_package_uri
from robots.exceptions import InvalidSpec


@dataclass(frozen=True)
class RobotSpec:
    """A registered robot.

    Attributes:
        description: The robot's description file, MJCF (``<mujoco>``) or URDF (``<robot>``): the
            robot alone (no ``<include>``), every joint a revolute arm joint (lock grippers in the
            file). Frames are its body / link names. A ``package://<name>/...`` URI is resolved
            like a mesh's (e.g. a file of the ``example-robot-data`` package).
        ee_frame: End-effector frame (default frame of the position, orientation, pose,
            manipulability and wall tasks).
        control_points: Default obstacle control points (frames whose origins are the points),
            used when a hierarchy names none.
        home: Home configuration: the name of a keyframe of an MJCF description, or the joint
            values [rad] (one per joint).
        velocity_limits: Joint velocity limits [rad/s], one per joint; None = the description's
            (a URDF's ``<limit velocity>``). Required for an MJCF.
        title: Human-readable name (maker, model) for docs and listings.
        prefix: Common prefix of the description's frame names that may be left out
            (``"j2s7s300_"``: ``"link_4"`` is ``"j2s7s300_link_4"``).
        workcell: An MJCF work cell (robot, table, depth camera, person) of the robot's own; None =
            the shared work cell ``robots/workcell/workcell.xml`` with the robot attached at its
            origin (:mod:`robots.workcell`).
        package_dirs: Directories searched for ``package://<name>/...`` mesh URIs (each holds
            ``<name>/``), before the installed cmeel prefixes and ``ROS_PACKAGE_PATH``.
        armature: Reflected rotor inertia added to every joint of a composed work cell
            [kg·m²] (at least this much; a description's larger value is kept).
        servo_kv: Gain of the velocity servo put on every joint of a composed work cell
            [N·m·s/rad] (the ``servo`` joint drive; the default drive does not use it).
    """

    description: Path
    ee_frame: str
    control_points: tuple[str, ...]
    home: str | tuple[float, ...] = "home"
    velocity_limits: tuple[float, ...] | None = None
    title: str = ""
    prefix: str = ""
    workcell: Path | None = None
    package_dirs: tuple[Path, ...] = field(default_factory=tuple)
    armature: float = 0.1
    servo_kv: float = 50.0

    def __post_init__(self) -> None:
        description = self.description
        if isinstance(description, str) and description.startswith(PACKAGE_URI):
            description = resolve_package_uri(description, package_search_path(self.package_dirs))
        object.__setattr__(self, "description", Path(description))
        if self.workcell is not None:
            object.__setattr__(self, "workcell", Path(self.workcell))
        object.__setattr__(self, "package_dirs", tuple(Path(p) for p in self.package_dirs))
        object.__setattr__(self, "control_points", _names(self.control_points, "control_points"))
        if not isinstance(self.ee_frame, str) or not self.ee_frame:
            raise InvalidSpec(f"ee_frame must be a frame name, got {self.ee_frame!r}")
        if not isinstance(self.home, str):
            object.__setattr__(self, "home", _floats(self.home, "home"))
        if self.velocity_limits is not None:
            limits = _floats(self.velocity_limits, "velocity_limits")
            bad = [v for v in limits if not (math.isfinite(v) and v > 0.0)]
            if bad:
                raise InvalidSpec(f"velocity_limits must be finite and > 0 rad/s, got {bad[0]!r}")
            object.__setattr__(self, "velocity_limits", limits)
        if not (math.isfinite(self.armature) and self.armature >= 0.0):
            raise InvalidSpec(f"armature must be >= 0 kg m^2, got {self.armature!r}")
        if not (math.isfinite(self.servo_kv) and self.servo_kv > 0.0):
            raise InvalidSpec(f"servo_kv must be > 0 N m s/rad, got {self.servo_kv!r}")

    @property
    def description_format(self) -> str:
        """``"urdf"`` or ``"mjcf"``, from the file's extension (the root element is checked at load)."""
        return "urdf" if self.description.suffix.lower() == ".urdf" else "mjcf"


def _names(values: Sequence[str], key: str) -> tuple[str, ...]:
    if isinstance(values, str):
        values = (values,)
    names = tuple(values)
    if not names or not all(isinstance(n, str) and n for n in names):
        raise InvalidSpec(f"{key} must be one or more frame names, got {list(names)!r}")
    if len(set(names)) != len(names):
        raise InvalidSpec(f"{key} has duplicate frames: {list(names)!r}")
    return names


def _floats(values: Sequence[float], key: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise InvalidSpec(f"{key} must be a sequence of numbers, got {values!r}") from None
    if not out or not all(math.isfinite(v) for v in out):
        raise InvalidSpec(f"{key} must be finite numbers, got {list(out)!r}")
    return out
