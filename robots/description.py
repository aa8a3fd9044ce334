"""One description file (MJCF or URDF) read by MuJoCo and by pinocchio, with every check a load needs.

Both libraries parse the same file; what can go wrong between them is caught here and reported as
one :class:`~robots.exceptions.InvalidDescription` line naming the file:

* an MJCF ``<include>`` (pinocchio's parser does not follow it: a scene gives a model without the
  robot, or with nq = 0 and no error) — give the robot's own file;
* a joint that is not a 1-DoF revolute joint (prismatic fingers, free joints, URDF
  ``continuous`` joints, which pinocchio represents with nq = 2);
* MuJoCo and pinocchio disagreeing on the joints or on any frame's pose: pinocchio 4.1.0's MJCF
  parser drops the pose of a first jointless body with a rotation (fixed upstream later), and it
  ignores ``compiler/eulerseq``; the forward kinematics of both are compared at load on several
  configurations (:func:`check_agreement`);
* no joint velocity limits: a URDF's ``<limit velocity>`` (pinocchio's ``velocityLimit``) or the
  spec's ``velocity_limits``, never an actuator's ``ctrlrange`` (:func:`velocity_limits`).

A URDF gets MuJoCo's URDF options a robot model needs: ``fusestatic`` off (every link stays a
body, reachable by its name, like ``panda_link8`` or ``tool0``), visual meshes discarded (MuJoCo
reads no COLLADA), and ``package://`` mesh URIs resolved (:func:`resolve_package_uri`).
"""

from __future__ import annotations

import math
import os
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from robots.exceptions import InvalidDescription, NotInstalled

PACKAGE_URI = "package://"
"""Scheme of a ROS package path (``package://<name>/<path>``)."""

