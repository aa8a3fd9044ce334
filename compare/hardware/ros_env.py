"""Reach ROS 1 (rospy and the message classes) from the project's Python environment.

Choice (docs/hardware.md, "How rospy is reached"): the controller runs **in one process** under
the project's interpreter, with Debian's ROS 1 Python packages made importable by *appending*
Debian's ``dist-packages`` to ``sys.path`` — only when the hardware bridge is used, and only
if the interpreter has the same major.minor version as Debian's (3.11 on bookworm), since a
few ROS dependencies are C extensions built for that ABI (``netifaces``, ``_yaml``, ``roslz4``).
Appending (not prepending, and without processing its ``.pth`` files) keeps every package of
the virtual environment first: the venv's numpy is the one imported, Debian's is never seen
(bookworm's ROS packages do not depend on numpy anyway; this is checked).

Why not a separate ROS process under ``/usr/bin/python3`` bridged to the controller: it would
add a hop (and a second watchdog) between the solver and the driver at 100 Hz for no benefit,
since rospy is pure Python and the ABI matches. If the interpreter's minor version differs,
:func:`load_ros` refuses with a clear message instead of importing mismatched extensions.

``kinova_msgs/JointVelocity`` is not packaged by Debian. It is generated at run time with
``genpy.dynamic`` from our own copy of its definition (``compare/hardware/msg/JointVelocity.msg``,
same seven ``float32`` fields in the same order), so its type name and MD5 sum equal those of
the driver's message and roscpp accepts the connection. The MD5 sum is checked against the
value the definition must hash to. The driver's ``kinova_msgs/Stop`` and ``kinova_msgs/Start``
services (``in/stop``, ``in/start``) are built the same way from ``compare/hardware/srv/``:
request and response classes with ``genpy.dynamic``, the service MD5 with ``genmsg`` (roscpp's
service server compares it).
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from compare.hardware.exceptions import RosUnavailable

DEBIAN_DIST_PACKAGES = Path("/usr/lib/python3/dist-packages")
DEBIAN_PYTHON = (3, 11)
"""Python version Debian 12's ROS packages are built for."""

MSG_DIR = Path(__file__).resolve().parent / "msg"
JOINT_VELOCITY_TYPE = "kinova_msgs/JointVelocity"
JOINT_VELOCITY_MD5 = "bf16c4e5154848a0767d1aaab0a4796b"
"""MD5 sum of ``kinova_msgs/JointVelocity`` (seven float32 ``joint1..joint7``), as roscpp checks it."""
SRV_DIR = Path(__file__).resolve().parent / "srv"
SERVICE_TYPES = {"Stop": "kinova_msgs/Stop", "Start": "kinova_msgs/Start"}
"""The driver's services we call (``kinova_msgs/srv/Stop.srv``, ``Start.srv``: empty request, one string back)."""

INSTALL_HINT = "install ROS 1 from Debian with `make hw-deps` (Debian 12; needs root)"


@dataclass(frozen=True)
class RosApi:
    """The ROS 1 pieces the bridge uses, loaded once.

    Attributes:
        rospy: The ``rospy`` module.
        rosgraph: The ``rosgraph`` module (master checks).
        JointState: ``sensor_msgs/JointState``.
        Image: ``sensor_msgs/Image``.
        CameraInfo: ``sensor_msgs/CameraInfo``.
        JointVelocity: ``kinova_msgs/JointVelocity`` generated from our ``.msg``.
        Stop: ``kinova_msgs/Stop`` service class (``in/stop``).
        Start: ``kinova_msgs/Start`` service class (``in/start``).
    """

    rospy: ModuleType
    rosgraph: ModuleType
    JointState: Any
    Image: Any
    CameraInfo: Any
    JointVelocity: Any
    Stop: Any = None
    Start: Any = None


_API: RosApi | None = None


def _add_debian_path() -> None:
    if importlib.util.find_spec("rospy") is not None:
        return  # a ROS environment (PYTHONPATH of a sourced ROS setup) already provides it
    if not (DEBIAN_DIST_PACKAGES / "rospy").is_dir():
        raise RosUnavailable(f"rospy not found (looked in {DEBIAN_DIST_PACKAGES}): {INSTALL_HINT}")
    if sys.version_info[:2] != DEBIAN_PYTHON:
        have = ".".join(map(str, sys.version_info[:2]))
        want = ".".join(map(str, DEBIAN_PYTHON))
        raise RosUnavailable(
            f"Debian's rospy is built for Python {want}, this interpreter is {have}: "
            f"run the hardware bridge from a Python {want} environment"
        )
    if str(DEBIAN_DIST_PACKAGES) not in sys.path:
        sys.path.append(str(DEBIAN_DIST_PACKAGES))


