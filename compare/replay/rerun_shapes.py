"""MuJoCo geoms, poses and colours as rerun archetypes (for :mod:`compare.replay.recording`)."""

from __future__ import annotations

import mujoco
import numpy as np
import rerun as rr

VISIBLE_GROUPS = (0, 1, 2)
"""Geom groups drawn (environment, person, the arm's visual geoms), as in MuJoCo's viewer."""


def xyzw(wxyz: np.ndarray) -> np.ndarray:
    """MuJoCo's (w, x, y, z) quaternions as rerun's (x, y, z, w). Shape (..., 4)."""
    return np.concatenate([wxyz[..., 1:], wxyz[..., :1]], axis=-1)


def rgb8(rgba: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Colours in [0, 1] as 8-bit values."""
    return (np.clip(np.asarray(rgba, dtype=float), 0.0, 1.0) * 255).round().astype(np.uint8)


def geom_archetype(model: mujoco.MjModel, g: int) -> rr.AsComponents | None:
    """The rerun shape of geom ``g`` in its own frame (None for planes and other unsupported types)."""
    size = model.geom_size[g]
    colour = rgb8(model.mat_rgba[model.geom_matid[g]] if model.geom_matid[g] >= 0 else model.geom_rgba[g])
    kind = model.geom_type[g]
    solid = rr.components.FillMode.Solid
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[colour])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=[colour], fill_mode=solid)
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size], colors=[colour], fill_mode=solid)
    if kind in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_ELLIPSOID):
        half = [size[0]] * 3 if kind == mujoco.mjtGeom.mjGEOM_SPHERE else size
        return rr.Ellipsoids3D(half_sizes=[half], colors=[colour], fill_mode=solid)
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
        return rr.Mesh3D(
            vertex_positions=model.mesh_vert[v0 : v0 + nv],
            triangle_indices=model.mesh_face[f0 : f0 + nf],
            albedo_factor=colour,
        )
    return None


def quat_z_to(v: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of the shortest rotations taking +z to each row of ``v`` (N, 3)."""
    n = np.linalg.norm(v, axis=1)
    u = v / np.maximum(n, 1e-12)[:, None]
    q = np.column_stack([-u[:, 1], u[:, 0], np.zeros(len(u)), 1.0 + u[:, 2]])
    down = q[:, 3] < 1e-9
    q[down] = (1.0, 0.0, 0.0, 0.0)  # straight down: half a turn about x
    q[n < 1e-12] = (0.0, 0.0, 0.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def arm_bodies(model: mujoco.MjModel) -> list[int]:
    """Bodies of the arm (the subtree of the model's first joint)."""
    root = model.body_rootid[model.jnt_bodyid[0]]
    return [b for b in range(model.nbody) if model.body_rootid[b] == root]
