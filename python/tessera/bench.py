"""`tessera bench ...`: benchmarks that print tables of speed, memory and error (never timed tests).

    tessera bench build [STAGE.usd | MESH.obj ...] [--json FILE]

Each mesh is built in a child process so that its peak memory is its own (the input arrays excluded).
"""

from __future__ import annotations

import json
import multiprocessing
import resource
import time

import numpy as np


def displaced_sphere(n: int):
    """A closed sphere of 4 n^2 triangles with a few octaves of bumps: a stand-in for a dense scan."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, 2 * n, endpoint=False), indexing="ij")
    r = 1.0 + 0.04 * np.sin(9 * theta) * np.cos(13 * phi) + 0.01 * np.sin(41 * theta + 3) * np.cos(37 * phi)
    points = np.stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi), r * np.cos(theta)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a, b = i * 2 * n + j, i * 2 * n + (j + 1) % (2 * n)
    quads = np.stack([a, a + 2 * n, b + 2 * n, b], -1).reshape(-1, 4).astype(np.int32)
    return points.astype(np.float32).reshape(-1), np.full(len(quads), 4, np.int32), quads.reshape(-1)


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


def _build_one(arrays, queue):
    from tessera import _tessera

    points, counts, indices = arrays
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    stats = _tessera.build_mesh(points, counts, indices)  # includes encoding the pages
    seconds = time.perf_counter() - start
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    queue.put((stats, seconds, (peak_kib - before) * 1024, peak_kib * 1024))


def _measure(name, make):
    # The input is made here, before the fork, so that the child's peak memory is the build's alone.
    arrays = make()
    queue = multiprocessing.get_context("fork").Queue()
    process = multiprocessing.get_context("fork").Process(target=_build_one, args=(arrays, queue))
    process.start()
    stats, seconds, build_peak, process_peak = queue.get()
    process.join()
    del arrays
    levels = stats["levels"]
    source = stats["source_triangles"]
    return {
        "mesh": name,
        "input_triangles": source,
        "build_seconds": round(seconds, 3),
        "input_triangles_per_second": round(source / seconds),
        "peak_memory_bytes_per_input_triangle": round(build_peak / max(source, 1), 1),
        "process_peak_mib": round(process_peak / 2**20, 1),
        "in_memory_bytes_per_input_triangle": round(stats["memory_bytes"] / max(source, 1), 1),
        "disk_bytes_per_input_triangle": round(stats["disk_bytes"] / max(source, 1), 2),
        "pages": stats["pages"],
        "dag_depth": len(levels),
        "clusters": stats["clusters"],
        "groups": stats["groups"],
        "root_triangles": stats["root_triangles"],
        "mean_triangles_per_cluster_level0": round(levels[0]["triangles"] / max(levels[0]["clusters"], 1), 1),
        "relative_error_per_level": [float(f"{level['relative_error']:.3g}") for level in levels],
    }


def default_meshes():
    from pathlib import Path

    # The shared test assets sit beside the project: found from the working directory (the project root).
    meshes = []
    for root in (Path.cwd() / ".." / "shared", Path.cwd() / "shared"):
        bunny = root / "assets" / "meshes" / "stanford-bunny.obj"
        if bunny.exists():
            meshes.append(("stanford-bunny (69k)", lambda b=bunny: obj_mesh(str(b))))
            break
    meshes.append(("displaced sphere 1M", lambda: displaced_sphere(500)))
    meshes.append(("displaced sphere 10M", lambda: displaced_sphere(1581)))
    return meshes


COLUMNS = [("mesh", "mesh"), ("input_triangles", "input tris"), ("build_seconds", "build s"), ("input_triangles_per_second", "tris/s"),
           ("peak_memory_bytes_per_input_triangle", "peak B/tri"), ("disk_bytes_per_input_triangle", "disk B/tri"),
           ("dag_depth", "depth"), ("root_triangles", "root tris"), ("mean_triangles_per_cluster_level0", "tris/cluster L0")]


def build(args) -> int:
    meshes = []
    for path in args.stages:
        if path.endswith(".obj"):
            meshes.append((path, lambda p=path: obj_mesh(p)))
        else:
            meshes.extend(stage_meshes(path))
    if not args.stages:
        meshes = default_meshes()
    rows = []
    print(" | ".join(title for _, title in COLUMNS) + " | relative error per level")
    for name, make in meshes:
        row = _measure(name, make)
        rows.append(row)
        print(" | ".join(str(row[key]) for key, _ in COLUMNS) + " | " + " ".join(f"{e:.2g}" for e in row["relative_error_per_level"]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0
