"""The robot registry: the robots shipped with the project, and :func:`register` for yours.

Adding a robot is one description file plus one :func:`register` call (docs/robots.md)::

    import robots
    from robots import RobotSpec

    robots.register(
        "myarm",
        RobotSpec(
            description="path/to/myarm.urdf",       # or an MJCF; meshes by package:// or relative path
            ee_frame="tool0",
            control_points=("forearm_link", "wrist_2_link", "wrist_3_link"),
            home=(0.0, -1.2, 1.6, -1.9, -1.57, 0.0),
        ),
    )
    arm = robots.load("myarm")

and ``[scenario] robot = "myarm"`` in a config (registered before the config is read, e.g. in a
module the user imports).
"""

from __future__ import annotations

from pathlib import Path

from robots.description import missing_files
from robots.exceptions import InvalidSpec, NotInstalled, UnknownRobot
from robots.robot import Robot
from robots.spec import RobotSpec

_HERE = Path(__file__).resolve().parent

DEFAULT_ROBOT = "jaco2"
"""The robot of the paper, used when a config names none (``[scenario] robot``)."""

_REGISTRY: dict[str, RobotSpec] = {}
_ALIASES: dict[str, str] = {}
_LOADED: dict[str, Robot] = {}  # parsed once per process


def register(name: str, spec: RobotSpec, aliases: tuple[str, ...] = (), replace: bool = False) -> None:
    """Add a robot to the registry (:func:`load` parses it on first use).

    Args:
        name: Registry name (``[scenario] robot``).
        spec: Its description file and frames.
        aliases: Other names accepted by :func:`load`.
        replace: Allow replacing a registered robot of the same name.

    Raises:
        InvalidSpec: empty or taken name, or ``spec`` is not a :class:`RobotSpec`.
    """
    if not isinstance(spec, RobotSpec):
        raise InvalidSpec(f"register('{name}'): spec must be a RobotSpec, got {type(spec).__name__}")
    for key in (name, *aliases):
        if not isinstance(key, str) or not key:
            raise InvalidSpec(f"robot names must be non-empty strings, got {key!r}")
        taken = key in _REGISTRY or key in _ALIASES
        if taken and not replace:
            raise InvalidSpec(f"robot '{key}' is already registered (replace=True to replace it)")
    _REGISTRY[name] = spec
    for alias in aliases:
        _ALIASES[alias] = name
    _LOADED.pop(name, None)


def unregister(name: str) -> None:
    """Remove a robot (and its aliases) from the registry; unknown names are ignored."""
    key = _ALIASES.get(name, name)
    _REGISTRY.pop(key, None)
    for alias in [a for a, target in _ALIASES.items() if target == key]:
        del _ALIASES[alias]
    _LOADED.pop(key, None)


def registered_robots() -> list[str]:
    """Every registered name, installed or not."""
    return sorted(_REGISTRY)


def available_robots() -> list[str]:
    """Registered robots whose files are installed (names accepted by :func:`load`)."""
    return [n for n, s in sorted(_REGISTRY.items()) if missing_files(s.description, s.package_dirs) is None]


def spec_of(name: str) -> RobotSpec:
    """The spec registered under ``name`` (or an alias).

    Raises:
        UnknownRobot: not registered.
    """
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        raise UnknownRobot(name, available_robots())
    return _REGISTRY[key]


def load(name: str) -> Robot:
    """Load a robot by registry name (``"jaco2"``, ``"panda"``, ``"ur5"``); parsed once per process.

    Raises:
        UnknownRobot: ``name`` is not registered.
        NotInstalled: a file it needs is missing (e.g. the ``example-robot-data`` meshes).
        InvalidDescription: its description cannot be used (one line saying why).
    """
    key = _ALIASES.get(name, name)
    if key in _LOADED:
        return _LOADED[key]
    spec = spec_of(name)
    problem = missing_files(spec.description, spec.package_dirs)
    if problem is not None:
        raise NotInstalled(f"robot '{key}' is not installed: {problem}")
    _LOADED[key] = Robot(key, spec)
    return _LOADED[key]


register(
    "jaco2",
    RobotSpec(
        description=_HERE / "kinova_j2s7s300" / "j2s7s300.xml",
        title="Kinova Jaco² j2s7s300 (7 DOF, spherical wrist)",
        ee_frame="end_effector",
        control_points=("link_4", "link_6", "link_7"),
        home="home",
        # kinova-ros URDF <limit velocity> (robots/kinova_j2s7s300/README.md, step 5); an MJCF has none.
        velocity_limits=(0.6283, 0.6283, 0.6283, 0.6283, 0.8378, 0.8378, 0.8378),
        prefix="j2s7s300_",
        workcell=_HERE / "kinova_j2s7s300" / "scene_workcell.xml",
    ),
    aliases=("j2s7s300", "kinova_j2s7s300"),
)
register(
    "panda",
    RobotSpec(
        description=_HERE / "franka_panda" / "panda.urdf",
        title="Franka Emika Panda (7 DOF) with hand",
        ee_frame="panda_hand_tcp",
        control_points=("panda_link4", "panda_link6", "panda_link7"),
        # Franka's "ready" pose (franka_ros / MoveIt): elbow up, flange pointing down.
        home=(0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398),
    ),
    aliases=("franka_panda",),
)
register(
    "ur5",
    RobotSpec(
        description=_HERE / "universal_robots_ur5" / "ur5.urdf",
        title="Universal Robots UR5 (6 DOF)",
        ee_frame="tool0",
        control_points=("forearm_link", "wrist_2_link", "wrist_3_link"),
        # Elbow up, forearm level, tool pointing down (the UR "home" of MoveIt's ur5 SRDF is all 0:
        # arm stretched horizontally, a singular pose).
        home=(0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0),
    ),
    aliases=("universal_robots_ur5",),
)
