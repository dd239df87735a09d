"""`tessera bench ...`: benchmarks that print tables of speed, memory and error (never timed tests).

    tessera bench build [STAGE.usd | MESH.obj ...] [--json FILE]
    tessera bench usd [--prims N] [--instances N] [--point-instances N] [--edits N] [--json FILE]

Each mesh is built in a child process so that its peak memory is its own (the input arrays excluded), after a
tetrahedron that pays the process's one-time costs (reported as "first build MiB").
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import resource
import time

import numpy as np

from . import raster_split


def _in_child(target, *args):
    """Runs target(queue, *args) in a fresh process and returns what it puts on the queue (a result or an Exception).
    The process is spawned, not forked: the parent has used USD, whose TBB worker threads do not survive a fork (a
    forked child could hang in them). A child that dies without answering comes back as an Exception, never a wait."""
    import queue as queues

    context = multiprocessing.get_context("spawn")
    channel = context.Queue()
    process = context.Process(target=target, args=(channel, *args))
    process.start()
    while True:
        try:
            outcome = channel.get(timeout=1.0)
            break
        except queues.Empty:
            if not process.is_alive():
                try:
                    outcome = channel.get(timeout=1.0)  # it may have answered just before exiting
                except queues.Empty:
                    outcome = RuntimeError(f"the benchmark's child process exited with code {process.exitcode} without a result")
                break
    process.join()
    return outcome


# The displaced sphere's bumps: (amplitude, theta frequency, theta phase, phi frequency) of each octave, each
# amplitude * sin(frequency * theta + phase) * cos(frequency * phi).
_BUMPS = ((0.04, 9, 0.0, 13), (0.01, 41, 3.0, 37))


def displaced_radius(theta, phi):
    """The displaced sphere's surface: its radius at polar angle theta and azimuth phi (radians)."""
    radius = 1.0
    for a, f, c, g in _BUMPS:
        radius = radius + a * np.sin(f * theta + c) * np.cos(g * phi)
    return radius


def _displaced_radius_slopes(theta, phi):
    """The radius's derivatives by theta and by phi."""
    return (sum(a * f * np.cos(f * theta + c) * np.cos(g * phi) for a, f, c, g in _BUMPS),
            sum(-a * g * np.sin(f * theta + c) * np.sin(g * phi) for a, f, c, g in _BUMPS))


def displaced_sphere(n: int):
    """A closed sphere of 4 n^2 triangles with a few octaves of bumps: a stand-in for a dense scan."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, 2 * n, endpoint=False), indexing="ij")
    points = _displaced_point(theta, phi).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a, b = i * 2 * n + j, i * 2 * n + (j + 1) % (2 * n)
    quads = np.stack([a, a + 2 * n, b + 2 * n, b], -1).reshape(-1, 4).astype(np.int32)
    return points.astype(np.float32).reshape(-1), np.full(len(quads), 4, np.int32), quads.reshape(-1)


def lat_long_uvs(n: int):
    """displaced_sphere(n)'s texture coordinates, face-varying (a row per face vertex) as a DCC exports a sphere's: u
    along the azimuth, v along the polar angle, with a seam where u wraps from 1 back to 0."""
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    u = np.stack([j, j, j + 1, j + 1], -1) / (2 * n)
    v = np.stack([i, i + 1, i + 1, i], -1) / n
    return np.stack([u, v], -1).astype(np.float32).reshape(-1)


def _displaced_point(theta, phi):
    """The displaced sphere's surface point at polar angle theta and azimuth phi (radians), last axis xyz."""
    r = displaced_radius(theta, phi)
    return np.stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi), r * np.cos(theta)], -1)


def _nearest_surface_distance(points, reach):
    """Each point's distance to the nearest point of the displaced sphere's surface, searched over the surface's (theta,
    phi) within `reach` of it (each point's radial distance: its radial projection lies on the surface, so the nearest
    point lies no farther): a 15 x 15 lattice, then four more, each a quarter as wide around the best sample so far."""
    rho = np.linalg.norm(points, axis=1)
    theta = np.arccos(np.clip(points[:, 2] / rho, -1.0, 1.0))
    phi = np.arctan2(points[:, 1], points[:, 0])
    # Half-widths of the window in theta and phi that hold every surface point within `reach` (angles at radius >= 0.9).
    half = np.minimum(2.0 * reach / 0.9 + 1e-9, np.pi / 2)
    half_phi = np.minimum(half / np.maximum(np.sin(theta) - half, 1e-3), np.pi)
    lattice = np.linspace(-1.0, 1.0, 15)
    best = np.full(len(points), np.inf)
    for _ in range(5):
        t = np.clip(theta[:, None, None] + half[:, None, None] * lattice[None, :, None], 0.0, np.pi)
        f = phi[:, None, None] + half_phi[:, None, None] * lattice[None, None, :]
        t, f = np.broadcast_arrays(t, f)
        distance = np.linalg.norm(_displaced_point(t, f) - points[:, None, None, :], axis=-1).reshape(len(points), -1)
        at = distance.argmin(axis=1)
        best = np.minimum(best, distance[np.arange(len(points)), at])
        theta, phi = t.reshape(len(points), -1)[np.arange(len(points)), at], f.reshape(len(points), -1)[np.arange(len(points)), at]
        half, half_phi = half / 4, half_phi / 4
    return best


def displaced_sphere_deviation(positions, indices, exact_points: int = 256):
    """How far a mesh made from the displaced sphere (a cut of its DAG, say) lies from the sphere's surface, at the
    points of a 7 x 7 barycentric lattice on every triangle, as (largest, mean) of their distances to the surface. The
    mean is of the first-order distance (the radial distance divided by the length of the surface function's gradient:
    near steep bumps the radial distance reads several times the nearest, up to 5x near the polar caps); the largest is
    the nearest distance itself, searched on the surface for the `exact_points` points farthest by either measure. The
    polar caps (|z| >= 0.98 r) are left out: at the poles the surface's radius depends on the azimuth, so the mesh's own
    pole fans stray from it. The source mesh's own deviation is in it."""
    steps = np.linspace(0.0, 1.0, 7)
    lattice = np.array([(a, b, 1.0 - a - b) for a in steps for b in steps if a + b <= 1.0 + 1e-9])
    points = np.einsum("kj,mjd->mkd", lattice, np.asarray(positions, np.float64)[np.asarray(indices)]).reshape(-1, 3)
    radius = np.linalg.norm(points, axis=1)
    inside = np.abs(points[:, 2]) < 0.98 * radius
    points, radius = points[inside], radius[inside]
    theta = np.arccos(np.clip(points[:, 2] / radius, -1.0, 1.0))
    phi = np.arctan2(points[:, 1], points[:, 0]) % (2 * np.pi)
    radial = np.abs(radius - displaced_radius(theta, phi))
    # The gradient of |p| - r(theta, phi): (1, -r_theta / |p|, -r_phi / (|p| sin theta)) in the spherical frame.
    r_theta, r_phi = _displaced_radius_slopes(theta, phi)
    first_order = radial / np.sqrt(1.0 + (r_theta / radius) ** 2 + (r_phi / (radius * np.sin(theta))) ** 2)
    farthest = np.union1d(np.argsort(radial)[-exact_points:], np.argsort(first_order)[-exact_points:])
    largest = _nearest_surface_distance(points[farthest], radial[farthest]).max() if len(farthest) else 0.0
    return float(largest), float(first_order.mean())