_REVOLUTE = {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned"}
AGREEMENT_TOL = 1e-9
"""Largest accepted difference between MuJoCo's and pinocchio's frame poses [m] / [rad]."""


def root_element(path: Path) -> ET.Element:
    """The parsed root element of a description file.

    Raises:
        InvalidDescription: missing file or not XML.
    """
    if not path.is_file():
        raise InvalidDescription(f"{path}: no such description file")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InvalidDescription(f"{path}: not valid XML ({exc})") from None


def description_format(path: Path, root: ET.Element | None = None) -> str:
    """``"mjcf"`` or ``"urdf"``, from the root element (``<mujoco>`` / ``<robot>``)."""
    root = root_element(path) if root is None else root
    if root.tag == "mujoco":
        return "mjcf"
    if root.tag == "robot":
        return "urdf"
    raise InvalidDescription(f"{path}: root element <{root.tag}> is neither <mujoco> (MJCF) nor <robot> (URDF)")


def package_search_path(extra: Sequence[Path] = ()) -> list[Path]:
    """Directories searched for ``package://<name>/...``: ``extra``, cmeel prefixes, ``ROSPACKAGE_URI_PATH``.

    Each directory holds packages as sub-directories (``<dir>/<name>/...``). pip-installed
    cmeel packages (``example-robot-data``) live in ``<site-packages>/cmeel.prefix/share``.
    """
    dirs = [Path(p) for p in extra]
    for entry in sys.path:
        share = Path(entry or ".") / "cmeel.prefix" / "share"
        if share.is_dir() and share not in dirs:
            dirs.append(share)
    for entry in os.environ.get("ROSPACKAGE_URI_PATH", "").split(os.pathsep):
        if entry and Path(entry) not in dirs:
            dirs.append(Path(entry))
    return dirs


def resolve_package_uri(uri: str, search_path: Iterable[Path]) -> Path:
    """The file a ``package://<name>/<rest>`` URI names.

    Raises:
        NotInstalled: no directory of ``search_path`` holds ``<name>/<rest>``.
    """
    rest = uri[len(PACKAGE_URI) :]
    name = rest.split("/", 1)[0]
    dirs = list(search_path)
    for d in dirs:
        candidate = d / rest
        if candidate.is_file():
            return candidate
    where = ", ".join(str(d) for d in dirs) or "nowhere (no cmeel prefix, ROSPACKAGE_URI_PATH empty)"
    hint = " (pip install example-robot-data)" if name == "example-robot-data" else ""
    raise NotInstalled(f"package '{name}' not found for {uri}{hint}; searched {where}")


def missing_files(path: Path, package_dirs: Sequence[Path] = ()) -> str | None:
    """Why the description (or a mesh its collision geometry needs) is not installed, or None."""
    try:
        root = root_element(path)
    except InvalidDescription as exc:
        return str(exc)
    if root.tag != "robot":
        return None
    search = package_search_path(package_dirs)
    for collision in root.iter("collision"):
        for mesh in collision.iter("mesh"):
            uri = mesh.get("filename", "")
            if uri.startswith(PACKAGE_URI):
                try:
                    resolve_package_uri(uri, search)
                except NotInstalled as exc:
                    return str(exc)
            elif not (path.parent / uri).is_file():
                return f"{path}: mesh {uri} not found"
    return None


def mujoco_spec(path: Path, package_dirs: Sequence[Path] = ()) -> mujoco.MjSpec:
    """A fresh MuJoCo spec of the description (not compiled).

    MJCF: as written. URDF: every link kept as a body (``fusestatic`` off), visuals discarded,
    mesh files resolved to absolute paths (``package://`` through :func:`package_search_path`,
    others relative to the file).

    Raises:
        InvalidDescription: MuJoCo cannot parse the file, or an MJCF has an ``<include>``.
        NotInstalled: a ``package://`` mesh is not found.
    """
    root = root_element(path)
    fmt = description_format(path, root)
    if fmt == "mjcf":
        include = next(root.iter("include"), None)
        if include is not None:
            raise InvalidDescription(
                f"{path}: MJCF <include file={include.get('file')!r}> is not followed by pinocchio's parser "
                "(a scene gives a model without the robot); give the robot's own file as the description"
            )
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise InvalidDescription(f"{path}: MuJoCo cannot read it: {_one_line(exc)}") from None
    if fmt == "urdf":
        spec.compiler.fusestatic = False
        spec.compiler.discardvisual = True
        search = package_search_path(package_dirs)
        for mesh in spec.meshes:
            uri = mesh.file
            if uri.startswith(PACKAGE_URI):
                mesh.file = str(resolve_package_uri(uri, search))
            elif not Path(uri).is_absolute():
                mesh.file = str((path.parent / uri).resolve())
        spec.meshdir = ""
    return spec


def compile_spec(spec: mujoco.MjSpec, path: Path) -> mujoco.MjModel:
    """Compile ``spec``; a compiler error becomes :class:`InvalidDescription` naming ``path``."""
    try:
        return spec.compile()
    except ValueError as exc:
        raise InvalidDescription(f"{path}: MuJoCo cannot compile it: {_one_line(exc)}") from None


def pinocchio_model(path: Path) -> pin.Model:
    """Pinocchio's model of the description (fixed base).

    Raises:
        InvalidDescription: pinocchio cannot parse it, or finds no joint.
    """
    fmt = description_format(path)
    try:
        model = pin.buildModelFromUrdf(str(path)) if fmt == "urdf" else pin.buildModelFromMJCF(str(path))
    except (ValueError, RuntimeError) as exc:
        raise InvalidDescription(f"{path}: pinocchio cannot read it: {_one_line(exc)}") from None
    if model.nq == 0:
        raise InvalidDescription(f"{path}: pinocchio found no joint (nq = 0); is it a scene rather than the robot?")
    return model


def check_joints(path: Path, mj_model: mujoco.MjModel, pin_model: pin.Model) -> tuple[str, ...]:
    """Check that both models have the same 1-DoF revolute joints in the same order; return their names.

    Raises:
        InvalidDescription: naming the first offending joint.
    """
    for joint_id in range(1, pin_model.njoints):
        kind = pin_model.joints[joint_id].shortname()
        if kind not in _REVOLUTE:
            name = pin_model.names[joint_id]
            what = "a continuous joint (nq = 2 in pinocchio)" if "Unbounded" in kind or "RUB" in kind else kind
            raise InvalidDescription(
                f"{path}: joint '{name}' is {what}; only revolute arm joints are supported "
                "(make grippers and other joints fixed in the description)"
            )
    hinge = mujoco.mjtJoint.mjJNT_HINGE
    for j in range(mj_model.njnt):
        if mj_model.jnt_type[j] != hinge:
            raise InvalidDescription(f"{path}: MuJoCo joint '{mj_model.joint(j).name}' is not a hinge")
    mj_names = tuple(mj_model.joint(j).name for j in range(mj_model.njnt))
    pin_names = tuple(pin_model.names[1:])
    if mj_names != pin_names or mj_model.nq != pin_model.nq:
        raise InvalidDescription(f"{path}: MuJoCo joints {list(mj_names)} differ from pinocchio's {list(pin_names)}")
    return mj_names


def velocity_limits(
    path: Path, pin_model: pin.Model, joint_names: Sequence[str], given: Sequence[float] | None
) -> np.ndarray:
    """Joint velocity limits [rad/s]: the spec's, else the description's ``<limit velocity>``.

    Never an actuator's ``ctrlrange`` (a position servo's is a position, a motor's a torque).

    Raises:
        InvalidDescription: wrong count, or no limit for some joint (an MJCF has none at all).
    """
    n = len(joint_names)
    if given is not None:
        if len(given) != n:
            raise InvalidDescription(f"{path}: velocity_limits has {len(given)} values for {n} joints")
        return np.array(given, dtype=float)
    if description_format(path) == "mjcf":
        raise InvalidDescription(
            f"{path}: an MJCF has no joint velocity limits (actuator ranges are not speeds); "
            "give velocity_limits in the robot's spec"
        )
    v = np.array(pin_model.velocityLimit, dtype=float)
    for name, value in zip(joint_names, v, strict=True):
        if not (math.isfinite(value) and value > 0.0):
            raise InvalidDescription(
                f"{path}: joint '{name}' has no <limit velocity> (> 0 rad/s); add it or give velocity_limits"
            )
    return v


def check_agreement(
    path: Path, mj_model: mujoco.MjModel, pin_model: pin.Model, configurations: Iterable[np.ndarray]
) -> list[str]:
    """Compare MuJoCo's and pinocchio's pose of every body frame both have; return those names.

    Raises:
        InvalidDescription: a frame differs by more than :data:`AGREEMENT_TOL` (the first one, by
            how much), e.g. pinocchio 4.1.0 dropping the pose of a first jointless rotated MJCF body.
    """
    data = mujoco.MjData(mj_model)
    pin_data = pin_model.createData()
    bodies = {mj_model.body(b).name: b for b in range(1, mj_model.nbody)}
    frames = [
        (f.name, i, bodies[f.name])
        for i, f in enumerate(pin_model.frames)
        if f.type == pin.FrameType.BODY and f.name in bodies
    ]
    for q in configurations:
        data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, data)
        pin.framesForwardKinematics(pin_model, pin_data, np.asarray(q, dtype=float))
        for name, fid, bid in frames:
            placement = pin_data.oMf[fid]
            dp = float(np.linalg.norm(placement.translation - data.xpos[bid]))
            dr = float(np.max(np.abs(placement.rotation - data.xmat[bid].reshape(3, 3))))
            if dp > AGREEMENT_TOL or dr > AGREEMENT_TOL:
                raise InvalidDescription(
                    f"{path}: MuJoCo and pinocchio disagree on frame '{name}' by {dp:.3g} m / {dr:.3g} "
                    f"at q = {np.round(q, 3).tolist()} (pinocchio {pin.__version__}'s MJCF parser drops the pose of "
                    "a first jointless rotated body and ignores eulerseq: move that pose into a child, write "
                    "orientations as quaternions, or use a URDF)"
                )
    return [name for name, _, _ in frames]


def _one_line(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    # pinocchio's messages start with "From file: ..." / "in function: ..."; keep the message.
    for ln in lines:
        if ln.startswith("message:"):
            return ln.removeprefix("message:").strip()
    return lines[-1] if lines else type(exc).__name__
