"""Writes Tessera's demo stage: dense meshes and many instances, generated (deterministically) with numpy.

    python testenv/demo/make_demo_stage.py out/demo/demo.usdc [--rocks N] [--detail LEVEL]

The stage: a ground of 131k triangles, a 500k-triangle torus knot in the middle, a PointInstancer scattering
N copies of three 82k-triangle rocks (default 1200: about 98 M instanced triangles), and a ring of native
instances of a pillar asset, with a camera, a sun and a sky dome.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt


def icosphere(level: int):
    t = (1.0 + 5 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
                  [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
                  [8, 6, 7], [9, 8, 1]], np.int64)
    for _ in range(level):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mids = len(v) + inverse.reshape(3, -1).T  # midpoint index of edges (01, 12, 20) per face
        v = np.concatenate([v, (v[unique[:, 0]] + v[unique[:, 1]]) / 2.0])
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = mids[:, 0], mids[:, 1], mids[:, 2]
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1), np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)])
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def rock(seed: int, level: int = 6):
    """An icosphere displaced by a few octaves of random ridged waves: a lumpy, faceted stone."""
    rng = np.random.default_rng(seed)
    v, f = icosphere(level)
    height = np.zeros(len(v))
    for octave in range(6):
        freq = 1.5 * 2.0 ** octave
        for _ in range(4):
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            height += (1.0 - np.abs(np.sin(freq * v @ direction + rng.uniform(0, 6.3)))) * 0.18 / 2.0 ** octave
    squash = np.array([1.0, rng.uniform(0.55, 0.8), rng.uniform(0.8, 1.1)])
    return v * (0.8 + height)[:, None] * squash, f


def torus_knot(p=3, q=5, segments=2000, sides=125, radius=0.35):
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    r = 2.0 + np.cos(q * t)
    center = np.stack([r * np.cos(p * t), np.sin(q * t) * 1.2, r * np.sin(p * t)], 1)
    tangent = np.roll(center, -1, 0) - np.roll(center, 1, 0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross(tangent, [0, 1, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ripple = radius * (1 + 0.08 * np.sin(40 * t)[:, None] * np.cos(3 * a)[None])
    points = center[:, None] + ripple[..., None] * (np.cos(a)[None, :, None] * normal[:, None] + np.sin(a)[None, :, None] * binormal[:, None])
    i, j = np.meshgrid(np.arange(segments), np.arange(sides), indexing="ij")
    i2, j2 = (i + 1) % segments, (j + 1) % sides
    quads = np.stack([i * sides + j, i2 * sides + j, i2 * sides + j2, i * sides + j2], -1).reshape(-1, 4)
    return points.reshape(-1, 3), quads


def ground(n=256, size=80.0):
    x = np.linspace(-size / 2, size / 2, n + 1)
    gx, gz = np.meshgrid(x, x)
    gy = 0.25 * np.sin(gx * 0.35) * np.cos(gz * 0.3) - 0.6
    points = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = i * (n + 1) + j
    quads = np.stack([a, a + n + 1, a + n + 2, a + 1], -1).reshape(-1, 4)
    return points, quads


def define_mesh(stage, path, points, faces, color):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(faces), faces.shape[1], np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(faces.reshape(-1).astype(np.int32)))
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    mesh.CreateDisplayColorAttr([Gf.Vec3f(*color)])
    lo, hi = points.min(0), points.max(0)
    mesh.GetExtentAttr().Set([Gf.Vec3f(*lo), Gf.Vec3f(*hi)])
    return mesh


def make_stage(path: Path, rocks: int = 1200, detail: int = 6) -> Usd.Stage:
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())

    gp, gq = ground()
    define_mesh(stage, "/World/Ground", gp, gq, (0.32, 0.3, 0.27))
    kp, kq = torus_knot()
    knot = define_mesh(stage, "/World/Knot", kp, kq, (0.85, 0.55, 0.2))
    UsdGeom.Xformable(knot).AddTranslateOp().Set(Gf.Vec3d(0, 2.6, 0))

    # A PointInstancer scattering three dense rocks.
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Rocks")
    protos = stage.DefinePrim("/World/Rocks/Prototypes", "Scope")
    colors = [(0.45, 0.43, 0.4), (0.5, 0.38, 0.3), (0.36, 0.4, 0.42)]
    targets = []
    for k in range(3):
        v, f = rock(seed=11 + k, level=detail)
        define_mesh(stage, f"/World/Rocks/Prototypes/Rock{k}", v, f, colors[k])
        targets.append(Sdf.Path(f"/World/Rocks/Prototypes/Rock{k}"))
    instancer.GetPrototypesRel().SetTargets(targets)
    rng = np.random.default_rng(5)
    angle = rng.uniform(0, 2 * np.pi, rocks)
    distance = 6.0 + 28.0 * np.sqrt(rng.uniform(0, 1, rocks))
    positions = np.stack([distance * np.cos(angle), np.full(rocks, -0.5), distance * np.sin(angle)], 1)
    yaw = rng.uniform(0, 2 * np.pi, rocks)
    orientations = np.stack([np.cos(yaw / 2), np.zeros(rocks), np.sin(yaw / 2), np.zeros(rocks)], 1)
    scales = np.repeat(rng.uniform(0.35, 1.2, rocks)[:, None], 3, 1)
    instancer.GetPositionsAttr().Set(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    instancer.GetOrientationsAttr().Set(Vt.QuathArray([Gf.Quath(*map(float, q)) for q in orientations]))
    instancer.GetScalesAttr().Set(Vt.Vec3fArray.FromNumpy(scales.astype(np.float32)))
    instancer.GetProtoIndicesAttr().Set(Vt.IntArray.FromNumpy(rng.integers(0, 3, rocks).astype(np.int32)))

    # Native instancing: a pillar asset (class) referenced 12 times around the knot.
    asset = stage.CreateClassPrim("/PillarAsset")
    v, f = icosphere(5)
    shaft = v * np.array([0.45, 2.2, 0.45]) + np.array([0, 2.2, 0])
    define_mesh(stage, "/PillarAsset/Shaft", shaft, f, (0.75, 0.74, 0.7))
    define_mesh(stage, "/PillarAsset/Cap", v * np.array([0.7, 0.25, 0.7]) + np.array([0, 4.4, 0]), f, (0.6, 0.6, 0.62))
    for k in range(12):
        a = 2 * math.pi * k / 12
        pillar = UsdGeom.Xform.Define(stage, f"/World/Pillars/Pillar{k}")
        pillar.GetPrim().GetReferences().AddInternalReference(asset.GetPath())
        pillar.GetPrim().SetInstanceable(True)
        pillar.AddTranslateOp().Set(Gf.Vec3d(5.0 * math.cos(a), -0.6, 5.0 * math.sin(a)))

    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.GetFocalLengthAttr().Set(28.0)
    camera.GetHorizontalApertureAttr().Set(36.0)
    camera.GetVerticalApertureAttr().Set(20.25)
    camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.05, 500.0))
    eye, target = Gf.Vec3d(0.0, 6.5, 17.0), Gf.Vec3d(0.0, 1.5, 0.0)
    view = Gf.Matrix4d().SetLookAt(eye, target, Gf.Vec3d(0, 1, 0))
    camera.AddTransformOp().Set(view.GetInverse())

    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.3)
    sun.CreateNormalizeAttr(True)  # intensity is the irradiance
    sun.CreateColorAttr(Gf.Vec3f(1.0, 0.95, 0.85))
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 35.0, 0.0))
    sky = UsdLux.DomeLight.Define(stage, "/World/Sky")
    sky.CreateIntensityAttr(0.25)
    sky.CreateColorAttr(Gf.Vec3f(0.75, 0.85, 1.0))
    stage.GetRootLayer().Save()
    return stage


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("output", type=Path)
    parser.add_argument("--rocks", type=int, default=1200)
    parser.add_argument("--detail", type=int, default=6, help="icosphere subdivision level of the rocks (6: 82k triangles)")
    args = parser.parse_args()
    make_stage(args.output, args.rocks, args.detail)


if __name__ == "__main__":
    main()