def obj_mesh(path: str):
    vertices, counts, indices = [], [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                vertices.extend(float(x) for x in line.split()[1:4])
            elif line.startswith("f "):
                corners = [int(c.split("/")[0]) - 1 for c in line.split()[1:]]
                counts.append(len(corners))
                indices.extend(corners)
    return np.array(vertices, np.float32), np.array(counts, np.int32), np.array(indices, np.int32)


def stage_meshes(path: str):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(path)
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            mesh = UsdGeom.Mesh(prim)
            points = mesh.GetPointsAttr().Get()
            counts = mesh.GetFaceVertexCountsAttr().Get()
            indices = mesh.GetFaceVertexIndicesAttr().Get()
            if points is None or counts is None or indices is None:
                continue
            yield (f"{path}:{prim.GetPath()}", lambda p=points, c=counts, i=indices: (
                np.ascontiguousarray(np.asarray(p, np.float32).reshape(-1)), np.asarray(c, np.int32), np.asarray(i, np.int32)))


# A tetrahedron: the smallest closed mesh, built once before the measured mesh (see _build_one).
_TETRAHEDRON = (np.array([0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1], np.float32), np.full(4, 3, np.int32),
                np.array([0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3], np.int32))


def _resident_peak_bytes():
    """The process's resident peak (VmHWM in /proc/self/status), in bytes; None where there is none."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _restart_resident_peak() -> bool:
    """Restarts the process's resident peak at what it holds now (Linux 4.0 and later); False where it cannot."""
    try:
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")
    except OSError:
        return False
    return _resident_peak_bytes() is not None


def _build_one(arrays, queue):
    from tessera import _tessera

    def peak_bytes():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

    # The first build in a process faults in the builder's code and starts its worker threads (stacks, allocator
    # arenas): about 2 MiB whatever the mesh. A tetrahedron pays that first, so that "peak B/tri" is what the mesh
    # itself costs; the one-time cost is its own column. Then the resident peak restarts from what the process holds:
    # measured as the growth of the lifetime peak instead (where it cannot restart), the figure moved by +-40 B/tri
    # between runs of the bunny, as the child found more or less of its parent's freed memory to reuse.
    start = peak_bytes()
    _tessera.build_mesh(*_TETRAHEDRON)
    first_build = peak_bytes() - start
    held = _rss_bytes()  # after handing malloc's unused memory back
    restarted = _restart_resident_peak()
    before = held if restarted else peak_bytes()
    start = time.perf_counter()
    stats = _tessera.build_mesh(*arrays)  # includes encoding the pages, and decoding them once
    seconds = time.perf_counter() - start - stats["decode_seconds"]
    peak = _resident_peak_bytes() if restarted else peak_bytes()
    queue.put((stats, seconds, peak - before, peak_bytes(), first_build))


def _measure(name, make, on_displaced_sphere=False):
    # The input is made here, before the fork, so that the child's peak memory is the build's alone.
    arrays = make()
    queue = multiprocessing.get_context("fork").Queue()
    process = multiprocessing.get_context("fork").Process(target=_build_one, args=(arrays, queue))
    process.start()
    stats, seconds, build_peak, process_peak, first_build_bytes = queue.get()
    process.join()
    del arrays
    levels = stats["levels"]
    source = stats["source_triangles"]
    row = {
        "mesh": name,
        "input_triangles": source,
        "build_seconds": round(seconds, 3),
        "input_triangles_per_second": round(source / seconds),
        "peak_memory_bytes_per_input_triangle": round(build_peak / max(source, 1), 1),
        "process_peak_mib": round(process_peak / 2**20, 1),
        "first_build_mib": round(first_build_bytes / 2**20, 2),
        "in_memory_bytes_per_input_triangle": round(stats["memory_bytes"] / max(source, 1), 1),
        "disk_bytes_per_input_triangle": round(stats["disk_bytes"] / max(source, 1), 2),
        "decode_seconds": round(stats["decode_seconds"], 4),
        "decode_input_triangles_per_second": round(source / max(stats["decode_seconds"], 1e-9)),
        "pages": stats["pages"],
        "dag_depth": len(levels),
        "clusters": stats["clusters"],
        "groups": stats["groups"],
        "root_triangles": stats["root_triangles"],
        "mean_triangles_per_cluster_level0": round(levels[0]["triangles"] / max(levels[0]["clusters"], 1), 1),
        "relative_error_per_level": [float(f"{level['relative_error']:.3g}") for level in levels],
    }
    # The error against the geometry: the fallback mesh (the DAG's first cut at 1 % of the size) of a displaced sphere,
    # its claimed error and its distance from the sphere's surface (relative to the size): the largest nearest distance
    # and the mean first-order one (displaced_sphere_deviation).
    fallback = stats["fallback"]
    row["fallback_triangles"] = fallback["triangles"]
    row["fallback_relative_error"] = float(f"{fallback['relative_error']:.3g}")
    if on_displaced_sphere:
        largest, mean = displaced_sphere_deviation(fallback["positions"], fallback["indices"])
        row["fallback_measured_relative_max"] = float(f"{largest / stats['size']:.3g}")
        row["fallback_measured_relative_mean"] = float(f"{mean / stats['size']:.3g}")
    return row


def default_meshes():
    from pathlib import Path

    # The shared test assets sit beside the project: found from the working directory (the project root).
    meshes = []
    for root in (Path.cwd() / ".." / "shared", Path.cwd() / "shared"):
        bunny = root / "assets" / "meshes" / "stanford-bunny.obj"
        if bunny.exists():
            meshes.append(("stanford-bunny (69k)", lambda b=bunny: obj_mesh(str(b)), False))
            break
    meshes.append(("displaced sphere 1M", lambda: displaced_sphere(500), True))
    # The same with face-varying texture coordinates, as most USD meshes come: their seam splits vertices, and the
    # simplifier weighs them.
    meshes.append(("displaced sphere 1M, face-varying UVs", lambda: (*displaced_sphere(500), "mesh", lat_long_uvs(500)), True))
    meshes.append(("displaced sphere 10M", lambda: displaced_sphere(1581), True))
    return meshes


COLUMNS = [("mesh", "mesh"), ("input_triangles", "input tris"), ("build_seconds", "build s"), ("input_triangles_per_second", "tris/s"),
           ("peak_memory_bytes_per_input_triangle", "peak B/tri"), ("disk_bytes_per_input_triangle", "disk B/tri"),
           ("first_build_mib", "first build MiB"), ("decode_input_triangles_per_second", "decode tris/s"),
           ("dag_depth", "depth"), ("root_triangles", "root tris"), ("mean_triangles_per_cluster_level0", "tris/cluster L0"),
           ("fallback_triangles", "fallback tris"), ("fallback_relative_error", "fallback error"),
           ("fallback_measured_relative_max", "measured max"), ("fallback_measured_relative_mean", "measured mean")]


def build(args) -> int:
    meshes = []
    for path in args.stages:
        if path.endswith(".obj"):
            meshes.append((path, lambda p=path: obj_mesh(p), False))
        else:
            meshes.extend((name, make, False) for name, make in stage_meshes(path))
    if not args.stages:
        meshes = default_meshes()
    rows = []
    print(" | ".join(title for _, title in COLUMNS) + " | relative error per level")
    for name, make, on_displaced_sphere in meshes:
        row = _measure(name, make, on_displaced_sphere)
        rows.append(row)
        print(" | ".join(str(row.get(key, "")) for key, _ in COLUMNS) + " | " + " ".join(f"{e:.2g}" for e in row["relative_error_per_level"]),
              flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0


# ---------------------------------------------------------------------------------------------------------------
# tessera bench render: density scaling, against brute force, speed against error (on the device Tessera picks).

FIELD_SIDE = 32  # fields are FIELD_SIDE^2 instances of one displaced sphere on a grid 3 units apart
FIELD_MATERIALS = 8  # the materials table's field: its instances take that many materials in turn
BRUTE_TRIANGLES = 1e7  # the single mesh drawn against brute force has at least this many triangles (at --max-density 3)


def _write_sphere_stage(path, n: int, field: bool, face_colours: bool = False, materials: int = 1):
    """A stage holding one displaced sphere of 4 n^2 triangles, alone or instanced FIELD_SIDE^2 times; with
    `face_colours`, a colour per face (uniform displayColor, varying smoothly over the sphere: a seam at every edge); with
    `materials` > 1 (a field), as many prototypes of that sphere, each bound to a UsdPreviewSurface of its own colour,
    taken by the instances in turn (the mesh cache builds the sphere once, the GPU holds it once)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    points, counts, indices = displaced_sphere(n)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    mesh_path = "/World/Field/Prototypes/Sphere" if field else "/World/Sphere"
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points.reshape(-1, 3)))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(indices))
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    if face_colours:
        centres = points.reshape(-1, 3)[indices.reshape(-1, 4)].mean(1)
        colours = 0.5 + 0.2 * np.sin(3 * centres + np.array([0.0, 1.0, 2.0]))
        primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform)
        primvar.Set(Vt.Vec3fArray.FromNumpy(colours.astype(np.float32)))
    else:
        mesh.GetDisplayColorAttr().Set([Gf.Vec3f(0.6, 0.55, 0.5)])
    if field:
        prototypes = [mesh]
        for k in range(1, materials):  # the same sphere again (Sdf copies its specs)
            Sdf.CopySpec(stage.GetRootLayer(), mesh.GetPath(), stage.GetRootLayer(), mesh.GetPath().ReplaceName(f"Sphere{k}"))
            prototypes.append(UsdGeom.Mesh.Get(stage, mesh.GetPath().ReplaceName(f"Sphere{k}")))
        for k, prototype in enumerate(prototypes if materials > 1 else []):
            material = UsdShade.Material.Define(stage, f"/World/Looks/Material{k}")
            shader = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("Surface"))
            shader.CreateIdAttr("UsdPreviewSurface")
            hue = 2 * np.pi * k / materials
            shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*(0.45 + 0.3 * np.cos(hue + np.array([0.0, 2.1, 4.2])))))
            shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.3 + 0.4 * k / materials)
            material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(prototype.GetPrim()).Bind(material)
        instancer = UsdGeom.PointInstancer.Define(stage, "/World/Field")
        instancer.GetPrototypesRel().SetTargets([prototype.GetPath() for prototype in prototypes])
        grid = np.arange(FIELD_SIDE, dtype=np.float32) * 3.0
        x, z = np.meshgrid(grid, grid, indexing="ij")
        positions = np.stack([x.ravel(), np.zeros(x.size, np.float32), z.ravel()], 1)
        instancer.GetPositionsAttr().Set(Vt.Vec3fArray.FromNumpy(positions))
        instancer.GetProtoIndicesAttr().Set(Vt.IntArray.FromNumpy((np.arange(x.size) % materials).astype(np.int32)))
    _camera_and_lights(stage, field)
    stage.GetRootLayer().Save()


def _camera_and_lights(stage, field: bool):
    """/World/Camera over the field, or framing a unit sphere at the origin; a sun and a dim sky."""
    from pxr import Gf, UsdGeom, UsdLux

    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.GetFocalLengthAttr().Set(24.0 if field else 35.0)
    camera.GetHorizontalApertureAttr().Set(36.0)
    camera.GetVerticalApertureAttr().Set(20.25)
    if field:
        eye, target = Gf.Vec3d(-6.0, 14.0, -6.0), Gf.Vec3d(46.5, 0.0, 46.5)
        camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.1, 1000.0))
    else:
        eye, target = Gf.Vec3d(0.0, 0.4, 2.3), Gf.Vec3d(0.0, 0.0, 0.0)  # the sphere fills the frame
        camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.01, 100.0))
    camera.AddTransformOp().Set(Gf.Matrix4d().SetLookAt(eye, target, Gf.Vec3d(0, 1, 0)).GetInverse())
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateNormalizeAttr(True)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(-45.0, 30.0, 0.0))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.3)


def _displaced_stage(directory, segments: int) -> str:
    """A stage holding one UV sphere of about 2 segments^2 triangles (a wrap seam, texture coordinates) displaced at render
    time by a height map, filling the frame as the single sphere of `_write_sphere_stage` does (its camera, its lights)."""
    from pathlib import Path

    from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

    from .bench_displacement import displaced_material, height_map, uv_sphere, write_height_png

    path = Path(directory) / f"displaced_sphere_{segments}.usdc"
    if path.exists():
        return str(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    heights = path.with_name(f"displaced_sphere_{segments}_heights.png")
    write_height_png(heights, height_map(512, 256, bumps=8))
    temporary = path.with_suffix(".tmp.usdc")
    stage = Usd.Stage.CreateNew(str(temporary))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    points, normals, uvs, triangles = uv_sphere(segments, segments // 2)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Sphere")
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(triangles), 3, np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(triangles.astype(np.int32).reshape(-1)))
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    mesh.GetNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(uvs.astype(np.float32)))
    material = displaced_material(stage, "/World/Looks/Bumps", texture=heights.name, magnitude=0.05, center=0.5)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    _camera_and_lights(stage, False)
    stage.GetRootLayer().Save()
    temporary.rename(path)
    return str(path)


def _stage(directory, n: int, field: bool, face_colours: bool = False, materials: int = 1) -> str:
    from pathlib import Path

    suffix = ("_face_colours" if face_colours else "") + (f"_{materials}_materials" if materials > 1 else "")
    path = Path(directory) / f"{'field' if field else 'single'}_sphere_{n}{suffix}.usdc"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_suffix(".tmp.usdc")
        _write_sphere_stage(temporary, n, field, face_colours, materials)
        temporary.rename(path)
    return str(path)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two RGB(A) images clipped to [0, 1] (99 when identical)."""
    mse = float(np.mean((np.clip(a[..., :3], 0, 1) - np.clip(b[..., :3], 0, 1)) ** 2))
    return 99.0 if mse == 0 else round(10 * np.log10(1.0 / mse), 2)


def block_means(image: np.ndarray, block: int = 4) -> np.ndarray:
    """An RGB(A) image clipped to [0, 1] and averaged over block x block pixels (the edge rows and columns that fill no
    block left out): the image at the scale of a few pixels. At one sample per pixel, a surface with detail below a
    pixel aliases into noise whose every sample differs between two renderings; the means keep what the eye sees."""
    height, width = image.shape[0] // block * block, image.shape[1] // block * block
    rgb = np.clip(image[:height, :width, :3], 0, 1)
    return rgb.reshape(height // block, block, width // block, block, 3).mean(axis=(1, 3))


def _process_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _timed_frames(session, frames: int, camera="/World/Camera", **settings):
    """One warm-up frame, then the median of `frames` frames (wall ms of the whole render call including the readback,
    GPU ms of the passes, and the process's CPU ms: on a CPU device, lavapipe's threads too, which other jobs on the
    machine move less than the wall time), with the last frame."""
    session.render(camera=camera, **settings)
    walls, passes, cpus = [], [], []
    for _ in range(frames):
        start, cpu = time.perf_counter(), _process_seconds()
        result = session.render(camera=camera, **settings)
        walls.append((time.perf_counter() - start) * 1000)
        cpus.append((_process_seconds() - cpu) * 1000)
        passes.append(result.stats["gpu_ms"])
    if result.errors:
        raise RuntimeError("; ".join(result.errors))
    gpu = {name: float(np.median([p[name] for p in passes])) for name in passes[0]}
    gpu["total"] = float(np.median([sum(p.values()) for p in passes]))
    gpu["process_cpu"] = float(np.median(cpus))
    return result, float(np.median(walls)), gpu


def _frames(session, frames: int, camera="/World/Camera", **settings):
    """_timed_frames of the settings' (colour) frames, then one frame with color and primId for the error measures."""
    _, wall, gpu = _timed_frames(session, frames, camera, **settings)
    result = session.render(camera=camera, **{**settings, "aovs": ("color", "primId")})
    if result.errors:
        raise RuntimeError("; ".join(result.errors))
    return result, wall, gpu


def _row(table, label, result, wall, gpu, reference=None, **extra):
    s = result.stats
    row = {"table": table, "case": label, "source_triangles": s["source_triangles"], "instances": s["instances"],
           "visible_instances": s["visible_instances"], "pixel_error": s["pixel_error"], "lod": s["lod"],
           "error_bound_px": s["pixel_error"] if s["lod"] else 0,
           "candidate_clusters": s["candidate_clusters"], "visible_clusters": s["visible_clusters"],
           "triangles_drawn": s["visible_triangles"], "frame_ms": round(wall, 1), "frame_cpu_ms": round(gpu["process_cpu"], 1),
           "gpu_ms": round(gpu["total"], 1),
           "cull_ms": round(gpu["cull"], 1), "sw_raster_ms": round(gpu["sw_raster"], 1), "hw_raster_ms": round(gpu["hw_raster"], 1),
           "hzb_ms": round(gpu["hzb"], 1), "classify_ms": round(gpu["classify"], 1), "resolve_ms": round(gpu["resolve"], 1),
           "readback_ms": round(gpu["readback"], 1), "sw_triangles": s["sw_triangles"],
           "hw_triangles": s["hw_triangles"], "occlusion": s["occlusion_tested"], "occlusion_rested": s["occlusion_rested"],
           "occluded_instances": s["occluded_instances"],
           "occluded_clusters": s["occluded_clusters"], "sw_raster_area": s["sw_raster_area"],
           "sw_raster_area_source": s["sw_raster_area_source"]}
    if reference is not None:
        color, ref_color = result["color"].pixels, reference["color"].pixels
        row["psnr_db"] = psnr(color, ref_color)
        row["psnr_4x4_db"] = psnr(block_means(color), block_means(ref_color))
        row["pixels_off_percent"] = round(100 * float(np.mean(np.abs(color[..., :3] - ref_color[..., :3]).max(-1) > 0.05)), 3)
        row["same_prim_percent"] = round(100 * float(np.mean(result["primId"].ids() == reference["primId"].ids())), 3)
        row["error_reference"] = "--no-lod"  # every source triangle, unless the caller names another
    row.update(extra)
    return row


def _speedups(ref_wall, ref_gpu, wall, gpu):
    """A row's speed against its --no-lod reference: in wall time (the whole render call: the CPU's part included) and in
    the passes' GPU time alone."""
    return {"speedup_vs_no_lod": round(ref_wall / wall, 1),
            "gpu_speedup_vs_no_lod": round(ref_gpu["total"] / gpu["total"], 1) if gpu["total"] > 0 else None}


# A density field's image error is measured against every source triangle (--no-lod) up to --no-lod-limit source
# triangles in the stage; above it (the 1e10 field: 9.3 G triangles, about 30 min a frame on lavapipe) against the cut at
# DENSITY_REFERENCE_PIXEL_ERROR, whose own error against --no-lod on the 1e8 field is in docs/benchmarks.md.
DENSITY_REFERENCE_PIXEL_ERROR = 1 / 16


# The AOV table's sets: the colour alone, what compositing usually takes, every AOV.
AOV_SETS = (("color",), ("color", "depth", "normal", "primId"), ("color", "depth", "normal", "primId", "instanceId", "clusterId", "triangleId"))


# The anti-aliasing table's pixel samples and filters; the most box samples also give the reference every row is measured
# against besides its own.
ANTIALIASING_RUNS = ((1, "box"), (4, "box"), (16, "box"), (16, "gaussian"))


def _reference(session, settings, **render_args):
    """One untimed frame with color and primId for rows to measure their image error against."""
    result = session.render(camera="/World/Camera", **{**settings, "aovs": ("color", "primId")}, **render_args)
    if result.errors:
        raise RuntimeError("; ".join(result.errors))
    return result


def _density_reference(session, source_triangles, settings, no_lod_limit):
    """A density field's reference frame (_reference) and its name."""
    full = source_triangles <= no_lod_limit
    lod = {"lod": False} if full else {"pixel_error": DENSITY_REFERENCE_PIXEL_ERROR}
    return _reference(session, settings, **lod), "--no-lod" if full else f"{DENSITY_REFERENCE_PIXEL_ERROR:g} px cut"


def _render_case(queue, case, stage, resolution, frames, device, no_lod_limit):
    """Runs in a child process, so that its peak memory is its own and Vulkan starts fresh."""
    try:
        from tessera import Session

        started = time.perf_counter()
        beside = "a displaced sphere" if "displaced_sphere" in str(stage) else "the mesh"  # what an edit case edits beside
        if case == "edit":  # the stage with a small quad added in its session layer, in front of the camera
            stage = _with_quad(stage)
        session = Session(stage[0] if case == "displacement" else stage, device=device)
        settings = {"resolution": resolution, "aovs": ("color",)}
        load_s = time.perf_counter() - started
        rows = []
        if case == "displacement":  # the runtime-displaced sphere against the same surface pre-tessellated
            from .bench_displacement import measure

            rows = measure(_frames, session, Session(stage[1], device=device), frames, resolution, _row)
        elif case == "density":
            # With two-pass occlusion where it pays (the default: on a CPU device it rests while it culls little), in every
            # frame (each measured frame tests against the one before), then without.
            modes = {"auto": (True, ""), "always": ("always", ", occlusion every frame"), "off": (False, ", no occlusion")}
            measured = [(mode, *_frames(session, frames, occlusion=occlusion, **settings)) for mode, (occlusion, _) in modes.items()]
            reference, reference_name = _density_reference(session, measured[0][1].stats["source_triangles"], settings, no_lod_limit)
            for mode, result, wall, gpu in measured:
                label = f"{result.stats['source_triangles'] / 1e6:,.0f} M source triangles" + modes[mode][1]
                rows.append(_row("density scaling", label, result, wall, gpu, reference, error_reference=reference_name, occlusion_mode=mode))
        elif case == "seams":  # a field with a colour per face (a seam at every edge) or one colour, against --no-lod
            kind = "colour per face" if "face_colours" in stage else "one colour"
            reference, ref_wall, ref_gpu = _frames(session, 1, lod=False, **settings)  # every source triangle: one frame
            result, wall, gpu = _frames(session, frames, pixel_error=1.0, **settings)
            for label, row_result, row_wall, row_gpu in ((f"{kind}, 1 px", result, wall, gpu), (f"{kind}, --no-lod", reference, ref_wall, ref_gpu)):
                rows.append(_row("seams", label, row_result, row_wall, row_gpu, reference, **_speedups(ref_wall, ref_gpu, row_wall, row_gpu)))
        elif case == "antialiasing":  # pixel samples: cost per sample, error against every source triangle at as many samples
            references = {run: _reference(session, settings, lod=False, pixel_samples=run[0], pixel_filter=run[1]) for run in ANTIALIASING_RUNS}
            finest = references[max(run for run in ANTIALIASING_RUNS if run[1] == "box")]
            for samples, pixel_filter in ANTIALIASING_RUNS:
                result, wall, gpu = _frames(session, frames, pixel_samples=samples, pixel_filter=pixel_filter, **settings)
                name = f"{samples} sample{'s' if samples > 1 else ''}" + (f", {pixel_filter}" if pixel_filter != "box" else "")
                rows.append(_row("anti-aliasing", name, result, wall, gpu, references[(samples, pixel_filter)], error_reference=f"--no-lod, {name}",
                                 pixel_samples=samples, pixel_filter=pixel_filter, ms_per_sample=round(wall / samples, 1),
                                 psnr_vs_finest_db=psnr(result["color"].pixels, finest["color"].pixels)))
        elif case == "edit":  # a live edit beside a large mesh: the quad's points move, the mesh is built and goes up alone
            _reference(session, settings)
            _reference(session, settings)
            points = stage.GetPrimAtPath("/World/EditedQuad").GetAttribute("points")
            uploads, written, walls, cpus, passes, prepared, submissions = [], [], [], [], [], [], []
            for k in range(frames):
                points.Set([(x + 0.001 * (k + 1), y, z) for x, y, z in points.Get()])
                start, cpu = time.perf_counter(), _process_seconds()
                edited = session.render(camera="/World/Camera", **settings)
                walls.append((time.perf_counter() - start) * 1000)
                cpus.append((_process_seconds() - cpu) * 1000)
                passes.append(edited.stats["gpu_ms"])
                uploads.append(edited.stats["upload_ms"])
                written.append(edited.stats["geometry_upload_bytes"])
                prepared.append(edited.stats["displaced_meshes_prepared"])
                submissions.append(edited.stats["upload_submissions"])
                if edited.errors:
                    raise RuntimeError("; ".join(edited.errors))
            gpu = {name: float(np.median([p[name] for p in passes])) for name in passes[0]}
            gpu.update(total=float(np.median([sum(p.values()) for p in passes])), process_cpu=float(np.median(cpus)))
            rows.append(_row("live edit", f"a quad's points beside {beside}", edited, float(np.median(walls)), gpu,
                             upload_ms=round(float(np.median(uploads)), 2), geometry_upload_bytes=int(np.median(written)),
                             displaced_meshes_prepared=max(prepared), upload_submissions=int(np.median(submissions)),
                             micro_triangles=edited.stats["micro_triangles"],
                             host_mesh_mib=round(edited.stats["host_mesh_bytes"] / 2**20, 1), host_mesh_bytes=edited.stats["host_mesh_bytes"],
                             geometry_mib=round(edited.stats["geometry_bytes"] / 2**20, 1)))
        elif case == "materials":  # a field of several materials: each pixel reading its own (a CPU device), or bins
            os.environ["TESSERA_MATERIAL_BINS"] = "1"  # read when the session's renderer is made
            try:
                binned_session = Session(stage, device=device)
            finally:
                del os.environ["TESSERA_MATERIAL_BINS"]
            binned, binned_wall, binned_gpu = _frames(binned_session, frames, **settings)
            result, wall, gpu = _frames(session, frames, **settings)
            for row_result, row_wall, row_gpu in ((result, wall, gpu), (binned, binned_wall, binned_gpu)):
                how = "each pixel's own material" if row_result.stats["pixel_materials"] else f"{row_result.stats['shading_bins']} bins"
                rows.append(_row("materials", f"{FIELD_MATERIALS} materials, {how}", row_result, row_wall, row_gpu, binned,
                                 error_reference="bins", pixel_mib=round(row_result.stats["pixel_bytes"] / 2**20)))
        elif case == "aovs":  # the AOVs a compositing pipeline asks for together: resolve writes them in one pass
            for aovs in AOV_SETS:
                result, wall, gpu = _timed_frames(session, frames, **{**settings, "aovs": aovs})
                rows.append(_row("AOVs", ", ".join(aovs) if len(aovs) < len(AOV_SETS[-1]) else "all seven", result, wall, gpu,
                                 aovs=len(aovs), pixel_mib=round(result.stats["pixel_bytes"] / 2**20), pixel_bytes=result.stats["pixel_bytes"]))
        elif case == "first-frame":  # a batch render's first frame: its meshes from the mesh cache, uploaded, then drawn
            start = time.perf_counter()
            first = _reference(session, settings)  # timed: the first frame is the one measured
            first_ms = (time.perf_counter() - start) * 1000
            result, wall, gpu = _frames(session, frames, **settings)
            count = first.stats["source_triangles"]
            label = (f"{count / 1e6:,.0f} M" if count >= 1e6 else f"{count / 1e3:,.0f} k") + " source triangles" + (", a field" if "field" in stage else ", one mesh")
            rows.append(_row("first frame", label, result, wall, gpu, first, error_reference="first frame", first_frame_ms=round(first_ms, 1),
                             upload_ms=round(first.stats["upload_ms"], 2), meshes_cached=first.stats["meshes_cached"],
                             meshes_built=first.stats["meshes_built"], resident_mib=round(_resident_bytes() / 2**20)))
        else:
            reference, ref_wall, ref_gpu = _frames(session, frames, lod=False, **settings)
            for pixel_error in ((1.0,) if case == "brute" else (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)):
                result, wall, gpu = _frames(session, frames, pixel_error=pixel_error, **settings)
                rows.append(_row("against brute force" if case == "brute" else "speed against error", f"{pixel_error:g} px",
                                 result, wall, gpu, reference, **_speedups(ref_wall, ref_gpu, wall, gpu)))
            if case == "brute":
                rows.append(_row("against brute force", "--no-lod", reference, ref_wall, ref_gpu, reference,
                                 **_speedups(ref_wall, ref_gpu, ref_wall, ref_gpu)))
        # The kernel's high-water mark lags the resident set (it is brought up to date on some events only): never below it.
        peak = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, _resident_bytes())
        for row in rows:
            row["device"] = session.device_name
            row["resolution"] = f"{resolution[0]}x{resolution[1]}"
            row["load_seconds"] = round(load_s, 1)
            row["peak_memory_mib"] = round(peak / 2**20)
        queue.put(rows)
    except Exception as error:  # reported by the parent, which goes on with the other cases
        queue.put(error)


def _with_quad(path):
    """The stage at `path` opened with a 4-vertex quad, /World/EditedQuad, defined in its session layer near the camera's
    line of sight (the stages of `_write_sphere_stage`)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    stage.SetEditTarget(stage.GetSessionLayer())
    quad = UsdGeom.Mesh.Define(stage, "/World/EditedQuad")
    quad.GetPointsAttr().Set([(-0.1, -0.1, 1.2), (0.1, -0.1, 1.2), (0.1, 0.1, 1.2), (-0.1, 0.1, 1.2)])
    quad.GetFaceVertexCountsAttr().Set([4])
    quad.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    return stage


def _fill_cache(queue, stage, device):
    """Runs in a child process: renders the stage once, small, so that its meshes are in the mesh cache."""
    try:
        from tessera import Session

        result = Session(stage, device=device).render(camera="/World/Camera", resolution=(64, 36))
        queue.put(RuntimeError("; ".join(result.errors)) if result.errors else True)
    except Exception as error:
        queue.put(error)


def _density_in_turns(queue, stages, resolution, turns, device):
    """Runs in a child process: the density fields rendered in turns, one frame of each field after the other, so that
    a host whose speed drifts (shared cores, lavapipe) moves every field alike. The fields' own children measure each
    field alone, one after the other, minutes apart on a busy host: their ratio moves with the host (1.26x to 1.85x in
    six runs within two minutes, docs/benchmarks.md), this one with the code. A turn draws its field twice and times
    the second frame, so that each timed frame finds the caches as a field drawn alone would (the other fields' frames
    in between evict its data). On the 2-core host of session 17, single frames swung by 15 % within seconds: the
    ratio of the medians of 5 turns ranged over 1.34-1.82x, of 15 turns over 1.54-1.55x (three runs each). Puts
    [frame ms, GPU ms] per field, the medians of `turns` timed frames."""
    try:
        from tessera import Session

        sessions = [Session(stage, device=device) for stage in stages]
        settings = {"camera": "/World/Camera", "resolution": resolution, "aovs": ("color",)}
        for session in sessions:  # warm-up: pipelines, uploads, and the frame before for two-pass occlusion
            session.render(**settings)
        # Then half a second more of frames: a GPU left idle while the fields loaded runs at low clocks until it has been
        # busy a while (on an H100, after one frame each, every field measured about 1 ms more in turns than alone, its
        # passes' GPU time too; a probe drawing for seconds found no difference).
        warm_until = time.perf_counter() + 0.5
        while time.perf_counter() < warm_until:
            for session in sessions:
                session.render(**settings)
        walls, gpus = [[] for _ in sessions], [[] for _ in sessions]
        for _ in range(turns):
            for session, wall, gpu in zip(sessions, walls, gpus):
                session.render(**settings)
                start = time.perf_counter()
                result = session.render(**settings)
                wall.append((time.perf_counter() - start) * 1000)
                gpu.append(sum(result.stats["gpu_ms"].values()))
        queue.put([[round(float(np.median(w)), 1), round(float(np.median(g)), 1)] for w, g in zip(walls, gpus)])
    except Exception as error:  # reported by the parent, which goes on with the fields measured alone
        queue.put(error)


RENDER_COLUMNS = [("table", "table"), ("case", "case"), ("source_triangles", "source tris"), ("error_bound_px", "error bound px"), ("visible_instances", "instances"),
                  ("visible_clusters", "clusters"), ("triangles_drawn", "tris drawn"), ("sw_triangles", "SW tris"), ("frame_ms", "frame ms"),
                  ("frame_in_turns_ms", "in turns ms"), ("frame_cpu_ms", "frame CPU ms"),
                  ("gpu_ms", "GPU ms"), ("cull_ms", "cull"), ("sw_raster_ms", "SW raster"),
                  ("hw_raster_ms", "HW raster"), ("hzb_ms", "HZB"), ("classify_ms", "classify"), ("resolve_ms", "resolve"),
                  ("readback_ms", "readback"), ("occluded_instances", "occluded inst"), ("occluded_clusters", "occluded clusters"),
                  ("peak_memory_mib", "peak MiB"), ("psnr_db", "PSNR dB"), ("psnr_4x4_db", "PSNR 4x4 dB"), ("pixels_off_percent", "px off %"),
                  ("same_prim_percent", "same prim %"), ("error_reference", "against"), ("ms_per_sample", "ms per sample"),
                  ("psnr_vs_finest_db", "PSNR vs 16 box samples"), ("speedup_vs_no_lod", "speedup"),
                  ("gpu_speedup_vs_no_lod", "GPU speedup"), ("micro_triangles", "micro tris"),
                  ("tessellation_ms", "tess ms"), ("surface_gpu_mib", "surface GPU MiB"), ("load_seconds", "load s"),
                  ("first_frame_ms", "first frame ms"), ("upload_ms", "upload ms"), ("meshes_cached", "meshes cached"),
                  ("resident_mib", "resident MiB"), ("geometry_upload_bytes", "upload bytes"), ("geometry_mib", "GPU geometry MiB"),
                  ("host_mesh_mib", "host mesh MiB"), ("displaced_meshes_prepared", "displaced prepared"),
                  ("upload_submissions", "upload submits"), ("aovs", "AOVs"), ("pixel_mib", "pixel MiB")]


def _write_plot(rows, path):
    """A small PNG: frame ms (orange) and PSNR (blue) against the pixel error (log2 axis, 0.25 to 8)."""
    import struct
    import zlib

    width, height, pad = 480, 270, 24
    image = np.full((height, width, 3), 255, np.uint8)
    image[pad:height - pad, pad] = image[height - pad, pad:width - pad] = 0
    xs = [np.log2(r["pixel_error"]) for r in rows]
    for series, colour in (([r["frame_ms"] for r in rows], (230, 120, 20)), ([r["psnr_db"] for r in rows], (40, 90, 200))):
        lo, hi = min(series), max(series)
        points = [(pad + (x - xs[0]) / (xs[-1] - xs[0]) * (width - 3 * pad),
                   height - pad - (v - lo) / max(hi - lo, 1e-9) * (height - 3 * pad) - pad / 2) for x, v in zip(xs, series)]
        for (x0, y0), (x1, y1) in zip(points, points[1:]):
            for t in np.linspace(0, 1, 400):
                image[int(y0 + t * (y1 - y0)) - 1:int(y0 + t * (y1 - y0)) + 2, int(x0 + t * (x1 - x0)) - 1:int(x0 + t * (x1 - x0)) + 2] = colour
        for x, y in points:
            image[int(y) - 4:int(y) + 5, int(x) - 4:int(x) + 5] = colour
    raw = b"".join(b"\0" + image[y].tobytes() for y in range(height))
    chunk = lambda tag, data: struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) +
                chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def render(args) -> int:
    width, height = args.resolution
    # Density scaling: the same field of FIELD_SIDE^2 instances, with prototypes of ~1e3, ~1e5 and ~1e7 triangles.
    sides = [int(round(np.sqrt(total / FIELD_SIDE**2 / 4))) for total in (1e6, 1e8, 1e10)]
    cases = []
    if "density" in args.cases:
        cases += [("density", _stage(args.stages_dir, n, True)) for n in sides[:args.max_density]]
    if "brute" in args.cases or "error" in args.cases or "aovs" in args.cases:
        # One sphere filling the frame: the densest prototype's shape, at full density with at least BRUTE_TRIANGLES
        # triangles (the brute-force case's mesh size; the 1e10 field's prototype has 9.76 M).
        n = sides[min(args.max_density, 3) - 1]
        single = _stage(args.stages_dir, max(n, math.ceil(math.sqrt(BRUTE_TRIANGLES / 4))) if args.max_density >= 3 else n, False)
        cases += [(case, single) for case in ("brute", "error", "aovs") if case in args.cases]
    if "first-frame" in args.cases:  # each density field, then the densest prototype alone
        cases += [("first-frame", _stage(args.stages_dir, n, True)) for n in sides[:args.max_density]]
        cases.append(("first-frame", _stage(args.stages_dir, sides[min(args.max_density, 3) - 1], False)))
    if "edit" in args.cases:  # a quad edited beside the densest prototype alone, then beside a sphere drawn displaced
        cases.append(("edit", _stage(args.stages_dir, sides[min(args.max_density, 3) - 1], False)))
        cases.append(("edit", _displaced_stage(args.stages_dir, (32, 256, 1024)[min(args.max_density, 3) - 1])))
    if "antialiasing" in args.cases:  # the lightest density field: its --no-lod frames are cheap
        cases.append(("antialiasing", _stage(args.stages_dir, sides[0], True)))
    if "materials" in args.cases:  # the middle density field, its instances in eight materials
        cases.append(("materials", _stage(args.stages_dir, sides[min(args.max_density, 2) - 1], True, materials=FIELD_MATERIALS)))
    if "seams" in args.cases:  # the same field, with a colour per face and with one colour
        cases += [("seams", _stage(args.stages_dir, args.seams_n, True, face_colours)) for face_colours in (True, False)]
    if "displacement" in args.cases:
        from pathlib import Path

        from .bench_displacement import height_map, write_stages

        # A 48 x 24 sphere (2 208 triangles) displaced by a 512 x 256 height map, about 860 px across at 1080p; the reference
        # cuts each triangle 32 x 32 at 1080p (2.26 M triangles, edges of about 2 px), fewer at lower resolutions.
        cut = max(2, round(32 * height / 1080))
        directory = Path(args.stages_dir) / f"displacement-{cut}"
        if not (directory / "reference.usda").exists():
            write_stages(directory, segments=48, rings=24, heights=height_map(512, 256, bumps=8), n=cut, magnitude=0.08, eye=(1.1, 2.0, 5.3))
        cases.append(("displacement", (str(directory / "runtime.usda"), str(directory / "reference.usda"))))
    rows = []
    failed = 0
    # The fields in turns in one process first, so that each field's row prints with its figure.
    fields = [stage for case, stage in cases if case == "density"]
    in_turns = _in_child(_density_in_turns, fields, (width, height), args.turns, args.device) if len(fields) > 1 else None
    if isinstance(in_turns, Exception):
        print(f"tessera: error: density fields in turns: {in_turns}", flush=True)
        failed += 1
        in_turns = None
    print(" | ".join(title for _, title in RENDER_COLUMNS))
    for case, stage in cases:
        filled = _in_child(_fill_cache, stage, args.device) if case in ("first-frame", "edit") else True
        outcome = filled if isinstance(filled, Exception) else _in_child(_render_case, case, stage, (width, height), args.frames, args.device,
                                                                         args.no_lod_limit)
        if isinstance(outcome, Exception):
            print(f"tessera: error: {case} ({stage}): {outcome}", flush=True)
            failed += 1
            continue
        for row in outcome:
            if in_turns and row["table"] == "density scaling" and row["occlusion_mode"] == "auto":
                row["frame_in_turns_ms"], row["gpu_in_turns_ms"] = in_turns[fields.index(stage)]
            rows.append(row)
            print(" | ".join(str(row.get(key, "")) for key, _ in RENDER_COLUMNS), flush=True)
    density = [r for r in rows if r["table"] == "density scaling" and r["occlusion_mode"] == "auto"]
    if len(density) > 1 and density[0]["frame_ms"] > 0:
        times = f"({density[-1]['source_triangles'] / density[0]['source_triangles']:.0f}x the source triangles)"
        if in_turns and density[0].get("frame_in_turns_ms", 0) > 0 and "frame_in_turns_ms" in density[-1]:
            print(f"density scaling: the densest field costs {density[-1]['frame_in_turns_ms'] / density[0]['frame_in_turns_ms']:.2f}x "
                  f"the lightest {times}, rendered in turns in one process (GPU time "
                  f"{density[-1]['gpu_in_turns_ms'] / max(density[0]['gpu_in_turns_ms'], 1e-9):.2f}x); each alone in its own process: "
                  f"{density[-1]['frame_ms'] / density[0]['frame_ms']:.2f}x")
        else:
            print(f"density scaling: the densest field costs {density[-1]['frame_ms'] / density[0]['frame_ms']:.2f}x the lightest {times}")
    sweep = [r for r in rows if r["table"] == "speed against error"]
    if args.plot and sweep:
        _write_plot(sweep, args.plot)
    if rows:
        print(f"device: {rows[0]['device']}, {rows[0]['resolution']}, median of {args.frames} frames after one warm-up; "
              f"raster split {rows[0]['sw_raster_area']:g} px per triangle ({rows[0]['sw_raster_area_source']})")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 1 if failed else 0


# The raster split: grids of triangles of one size each, drawn by each rasterizer alone.
# Pixels per triangle. The largest have edges beyond TS_SW_MAX_EDGE_PIXELS and go to hardware raster whatever is asked
# (their SW share tells); up to 2048 px so that a device whose compute rasterizer wins at 256 still finds its crossover.
RASTER_AREAS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048)
RASTER_COLUMNS = [("area_px", "px per triangle"), ("triangles", "triangles"), ("software_share", "SW share"),
                  ("software_ms", "SW GPU ms"), ("hardware_ms", "HW GPU ms"), ("faster", "faster")]


def _write_grid_stage(path, width: int, height: int, area: float):
    """A flat grid facing the camera, filling the frame, of triangles covering about `area` pixels each."""
    from pxr import Gf, Usd, UsdGeom, Vt

    distance, focal, vertical = 10.0, 50.0, 24.0
    visible_height = vertical / focal * distance
    pixels_per_unit = height / visible_height
    side = np.sqrt(2.0 * area) / pixels_per_unit  # two triangles per square
    nx, ny = int(np.ceil(visible_height * width / height / side)) + 1, int(np.ceil(visible_height / side)) + 1
    x = (np.arange(nx + 1) - nx / 2) * side
    y = (np.arange(ny + 1) - ny / 2) * side
    px, py = np.meshgrid(x, y, indexing="xy")
    points = np.stack([px.ravel(), py.ravel(), np.zeros(px.size)], 1).astype(np.float32)
    i, j = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    a = (i * (nx + 1) + j).ravel()
    quads = np.stack([a, a + 1, a + nx + 2, a + nx + 1], 1).astype(np.int32)
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Grid")
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(quads.ravel()))
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.GetFocalLengthAttr().Set(focal)
    camera.GetVerticalApertureAttr().Set(vertical)
    camera.GetHorizontalApertureAttr().Set(vertical * width / height)
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, distance))
    stage.GetRootLayer().Save()


def _raster_case(queue, stages, resolution, frames, device):
    """Runs in a child process (a fresh Vulkan device): each grid through each rasterizer alone, every source
    triangle (lod off, so the cut cannot merge the flat grid into a few large triangles)."""
    try:
        from tessera import Session

        rows = []
        for area, stage in stages:
            session = Session(stage, device=device)
            timings = {}
            for raster in ("software", "hardware"):
                settings = {"camera": "/Camera", "resolution": resolution, "lod": False, "raster": raster}
                session.render(**settings)
                totals = []
                for _ in range(frames):
                    result = session.render(**settings)
                    totals.append(sum(result.stats["gpu_ms"].values()))
                timings[raster] = (float(np.median(totals)), result.stats)
            software_ms, software_stats = timings["software"]
            hardware_ms, _ = timings["hardware"]
            rows.append({"area_px": area, "triangles": software_stats["visible_triangles"],
                         "software_share": round(software_stats["sw_triangles"] / max(software_stats["visible_triangles"], 1), 3),
                         "software_ms": round(software_ms, 1), "hardware_ms": round(hardware_ms, 1),
                         "faster": "software" if software_ms < hardware_ms else "hardware", "device": session.device_name,
                         "device_key": raster_split.device_key(session.delegate.device_name, session.delegate.software_device),
                         "cache_directory": session.delegate.cache_directory, "resolution": f"{resolution[0]}x{resolution[1]}"})
        queue.put(rows)
    except Exception as error:  # reported by the parent
        queue.put(error)


def raster(args) -> int:
    """The triangle size below which the compute rasterizer beats hardware raster on this device (RenderSettings::
    softwareRasterArea, 256 px by default, was measured this way on lavapipe and an H100); `--record` keeps it for the
    device's sessions (tessera.raster_split)."""
    from pathlib import Path

    width, height = args.resolution
    stages = []
    for area in RASTER_AREAS:
        path = Path(args.stages_dir) / f"raster_grid_{width}x{height}_{area}px.usdc"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            temporary = path.with_suffix(".tmp.usdc")
            _write_grid_stage(temporary, width, height, area)
            temporary.rename(path)
        stages.append((area, str(path)))
    outcome = _in_child(_raster_case, stages, (width, height), args.frames, args.device)
    if isinstance(outcome, Exception):
        print(f"tessera: error: {outcome}", flush=True)
        return 1
    print(" | ".join(title for _, title in RASTER_COLUMNS))
    for row in outcome:
        print(" | ".join(str(row[key]) for key, _ in RASTER_COLUMNS))
    # Only sizes the compute rasterizer really drew count: past them its triangles' edges outgrow TS_SW_MAX_EDGE_PIXELS
    # and go to hardware raster even when software is asked for.
    print(f"device: {outcome[0]['device']}, {outcome[0]['resolution']}, median of {args.frames} frames after one warm-up")
    split = raster_split.crossover(outcome)
    if split is None:
        print(f"crossover: not measured (the compute rasterizer drew less than {raster_split.MIN_SOFTWARE_SHARE:.0%} at every size)")
    else:
        print(f"crossover: {split:g} px per triangle (the default is {raster_split.DEFAULT_AREA:g})")
        if args.record:
            path = raster_split.record(outcome[0]["cache_directory"], outcome[0]["device_key"], split, outcome)
            print(f"recorded for {outcome[0]['device_key']} in {path}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(outcome, f, indent=2)
    return 0


# ---------------------------------------------------------------------------------------------------------------
# tessera bench usd: translating a stage into the render index (populate, first sync, commit), its memory, and
# re-syncing one edited transform.

def _write_usd_stage(path, case: str, count: int):
    """`count` cubes (12 triangles) on a grid: each its own Mesh prim under its own Xform, all the same shape
    ("prims") or each a little larger than the one before ("distinct": every mesh its own build), or native
    instances of one Xform holding the cube ("instances"). Written through Sdf in one change block (fast)."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    layer = Sdf.Layer.CreateNew(str(path))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    points = Vt.Vec3fArray([(x, y, z) for z in (-0.4, 0.4) for y in (-0.4, 0.4) for x in (-0.4, 0.4)])
    counts = Vt.IntArray([4] * 6)
    indices = Vt.IntArray([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
    side = int(np.ceil(np.sqrt(count)))
    with Sdf.ChangeBlock():
        def mesh_spec(parent, scale=1.0):
            mesh = Sdf.PrimSpec(parent, "Cube", Sdf.SpecifierDef, "Mesh")
            Sdf.AttributeSpec(mesh, "points", Sdf.ValueTypeNames.Point3fArray).default = points if scale == 1.0 else \
                Vt.Vec3fArray([p * scale for p in points])
            Sdf.AttributeSpec(mesh, "faceVertexCounts", Sdf.ValueTypeNames.IntArray).default = counts
            Sdf.AttributeSpec(mesh, "faceVertexIndices", Sdf.ValueTypeNames.IntArray).default = indices
            Sdf.AttributeSpec(mesh, "subdivisionScheme", Sdf.ValueTypeNames.Token, variability=Sdf.VariabilityUniform).default = "none"

        world = Sdf.PrimSpec(layer, "World", Sdf.SpecifierDef, "Xform")
        if case == "instances":
            assets = Sdf.PrimSpec(layer, "Assets", Sdf.SpecifierClass, "Xform")
            mesh_spec(Sdf.PrimSpec(assets, "Block", Sdf.SpecifierDef, "Xform"))
        for i in range(count):
            item = Sdf.PrimSpec(world, f"Item{i}", Sdf.SpecifierDef, "Xform")
            Sdf.AttributeSpec(item, "xformOp:translate", Sdf.ValueTypeNames.Double3).default = (2.0 * (i % side), 2.0 * (i // side), 0.0)
            Sdf.AttributeSpec(item, "xformOpOrder", Sdf.ValueTypeNames.TokenArray, variability=Sdf.VariabilityUniform).default = \
                Vt.TokenArray(["xformOp:translate"])
            if case == "instances":
                item.referenceList.Prepend(Sdf.Reference("", "/Assets/Block"))
                item.instanceable = True
            else:
                mesh_spec(item, 1.0 + 1e-5 * i if case == "distinct" else 1.0)
    layer.Save()


def _resident_bytes() -> int:
    """Resident memory as it is: what the process holds, its allocator's free memory included."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def _rss_bytes() -> int:
    """Resident memory, after handing freed heap back to the system (so that it counts what is held)."""
    import ctypes
    import gc

    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def _usd_case(queue, case, stage_path, count, edits, device):
    """Runs in a child process, so that its memory is its own. The session's parts are made here one by one so
    that the device's memory is measured apart from the translation's."""
    try:
        from pathlib import Path

        from pxr import Gf, Usd

        from tessera import _tessera
        from tessera.usd import ChangeTracker, UsdSceneDelegate

        started = time.perf_counter()
        stage = Usd.Stage.Open(stage_path)
        opened = time.perf_counter()
        delegate = _tessera.RenderDelegate(device=device)
        # A small stage of the same kind through its own index first: code and USD caches the first use loads
        # are then not counted as this stage's translation.
        warm_path = str(Path(stage_path).with_suffix(".warmup.usdc"))
        if not Path(warm_path).exists():
            _write_usd_stage(warm_path, case, 4)
        warm_index = _tessera.RenderIndex(delegate)
        warm = UsdSceneDelegate(Usd.Stage.Open(warm_path), warm_index)
        warm.populate()
        warm_index.sync_all(warm)
        del warm, warm_index
        index = _tessera.RenderIndex(delegate)
        before_rss = _rss_bytes()
        translating, translating_cpu = time.perf_counter(), time.process_time()
        scene = UsdSceneDelegate(stage, index)
        scene.populate()
        populated = time.perf_counter()
        index.sync_all(scene)  # every mesh built, loaded from the cache or shared, then committed
        synced, synced_cpu = time.perf_counter(), time.process_time()
        translated_rss = _rss_bytes()
        diagnostics = index.take_diagnostics()
        # One transform edited, then re-synced (notice -> dirty bits -> sync -> commit), `edits` times.
        changes = ChangeTracker(stage)
        target = stage.GetPrimAtPath("/World/Item0").GetAttribute("xformOp:translate")
        times, synced_counts = [], []
        for k in range(edits):
            target.Set(Gf.Vec3d(0.0, 0.0, 0.1 * (k + 1)))
            edit_started = time.perf_counter()
            scene.apply_changes(*changes.take())
            index.sync_all(scene)
            times.append(time.perf_counter() - edit_started)
            synced_counts.append(len(index.last_synced))
        queue.put({
            "case": f"{count:,} " + {"prims": "mesh prims, one shape", "distinct": "mesh prims, distinct",
                                     "instances": "native instances"}[case],
            "prims_on_stage": count,
            "rprims": index.rprim_count,
            "meshes_built": diagnostics["meshes_built"],
            "meshes_cached": diagnostics["meshes_cached"],
            "meshes_shared": diagnostics["meshes_shared"],
            "open_seconds": round(opened - started, 2),
            "populate_seconds": round(populated - translating, 2),
            "first_sync_seconds": round(synced - populated, 2),
            "translate_seconds": round(synced - translating, 2),
            "translate_cpu_seconds": round(synced_cpu - translating_cpu, 2),  # this process's own, whatever else runs
            "translate_memory_mib": round((translated_rss - before_rss) / 2**20, 1),
            "translate_bytes_per_prim": round((translated_rss - before_rss) / count),
            "edit_resync_ms": round(1000 * float(np.median(times)), 2),
            "edit_resynced_prims": max(synced_counts),
            "device": delegate.device_name,
        })
    except Exception as error:  # reported by the parent, which goes on with the other cases
        queue.put(error)


def _write_point_instancer_stage(path, count: int, n: int):
    """One PointInstancer of `count` instances of a displaced sphere of 4 n^2 triangles, scattered over a square
    field (jittered grid, 4 units apart) with random orientations (quath, USD's usual type) and scales, and a camera
    looking across a corner of the field with a 300-unit far clip. The arrays go to USD straight from numpy."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    rng = np.random.default_rng(5)
    side = int(np.ceil(np.sqrt(count)))
    index = np.arange(count)
    positions = np.stack([4.0 * (index % side), np.zeros(count), 4.0 * (index // side)], -1) + rng.uniform(-1, 1, (count, 3)) * [1, 0, 1]
    orientations = rng.normal(size=(count, 4))
    orientations /= np.linalg.norm(orientations, axis=1, keepdims=True)
    scales = rng.uniform(0.6, 1.4, (count, 1)) * rng.uniform(0.8, 1.2, (count, 3))
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Field")
    rock = UsdGeom.Mesh.Define(stage, "/World/Field/Prototypes/Rock")
    points, counts, indices = displaced_sphere(n)
    rock.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.reshape(-1, 3)))
    rock.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts))
    rock.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices))
    rock.CreateSubdivisionSchemeAttr("none")
    instancer.CreatePrototypesRel().SetTargets([rock.GetPath()])
    instancer.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(count, np.int32)))
    instancer.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(positions.astype(np.float32)))
    instancer.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(orientations.astype(np.float16)))
    instancer.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(scales.astype(np.float32)))
    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.CreateClippingRangeAttr(Gf.Vec2f(0.5, 300.0))
    camera.CreateFocalLengthAttr(24.0)
    eye = Gf.Vec3d(-20.0, 25.0, -20.0)
    look = Gf.Matrix4d().SetLookAt(eye, Gf.Vec3d(60.0, 0.0, 60.0), Gf.Vec3d(0, 1, 0)).GetInverse()
    camera.AddTransformOp().Set(look)
    stage.GetRootLayer().Save()


def _rss_parts() -> tuple[int, int]:
    """(anonymous, file-backed) resident bytes, after handing freed heap back to the system."""
    import ctypes
    import gc

    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    parts = {}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(("RssAnon:", "RssFile:", "RssShmem:")):
                name, value, _ = line.split()
                parts[name] = int(value) * 1024
    return parts["RssAnon:"] + parts.get("RssShmem:", 0), parts["RssFile:"]


def _point_instancer_case(queue, stage_path, warm_path, count, resolution, device):
    """Runs in a child process: opens the stage, translates it (populate, sync, commit) and renders two frames."""
    try:
        from pxr import Usd

        from tessera import _tessera
        from tessera.usd import UsdSceneDelegate

        delegate = _tessera.RenderDelegate(device=device)
        # The small stage first: the prototype is built into the cache there (its build is reported apart), and code
        # and USD caches the first use loads are not counted as this stage's.
        warm_started = time.perf_counter()
        warm_index = _tessera.RenderIndex(delegate)
        warm = UsdSceneDelegate(Usd.Stage.Open(warm_path), warm_index)
        warm.populate()
        warm_index.sync_all(warm)
        warm_seconds = time.perf_counter() - warm_started
        warm_built = warm_index.take_diagnostics()["meshes_built"]
        del warm, warm_index
        anon_before, file_before = _rss_parts()
        started, started_cpu = time.perf_counter(), time.process_time()
        stage = Usd.Stage.Open(stage_path)
        opened = time.perf_counter()
        index = _tessera.RenderIndex(delegate)
        scene = UsdSceneDelegate(stage, index)
        scene.populate()
        populated = time.perf_counter()
        index.sync_all(scene)
        synced, synced_cpu = time.perf_counter(), time.process_time()
        anon_translated, file_translated = _rss_parts()
        frames = []
        for _ in range(2):  # the first frame uploads and culls by the frustum; the second has its HZB too
            frame_started = time.perf_counter()
            images, stats = index.execute("/World/Camera", _tessera.CameraDesc(), resolution[0], resolution[1], ["color"], (0, 0, 0, 0))
            frames.append((time.perf_counter() - frame_started, stats))
        anon_rendered, file_rendered = _rss_parts()
        first, second = frames[0][1], frames[1][1]
        upload = first["upload_ms"] / 1000
        queue.put({
            "case": f"{count:,} point instances of a {first['source_triangles'] // max(first['instances'], 1):,}-triangle prototype",
            "instances": first["instances"],
            "batches": first["instance_batches"],
            "prototype_build_seconds": round(warm_seconds, 2) if warm_built else None,
            "open_seconds": round(opened - started, 2),
            "populate_seconds": round(populated - opened, 2),
            "sync_seconds": round(synced - populated, 2),
            "upload_seconds": round(upload, 2),
            "load_seconds": round(synced - started + upload, 2),
            "translate_cpu_seconds": round(synced_cpu - started_cpu, 2),
            "cpu_bytes_per_instance": round((anon_translated - anon_before) / count, 1),
            "usd_file_bytes_per_instance": round((file_translated - file_before) / count, 1),
            "gpu_bytes_per_instance": round(first["instance_bytes"] / max(first["instances"], 1), 1),
            "process_bytes_per_instance": round((anon_rendered + file_rendered - anon_before - file_before) / count, 1),
            "first_frame_seconds": round(frames[0][0], 2),
            "second_frame_seconds": round(frames[1][0], 2),
            "cull_ms": [round(f[1]["gpu_ms"]["cull"], 1) for f in frames],
            "visible_instances": [f[1]["visible_instances"] for f in frames],
            "occluded_instances": second["occluded_instances"],
            "visible_clusters": [f[1]["visible_clusters"] for f in frames],
            "resolution": f"{resolution[0]}x{resolution[1]}",
            "device": delegate.device_name,
        })
    except Exception as error:  # reported by the parent
        queue.put(error)


POINT_INSTANCER_COLUMNS = [("case", "case"), ("instances", "instances"), ("open_seconds", "open s"), ("populate_seconds", "populate s"),
                           ("sync_seconds", "sync s"), ("upload_seconds", "upload s"), ("load_seconds", "load s"),
                           ("cpu_bytes_per_instance", "CPU B/inst"), ("usd_file_bytes_per_instance", "USD file-backed B/inst"),
                           ("gpu_bytes_per_instance", "GPU B/inst"), ("process_bytes_per_instance", "process B/inst after a frame"),
                           ("first_frame_seconds", "frame 1 s"), ("second_frame_seconds", "frame 2 s"), ("cull_ms", "cull ms"),
                           ("visible_instances", "visible inst"), ("occluded_instances", "occluded inst (frame 2)"),
                           ("visible_clusters", "visible clusters")]


USD_COLUMNS = [("case", "case"), ("rprims", "rprims"), ("meshes_built", "built"), ("meshes_cached", "cached"),
               ("meshes_shared", "shared"), ("open_seconds", "open s"),
               ("populate_seconds", "populate s"), ("first_sync_seconds", "first sync s"), ("translate_seconds", "translate s"),
               ("translate_cpu_seconds", "translate CPU s"), ("translate_memory_mib", "translate MiB"), ("translate_bytes_per_prim", "B/prim"),
               ("edit_resync_ms", "edit re-sync ms"), ("edit_resynced_prims", "prims re-synced")]


def usd(args) -> int:
    """Translate time and memory of big stages, and one transform edit re-synced (median of --edits)."""
    from pathlib import Path

    directory = Path(args.stages_dir)
    directory.mkdir(parents=True, exist_ok=True)
    rows = []
    print(" | ".join(title for _, title in USD_COLUMNS))
    for case, count in (("prims", args.prims), ("distinct", args.prims), ("instances", args.instances)):
        if count <= 0:
            continue
        stage = directory / f"usd_{case}_{count}.usdc"
        if not stage.exists():
            _write_usd_stage(stage, case, count)
        row = _in_child(_usd_case, case, str(stage), count, args.edits, args.device)
        if isinstance(row, Exception):
            print(f"tessera: error: {case}: {row}")
            continue
        rows.append(row)
        print(" | ".join(str(row[key]) for key, _ in USD_COLUMNS), flush=True)
    if args.point_instances:
        n = max(1, int(round(np.sqrt(args.prototype_triangles / 4))))
        stage = directory / f"usd_point_instancer_{args.point_instances}_{n}.usdc"
        warm = directory / f"usd_point_instancer_4_{n}.usdc"
        for path, count in ((stage, args.point_instances), (warm, 4)):
            if not path.exists():
                _write_point_instancer_stage(path, count, n)
        row = _in_child(_point_instancer_case, str(stage), str(warm), args.point_instances, (640, 360), args.device)
        if isinstance(row, Exception):
            print(f"tessera: error: point instancer: {row}")
        else:
            rows.append(row)
            print()
            print(" | ".join(title for _, title in POINT_INSTANCER_COLUMNS))
            print(" | ".join(str(row[key]) for key, _ in POINT_INSTANCER_COLUMNS), flush=True)
            if row["prototype_build_seconds"] is not None:
                print(f"(the prototype was built first, in {row['prototype_build_seconds']} s, with the 4-instance stage)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0