def ros_unavailable_reason() -> str | None:
    """Why :func:`load_ros` would fail, or None when ROS 1 can be loaded (imports nothing from ROS)."""
    if importlib.util.find_spec("rospy") is not None:
        return None
    if not (DEBIAN_DIST_PACKAGES / "rospy").is_dir():
        return f"rospy not found: {INSTALL_HINT}"
    for pkg in ("genpy", "genmsg", "sensor_msgs", "std_msgs", "rosgraph"):
        if not (DEBIAN_DIST_PACKAGES / pkg).is_dir():
            return f"Python package '{pkg}' of ROS 1 not found: {INSTALL_HINT}"
    if sys.version_info[:2] != DEBIAN_PYTHON:
        return f"Debian's rospy needs Python {DEBIAN_PYTHON[0]}.{DEBIAN_PYTHON[1]}"
    return None


def joint_velocity_definition() -> str:
    """Text of our ``kinova_msgs/JointVelocity`` definition."""
    return (MSG_DIR / "JointVelocity.msg").read_text(encoding="utf-8")


def service_definition(name: str) -> str:
    """Text of our copy of the driver's ``kinova_msgs/<name>.srv``."""
    return (SRV_DIR / f"{name}.srv").read_text(encoding="utf-8")


def service_class(name: str) -> Any:
    """A rospy service class for ``kinova_msgs/<name>`` (``Stop`` or ``Start``) from our ``.srv`` copy.

    Raises:
        RosUnavailable: genpy/genmsg missing or the definition does not parse.
    """
    # Deferred: ROS 1 is optional and importable only after _add_debian_path().
    import genmsg
    import genmsg.gentools
    import genmsg.msg_loader
    import genpy.dynamic

    full = SERVICE_TYPES[name]
    text = service_definition(name)
    request_text, _, response_text = text.partition("---")
    try:
        request = genpy.dynamic.generate_dynamic(full + "Request", request_text)[full + "Request"]
        response = genpy.dynamic.generate_dynamic(full + "Response", response_text)[full + "Response"]
        context = genmsg.MsgContext.create_default()
        md5 = genmsg.gentools.compute_md5(context, genmsg.msg_loader.load_srv_from_string(context, text, full))
    except (genmsg.InvalidMsgSpec, ValueError) as exc:
        raise RosUnavailable(f"cannot build {full} from {SRV_DIR / (name + '.srv')}: {exc}") from exc
    attrs = {"_type": full, "_md5sum": md5, "_request_class": request, "_response_class": response}
    return type(name, (), attrs)


def load_ros() -> RosApi:
    """Import rospy and the message classes (once per process).

    Raises:
        RosUnavailable: ROS 1 is not installed, the interpreter does not match Debian's, or the
            generated message does not hash like the driver's.
    """
    global _API
    if _API is not None:
        return _API
    numpy_before = sys.modules.get("numpy")
    _add_debian_path()
    try:  # Deferred: ROS 1 is optional and importable only after _add_debian_path()
        import genpy.dynamic
        import rosgraph
        import rospy
        from sensor_msgs.msg import CameraInfo, Image, JointState
    except ImportError as exc:
        raise RosUnavailable(f"cannot import ROS 1 ({exc}): {INSTALL_HINT}") from exc
    import numpy  # Deferred: the numpy seen after ROS's path was added, which the check below compares

    if numpy_before is not None and numpy is not numpy_before:  # pragma: no cover - defensive
        raise RosUnavailable("loading ROS replaced the environment's numpy; refusing to go on")
    classes = genpy.dynamic.generate_dynamic(JOINT_VELOCITY_TYPE, joint_velocity_definition())
    joint_velocity = classes[JOINT_VELOCITY_TYPE]
    if joint_velocity._md5sum != JOINT_VELOCITY_MD5:
        raise RosUnavailable(
            f"generated {JOINT_VELOCITY_TYPE} has MD5 {joint_velocity._md5sum}, the driver's is {JOINT_VELOCITY_MD5}: "
            f"{MSG_DIR / 'JointVelocity.msg'} was changed"
        )
    _API = RosApi(
        rospy, rosgraph, JointState, Image, CameraInfo, joint_velocity, service_class("Stop"), service_class("Start")
    )
    return _API
