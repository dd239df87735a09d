"""The displacement scene of `tessera bench render` (and of testenv/test_displacement.py): a coarse UV sphere displaced
by a height map at runtime, and the same surface pre-tessellated on the CPU (every triangle cut n x n, displaced by the
same bilinear samples along the same normals) as the reference it is measured against.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .bench_textures import write_png


def uv_sphere(segments=24, rings=12, radius=1.0):
    """A UV sphere as triangles: a wrap seam (the u = 0 and u = 1 columns are split vertices, same positions, different
    texture coordinates) and one vertex at each pole; normals are the exact sphere normals. Returns (points, normals,
    uvs, triangles) as numpy arrays."""
    points, normals, uvs = [], [], []
    row = segments + 1
    for r in range(1, rings):
        v = r / rings
        theta = math.pi * (1.0 - v)  # v = 0 at the south pole
        for s in range(row):
            phi = 2.0 * math.pi * s / segments
            n = (math.sin(theta) * math.cos(phi), math.cos(theta), -math.sin(theta) * math.sin(phi))
            points.append(tuple(radius * c for c in n))
            normals.append(n)
            uvs.append((s / segments, v))
    south, north = len(points), len(points) + 1
    points += [(0.0, -radius, 0.0), (0.0, radius, 0.0)]
    normals += [(0.0, -1.0, 0.0), (0.0, 1.0, 0.0)]
    uvs += [(0.5, 0.0), (0.5, 1.0)]
    triangles = []
    top = (rings - 2) * row
    for s in range(segments):
        triangles.append((south, s + 1, s))  # the fans around the poles
        triangles.append((top + s, top + s + 1, north))
    for r in range(rings - 2):
        for s in range(segments):
            a, b, c, d = r * row + s, r * row + s + 1, (r + 1) * row + s + 1, (r + 1) * row + s
            triangles += [(a, b, c), (a, c, d)]
    return np.array(points), np.array(normals), np.array(uvs), np.array(triangles)


def height_map(width=64, height=32, bumps=4) -> np.ndarray:
    """8-bit heights: smooth bumps periodic in u (the wrap seam reads the same values from both sides), constant in the
    first and last rows (the poles). Rows bottom first, as st reads them."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    heights = 0.5 + 0.5 * np.sin(2 * np.pi * bumps * u)[None, :] * np.sin(np.pi * v)[:, None] ** 2
    heights[0, :] = heights[-1, :] = 0.5
    return np.round(heights * 255).astype(np.uint8)


def write_height_png(path, heights: np.ndarray) -> None:
    write_png(Path(path), heights[::-1])  # a single-channel PNG, rows top first


def sample_bilinear(heights: np.ndarray, st: np.ndarray) -> np.ndarray:
    """What the GPU reads at st (shaders/texture.h: repeat wrap, texel centres at (i + 0.5) / size, rows bottom first)."""
    h, w = heights.shape
    values = heights.astype(np.float64) / 255.0
    x = (st[:, 0] % 1.0) * w - 0.5
    y = (st[:, 1] % 1.0) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    x0, y0 = x0 % w, y0 % h
    top = values[y0, x0] * (1 - fx) + values[y0, x1] * fx
    bottom = values[y1, x0] * (1 - fx) + values[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def pre_tessellated(points, normals, uvs, triangles, heights, n: int, magnitude: float, center: float):
    """Every triangle cut into n x n on a barycentric lattice and displaced as the GPU displaces: offset =
    (height - center) * magnitude along the interpolated, normalized normal. Returns (points, triangles)."""
    lattice = [(i, j) for j in range(n + 1) for i in range(n + 1 - j)]
    index = {ij: k for k, ij in enumerate(lattice)}
    weights = np.array([((n - i - j) / n, i / n, j / n) for i, j in lattice])
    cells = []
    for j in range(n):
        for i in range(n - j):
            cells.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
            if i + j < n - 1:
                cells.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
    cells = np.array(cells)
    out_points, out_triangles = [], []
    for t, triangle in enumerate(triangles):
        p = weights @ points[triangle]
        normal = weights @ normals[triangle]
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        offset = (sample_bilinear(heights, weights @ uvs[triangle]) - center) * magnitude
        out_points.append(p + normal * offset[:, None])
        out_triangles.append(cells + t * len(lattice))
    return np.concatenate(out_points), np.concatenate(out_triangles)


def displaced_material(stage, path, *, constant=None, texture=None, magnitude=None, center=None, fade=(0.0, 0.0)):
    """A grey preview surface displaced by a constant or by the r channel of a height map (read raw, with st), with
    Tessera's magnitude, center and fade (0, 0 by default: never faded) where given."""
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.6, 0.6, 0.6))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    material.CreateDisplacementOutput().ConnectToSource(surface.ConnectableAPI(), "displacement")
    displacement = surface.CreateInput("displacement", Sdf.ValueTypeNames.Float)
    if constant is not None:
        displacement.Set(constant)
    if texture is not None:
        reader = UsdShade.Shader.Define(stage, f"{path}/St")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
        tex = UsdShade.Shader.Define(stage, f"{path}/Height")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(texture))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")  # heights, not colours
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        displacement.ConnectToSource(tex.ConnectableAPI(), "r")
    prim = material.GetPrim()
    for name, value in (("magnitude", magnitude), ("center", center), ("fadeStart", fade[0]), ("fadeEnd", fade[1])):
        if value is not None:
            prim.CreateAttribute(f"tessera:displacement:{name}", Sdf.ValueTypeNames.Float).Set(value)
    return material


