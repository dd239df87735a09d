"""Implicit gprims (Cube, Sphere) tessellated into meshes, as UsdImaging does for Hydra."""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom

from tessera import _tessera


def supported(prim: Usd.Prim) -> bool:
    return prim.IsA(UsdGeom.Cube) or prim.IsA(UsdGeom.Sphere)


def _cube(size: float):
    h = size / 2.0
    corners = np.array([[x, y, z] for z in (-h, h) for y in (-h, h) for x in (-h, h)], np.float32)
    # Six faces wound counter-clockwise seen from outside, with a normal per face (uniform) for hard edges.
    faces = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]], np.int32)
    normals = np.array([[0, 0, -1], [0, 0, 1], [0, -1, 0], [0, 1, 0], [-1, 0, 0], [1, 0, 0]], np.float32)
    return corners, np.full(6, 4, np.int32), faces.reshape(-1), normals


def _sphere(radius: float, slices: int = 24, stacks: int = 12):
    # Latitude-longitude grid with poles, Z up as UsdGeomSphere.
    theta = np.linspace(0.0, np.pi, stacks + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, slices, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    points = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]).astype(np.float32) * radius
    counts, indices = [], []
    south = 1 + len(ring)
    for s in range(slices):
        n = (s + 1) % slices
        counts.append(3)
        indices += [0, 1 + s, 1 + n]
    for r in range(stacks - 3 + 1):
        for s in range(slices):
            n = (s + 1) % slices
            a, b = 1 + r * slices, 1 + (r + 1) * slices
            counts.append(4)
            indices += [a + s, b + s, b + n, a + n]
    last = 1 + (stacks - 2) * slices
    for s in range(slices):
        n = (s + 1) % slices
        counts.append(3)
        indices += [last + s, south, last + n]
    return points, np.array(counts, np.int32), np.array(indices, np.int32), None


def mesh_source(prim: Usd.Prim, time, color=None, components=3):
    """`color`: what the scene delegate read for the vertex channel (`components` floats per element); a tessellated
    implicit shape has no elements of its own, so it takes the first (a constant)."""
    if prim.IsA(UsdGeom.Cube):
        points, counts, indices, normals = _cube(UsdGeom.Cube(prim).GetSizeAttr().Get(time) or 2.0)
    else:
        points, counts, indices, normals = _sphere(UsdGeom.Sphere(prim).GetRadiusAttr().Get(time) or 1.0)
    color = None if color is None or len(color) < components else np.ascontiguousarray(color[:components])
    gprim = UsdGeom.Gprim(prim)
    return _tessera.mesh_source(
        str(prim.GetPath()), np.ascontiguousarray(points.reshape(-1)), counts, indices,
        left_handed=gprim.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded,
        double_sided=bool(gprim.GetDoubleSidedAttr().Get(time)),
        normals=None if normals is None else np.ascontiguousarray(normals.reshape(-1)), normals_interpolation="uniform",
        display_color=color, display_color_interpolation="constant", display_color_components=components)
