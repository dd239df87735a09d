"""tessera.build_mesh's per-mesh settings (Nanite's): trimming, the fallback mesh, Preserve Area, validation, and
render-wide defaults through tessera.Session."""

import os
import subprocess
import sys

import numpy as np
import pytest

import tessera
from conftest import TESTENV
from tessera.bench import displaced_sphere, displaced_sphere_deviation, lat_long_uvs


def card_field(count, seed=3):
    """Disjoint square cards facing +z (foliage seen from above)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 10, (count, 3)) * [1, 1, 0.1]
    turn = rng.uniform(0, np.pi / 2, count)
    axis_u = np.stack([np.cos(turn), np.sin(turn), 0 * turn], -1) * 0.04
    axis_v = np.stack([-np.sin(turn), np.cos(turn), 0 * turn], -1) * 0.04
    corners = np.stack([centres - axis_u - axis_v, centres + axis_u - axis_v, centres + axis_u + axis_v, centres - axis_u + axis_v], 1)
    return corners.reshape(-1, 3), np.full(count, 4), np.arange(4 * count)


def area_along_z(fallback):
    p = fallback["positions"][fallback["indices"]]  # (M, 3 corners, xyz)
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum()


def test_defaults_are_nanites_and_the_fallback_comes_back():
    stats = tessera.build_mesh(*displaced_sphere(60))
    assert stats["settings"] == {"position_precision": None, "preserve_area": False, "trim_relative_error": 0.0,
                                 "keep_triangle_percent": 100.0, "fallback_relative_error": 1.0,
                                 "fallback_triangle_percent": 100.0, "max_edge_length_factor": 0.0}
    assert stats["leaf_triangles"] == stats["source_triangles"] and stats["leaf_error"] == 0.0
    fallback = stats["fallback"]
    positions, normals, indices = fallback["positions"], fallback["normals"], fallback["indices"]
    assert positions.dtype == np.float32 and positions.shape[1] == 3 and normals.shape == positions.shape
    assert indices.dtype == np.uint32 and indices.shape == (fallback["triangles"], 3) and indices.max() < len(positions)
    assert fallback["colors"] is None and fallback["uvs"] is None and fallback["material_slots"] is None, "none authored"
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-3)
    assert fallback["relative_error"] >= 0.01, "the first cut at 1 % of the mesh size"
    assert fallback["triangles"] < stats["source_triangles"]
    assert np.abs(np.linalg.norm(positions, axis=1) - 1).max() < 0.1, "object space: on the unit sphere, give or take its bumps"


def test_texture_coordinates_come_through_build_mesh():
    points, counts, indices = displaced_sphere(60)
    plain = tessera.build_mesh(points, counts, indices)
    stats = tessera.build_mesh(points, counts, indices, "/Sphere", uvs=lat_long_uvs(60))
    assert stats["warnings"] == []
    uvs, positions = stats["fallback"]["uvs"], stats["fallback"]["positions"]
    assert uvs is not None and uvs.shape == (len(positions), 2)
    assert uvs.min() >= 0 and uvs.max() <= 1
    # Each fallback vertex keeps its place on the chart: v follows the polar angle (the bumps move points radially only).
    polar = np.arccos(np.clip(positions[:, 2] / np.linalg.norm(positions, axis=1), -1, 1)) / np.pi
    assert np.abs(uvs[:, 1] - polar).max() < 0.02
    # The wrap seam splits vertices there: u = 0 and u = 1 both occur, and the pages hold the coordinates.
    assert (uvs[:, 0] < 1e-6).any() and (uvs[:, 0] > 1 - 1e-6).any()
    assert stats["disk_bytes"] > plain["disk_bytes"]
    # Per point, too; a wrong count is a warning naming the mesh, and the mesh builds without them.
    per_point = tessera.build_mesh(points, counts, indices, "/Sphere", uvs=points.reshape(-1, 3)[:, :2] * 0.5 + 0.5, uv_interpolation="vertex")
    assert per_point["warnings"] == [] and per_point["fallback"]["uvs"] is not None
    short = tessera.build_mesh(points, counts, indices, "/Sphere", uvs=np.zeros((10, 2)))
    assert short["warnings"] == ["/Sphere: texture coordinates has 10 elements but its interpolation needs 28800; ignored"]
    assert short["fallback"]["uvs"] is None
    with pytest.raises(ValueError, match="uv_interpolation 'perCorner'"):
        tessera.build_mesh(points, counts, indices, uvs=lat_long_uvs(60), uv_interpolation="perCorner")


def test_the_fallbacks_error_bound_holds_against_the_surface():
    # The measure first: the plain unit sphere lies at most the bumps' 0.05 from the displaced surface.
    points, counts, indices = displaced_sphere(100)
    quads = indices.reshape(-1, 4)
    source = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    unit = points.reshape(-1, 3) / np.linalg.norm(points.reshape(-1, 3), axis=1, keepdims=True)
    largest, mean = displaced_sphere_deviation(unit, source)
    assert 0.045 < largest <= 0.052 and 0.01 < mean < 0.03  # 0.05 and the chords' sagitta (1e-3)
    own, _ = displaced_sphere_deviation(points.reshape(-1, 3), source)
    assert own < 0.006, "the source mesh itself: chords of a 40 k-triangle sphere"
    # A cut lies within its bound of the source, and the source within `own` of the surface.
    fallback = tessera.build_mesh(points, counts, indices)["fallback"]
    measured, measured_mean = displaced_sphere_deviation(fallback["positions"], fallback["indices"])
    assert 0 < measured_mean < measured <= fallback["error"] + own


def test_keep_triangle_percent_and_trim_relative_error_store_less():
    source = displaced_sphere(60)
    full = tessera.build_mesh(*source)
    kept = tessera.build_mesh(*source, keep_triangle_percent=25)
    assert kept["source_triangles"] == full["source_triangles"]
    assert kept["levels"][0]["triangles"] == kept["leaf_triangles"] <= 0.25 * full["source_triangles"]
    assert kept["levels"][0]["max_error"] == 0.0 and kept["leaf_error"] > 0
    trimmed = tessera.build_mesh(*source, trim_relative_error=0.5)
    assert trimmed["leaf_error"] >= 0.005 * trimmed["size"]
    assert trimmed["leaf_triangles"] < full["leaf_triangles"]


def test_preserve_area_keeps_a_card_field_covered():
    cards = card_field(3000)
    coarse = dict(fallback_relative_error=0.0, fallback_triangle_percent=10)  # the fallback: a cut at a tenth
    source = area_along_z(tessera.build_mesh(*cards, fallback_triangle_percent=100, fallback_relative_error=0)["fallback"])
    assert source == pytest.approx(3000 * 0.08 ** 2, rel=1e-3)
    kept = area_along_z(tessera.build_mesh(*cards, preserve_area=True, **coarse)["fallback"])
    lost = area_along_z(tessera.build_mesh(*cards, **coarse)["fallback"])
    assert kept == pytest.approx(source, rel=0.02)
    assert lost < 0.5 * source


def test_bad_settings_raise_and_name_the_keyword():
    source = displaced_sphere(8)
    for keyword, value in [("keep_triangle_percent", -1), ("fallback_triangle_percent", 101), ("trim_relative_error", float("nan")),
                           ("fallback_relative_error", float("inf")), ("max_edge_length_factor", -0.5), ("position_precision", 99)]:
        with pytest.raises(ValueError, match=keyword):
            tessera.build_mesh(*source, **{keyword: value})
    with pytest.raises(TypeError):
        tessera.build_mesh(*source, keep_percent=50)
    assert tessera.build_mesh(*source, position_precision=-8)["position_precision"] == -8


def test_session_applies_build_settings_to_every_mesh():
    session = tessera.Session(TESTENV / "testCube" / "cube.usda", build_settings={"keep_triangle_percent": 50, "preserve_area": True})
    for prim_id in session.scene.rprims:
        settings = session.scene.get_mesh(prim_id).settings.as_dict()
        assert settings["keep_triangle_percent"] == 50 and settings["preserve_area"]
    with pytest.raises(ValueError, match="keep_triangle_percent"):
        tessera.Session(TESTENV / "testCube" / "cube.usda", build_settings={"keep_triangle_percent": 500})


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two cores to give a process fewer")
def test_threads_follow_the_processs_cpu_affinity():
    """A farm slot pinned to some of a machine's cores (taskset, a cpuset) starts a thread per core it may use, not
    one per core of the machine."""
    first = min(os.sched_getaffinity(0))
    count = "from tessera import _tessera; print(_tessera.core_count())"
    pinned = subprocess.run([sys.executable, "-c", count], capture_output=True, text=True, check=True,
                            preexec_fn=lambda: os.sched_setaffinity(0, {first}))
    assert pinned.stdout.strip() == "1"
    free = subprocess.run([sys.executable, "-c", count], capture_output=True, text=True, check=True)
    assert free.stdout.strip() == str(len(os.sched_getaffinity(0)))