def grey_material(stage, path):
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.6, 0.6, 0.6))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def write_stages(directory, *, segments=24, rings=12, heights=None, n=24, magnitude=0.15, center=0.5, eye=(0.6, 1.1, 3.2)):
    """runtime.usda (the coarse sphere, displaced at render time) and reference.usda (pre-tessellated n x n per
    triangle), both seen by /Camera. Returns their paths."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    heights = height_map() if heights is None else heights
    write_height_png(directory / "heights.png", heights)
    points, normals, uvs, triangles = uv_sphere(segments, rings)

    def stage_with_camera(path):
        stage = Usd.Stage.CreateNew(str(path))
        camera = UsdGeom.Camera.Define(stage, "/Camera")
        camera.GetFocalLengthAttr().Set(35.0)
        camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.05, 100))
        view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(0, 0, 0), Gf.Vec3d(0, 1, 0))
        camera.AddTransformOp().Set(view.GetInverse())
        return stage

    def mesh(stage, mesh_points, mesh_triangles):
        m = UsdGeom.Mesh.Define(stage, "/Sphere")
        m.GetPointsAttr().Set(np.asarray(mesh_points, np.float32))
        m.GetFaceVertexCountsAttr().Set(np.full(len(mesh_triangles), 3, np.int32))
        m.GetFaceVertexIndicesAttr().Set(np.asarray(mesh_triangles, np.int32).reshape(-1))
        m.GetSubdivisionSchemeAttr().Set("none")
        return m

    runtime = stage_with_camera(directory / "runtime.usda")
    sphere = mesh(runtime, points, triangles)
    sphere.GetNormalsAttr().Set(np.asarray(normals, np.float32))
    sphere.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    st = UsdGeom.PrimvarsAPI(sphere).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(np.asarray(uvs, np.float32))
    material = displaced_material(runtime, "/Looks/Bumps", texture=directory / "heights.png", magnitude=magnitude, center=center)
    UsdShade.MaterialBindingAPI.Apply(sphere.GetPrim()).Bind(material)
    runtime.GetRootLayer().Save()

    reference = stage_with_camera(directory / "reference.usda")
    dense_points, dense_triangles = pre_tessellated(points, normals, uvs, triangles, heights, n, magnitude, center)
    dense = mesh(reference, dense_points, dense_triangles)
    UsdShade.MaterialBindingAPI.Apply(dense.GetPrim()).Bind(grey_material(reference, "/Looks/Grey"))
    reference.GetRootLayer().Save()
    return directory / "runtime.usda", directory / "reference.usda"


def measure(frames_of, runtime_session, reference_session, frames: int, resolution, row_of):
    """Rows of the displacement table: the pre-tessellated reference drawn at full detail (--no-lod) and through its DAG
    at 0.5, 1 and 2 px, and the runtime tessellation at dicing rates 0.5 to 8 px (the coarser ones to find where its
    error meets the DAG's); error against the full-detail reference."""
    settings = {"resolution": resolution, "aovs": ("color",), "camera": "/Camera"}
    def gpu_mib(result):  # what the surface costs in GPU memory: geometry, height map, tessellation lists
        s = result.stats
        return round((s["geometry_bytes"] + s["texture_bytes"] + s["tessellation_bytes"]) / 2**20, 1)

    reference, ref_wall, ref_gpu = frames_of(reference_session, frames, lod=False, **settings)
    rows = [row_of("displacement", "pre-tessellated, --no-lod", reference, ref_wall, ref_gpu, reference, surface_gpu_mib=gpu_mib(reference))]
    for error in (0.5, 1.0, 2.0):
        result, wall, gpu = frames_of(reference_session, frames, pixel_error=error, **settings)
        rows.append(row_of("displacement", f"pre-tessellated, {error:g} px", result, wall, gpu, reference, surface_gpu_mib=gpu_mib(result)))
    for rate in (0.5, 1.0, 2.0, 4.0, 8.0):
        result, wall, gpu = frames_of(runtime_session, frames, dicing_rate=rate, **settings)
        rows.append(row_of("displacement", f"runtime, dicing {rate:g} px", result, wall, gpu, reference,
                           micro_triangles=result.stats["micro_triangles"], patches=result.stats["patches"],
                           occluded_patches=result.stats["occluded_patches"], tessellation_ms=round(gpu["tessellation"], 1),
                           tessellation_bytes=result.stats["tessellation_bytes"], surface_gpu_mib=gpu_mib(result)))
    return rows
