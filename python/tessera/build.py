"""Building one mesh's cluster DAG from Python, with the per-mesh build settings (Nanite's, same defaults)."""

from __future__ import annotations

import numpy as np

from . import _tessera

BuildSettings = _tessera.BuildSettings


def build_mesh(points, face_vertex_counts, face_vertex_indices, name: str = "mesh", *,
               uvs=None,
               uv_interpolation: str = "faceVarying",
               preserve_area: bool = False,
               trim_relative_error: float = 0.0,
               keep_triangle_percent: float = 100.0,
               position_precision: int | None = None,
               fallback_relative_error: float = 1.0,
               fallback_triangle_percent: float = 100.0,
               max_edge_length_factor: float = 0.0) -> dict:
    """Prepares a polygon mesh (USD's points, faceVertexCounts, faceVertexIndices) and builds its cluster DAG.

    ``uvs``: texture coordinates (primvars:st), an (N, 2) array with one row per element of ``uv_interpolation``
    (USD's: "faceVarying", one per face vertex, by default; "vertex", one per point; "uniform", one per face;
    "constant"), or None. They are simplified with the mesh (seams kept) and stored in its pages.

    Settings (Nanite's names and defaults; relative errors are in percent of the mesh size, its bounding-box diagonal):

    - ``preserve_area`` (False): dilate open borders as levels simplify, so foliage (cards, quad soups) keeps its
      area instead of thinning out with distance.
    - ``trim_relative_error`` (0) and ``keep_triangle_percent`` (100): store less detail. The leaf level becomes the
      first DAG cut, fine to coarse, whose error is at least ``trim_relative_error`` percent of the size and whose
      triangles are at most ``keep_triangle_percent`` percent of the source.
    - ``position_precision`` (None: automatic): log2 of the position grid step in object space, -64 to 64.
    - ``fallback_relative_error`` (1) and ``fallback_triangle_percent`` (100): the fallback mesh, the first cut by
      the same rule (never finer than the stored leaves).
    - ``max_edge_length_factor`` (0: off): simplification makes no edge longer than this times the source's mean
      edge length.

    A bad value raises ValueError naming the setting. Returns the DAG's statistics: ``levels`` (clusters,
    triangles, max_error and relative_error, a fraction of the size, per level), ``leaf_triangles`` and
    ``leaf_error`` (what trimming kept, and its error), ``fallback`` (``positions`` and ``normals`` as (N, 3)
    float32 in object space, ``indices`` as (M, 3) uint32, ``colors`` (N, 4), ``uvs`` (N, 2) and ``material_slots``
    (M, 1) where the mesh has them (else None), ``triangles``, ``error``, ``relative_error``),
    ``settings``, bytes in memory and on disk, and the mesh's ``warnings``.
    """
    points = np.ascontiguousarray(points, dtype=np.float32).reshape(-1)
    counts = np.ascontiguousarray(face_vertex_counts, dtype=np.int32).reshape(-1)
    indices = np.ascontiguousarray(face_vertex_indices, dtype=np.int32).reshape(-1)
    if uvs is not None:
        uvs = np.ascontiguousarray(uvs, dtype=np.float32).reshape(-1)
    return _tessera.build_mesh(points, counts, indices, name, uvs, uv_interpolation, preserve_area=preserve_area,
                               trim_relative_error=trim_relative_error, keep_triangle_percent=keep_triangle_percent,
                               position_precision=position_precision, fallback_relative_error=fallback_relative_error,
                               fallback_triangle_percent=fallback_triangle_percent,
                               max_edge_length_factor=max_edge_length_factor)
