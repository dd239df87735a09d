"""Subdivision surfaces as Hydra draws them: the refine level from the `complexity` render setting (usdview's default
1.0 draws the control cage), and UsdGeomMesh's subdivision tags read from the stage. The builder's handling of each
tag is tested in C++ (testenv/cpp/test_builder.cpp, SubdivisionTags)."""

import subprocess
import sys

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, Vt

import tessera
from tessera.usd import subdivision

NO_HIT = 0xFFFFFFFF
CUBE_POINTS = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)]
CUBE_INDICES = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]
CUBE_EDGES = [(0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 6), (1, 7), (2, 4), (3, 5)]


def _cube(stage, path, x, scheme=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(px + x, py, pz) for px, py, pz in CUBE_POINTS])
    mesh.GetFaceVertexCountsAttr().Set([4] * 6)
    mesh.GetFaceVertexIndicesAttr().Set(CUBE_INDICES)
    if scheme:
        mesh.GetSubdivisionSchemeAttr().Set(scheme)
    return mesh


def _stage():
    """Seen from +Z: a cube that authors no subdivisionScheme (USD's fallback, catmullClark) on the left, one
    authored `none` on the right, and an implicit Cube (never subdivided) in the middle."""
    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 20))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(20.0)
    _cube(stage, "/World/Smooth", -4)
    _cube(stage, "/World/Polygons", 4, scheme="none")
    UsdGeom.Cube.Define(stage, "/World/Box").GetSizeAttr().Set(1.0)
    return stage


def _render(session, **kwargs):
    result = session.render(camera="/Camera", resolution=(200, 100), aovs=("primId",), **kwargs)
    assert not result.errors, "\n".join(result.errors)
    return result


def _covered(result, path):
    ids = np.asarray(result["primId"].ids())
    return int(sum(((ids == i) & (ids != NO_HIT)).sum() for i in np.unique(ids) if i != NO_HIT and result.prim_path(int(i)) == path))


def test_complexity_maps_to_refine_levels_as_hydra_does():
    assert [subdivision.refine_level(c) for c in subdivision.USDVIEW_COMPLEXITIES] == [0, 1, 2, 3]
    assert [subdivision.refine_level(c) for c in (1.05, 1.19, 1.29, 1.4, 1.8, 2.0, 3.0)] == [0, 2, 3, 4, 8, 8, 8]
    for bad in (0.99, 0.0, float("nan")):
        with pytest.raises(ValueError, match="complexity"):
            subdivision.refine_level(bad)
    with pytest.raises(tessera.StageError, match="complexity"):
        tessera.Session(_stage(), complexity=0.5)


def test_default_complexity_draws_the_control_cage():
    session = tessera.Session(_stage(), validation=True)
    result = _render(session)
    assert result.stats["complexity"] == 1.0 and result.stats["refine_level"] == 0
    assert result.stats["source_triangles"] == 12 + 12 + 12, "three cubes of 12 triangles: nothing refined"


def test_a_new_complexity_resyncs_only_meshes_with_a_subdivision_scheme():
    session = tessera.Session(_stage(), validation=True)
    cage = _render(session)
    refined = _render(session, complexity=1.2)
    assert refined.stats["synced"] == {"mesh": 1}, "only the catmullClark cube re-syncs"
    assert dict(session.index.last_synced) == {"/World/Smooth": tessera._tessera.dirty.TOPOLOGY}
    assert refined.stats["source_triangles"] == 12 * 16 + 12 + 12, "refined twice: 16 quads per face"
    assert _covered(refined, "/World/Smooth") < _covered(cage, "/World/Smooth"), "the refined cube is rounded"
    assert _covered(refined, "/World/Polygons") == _covered(cage, "/World/Polygons")
    assert _render(session, complexity=1.25).stats["synced"] == {}, "the same refine level: nothing re-syncs"
    again = _render(session)  # the session's complexity, 1.0, again
    assert again.stats["synced"] == {"mesh": 1} and again.stats["source_triangles"] == 36
    assert _render(tessera.Session(_stage(), complexity=1.1)).stats["refine_level"] == 1


def test_creases_and_corners_from_the_stage_keep_a_cube_square():
    """Every edge creased and every corner infinitely sharp (USD: 10): the refined cube covers what its cage covers."""
    stage = _stage()
    smooth = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Smooth"))
    session = tessera.Session(stage, validation=True)
    cage = _covered(_render(session), "/World/Smooth")
    rounded = _covered(_render(session, complexity=1.2), "/World/Smooth")
    assert rounded < 0.9 * cage
    smooth.GetCreaseIndicesAttr().Set([i for edge in CUBE_EDGES for i in edge])
    smooth.GetCreaseLengthsAttr().Set([2] * len(CUBE_EDGES))
    smooth.GetCreaseSharpnessesAttr().Set([10.0] * len(CUBE_EDGES))
    smooth.GetCornerIndicesAttr().Set(list(range(8)))
    smooth.GetCornerSharpnessesAttr().Set([10.0] * 8)
    square = _render(session, complexity=1.2)
    assert square.stats["synced"] == {"mesh": 1} and square.stats["meshes_built"] == 1, "a tag edit rebuilds the mesh"
    assert not square.warnings, square.warnings
    assert abs(_covered(square, "/World/Smooth") - cage) <= 0.01 * cage
    smooth.GetCreaseSharpnessesAttr().Set([0.0] * len(CUBE_EDGES))  # creases off: only the corners stay
    softened = _covered(_render(session, complexity=1.2), "/World/Smooth")
    assert rounded < softened < cage


def test_interpolate_boundary_from_the_stage():
    """An open 2 x 2 grid: edgeAndCorner (USD's fallback) keeps its corners, none draws no boundary face."""
    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    grid = UsdGeom.Mesh.Define(stage, "/Grid")
    grid.GetPointsAttr().Set([(x - 1.5, y - 1.5, 0) for y in range(4) for x in range(4)])
    grid.GetFaceVertexCountsAttr().Set([4] * 9)
    grid.GetFaceVertexIndicesAttr().Set([i for y in range(3) for x in range(3)
                                         for i in (4 * y + x, 4 * y + x + 1, 4 * y + x + 5, 4 * y + x + 4)])
    session = tessera.Session(stage, validation=True, complexity=1.2)
    kept = _covered(_render(session), "/Grid")
    grid.GetInterpolateBoundaryAttr().Set(UsdGeom.Tokens.edgeOnly)
    rounded = _covered(_render(session), "/Grid")
    grid.GetInterpolateBoundaryAttr().Set(UsdGeom.Tokens.none)
    inner = _render(session)
    assert inner.stats["source_triangles"] == 16 * 2, "only the middle face is drawn, refined twice"
    assert _covered(inner, "/Grid") < rounded < kept


def test_bad_tags_are_warnings_naming_the_prim():
    stage = _stage()
    smooth = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Smooth"))
    smooth.GetCreaseIndicesAttr().Set([0, 1, 3])
    smooth.GetCreaseLengthsAttr().Set([2])
    smooth.GetCreaseSharpnessesAttr().Set([10.0])
    smooth.GetCornerIndicesAttr().Set([42])
    smooth.GetCornerSharpnessesAttr().Set([10.0])
    smooth.GetPrim().GetAttribute("interpolateBoundary").Set("sometimes")
    result = _render(tessera.Session(stage, validation=True), complexity=1.1)
    assert result.stats["source_triangles"] == 12 * 4 + 24, "the cube still refines, without the bad tags"
    assert any(w.startswith("/World/Smooth: creases ignored: creaseLengths sum to 2") for w in result.warnings), result.warnings
    assert any(w.startswith("/World/Smooth: corners ignored: cornerIndices has 42") for w in result.warnings), result.warnings
    assert any(w.startswith("/World/Smooth: interpolateBoundary 'sometimes' is not one of") for w in result.warnings), result.warnings


def test_cli_complexity_and_refine_level_alias(tmp_path):
    stage_path = tmp_path / "cubes.usda"
    stage = _stage()  # held: a layer dies with its in-memory stage
    stage.GetRootLayer().Export(str(stage_path))

    def run(*flags):
        stats = tmp_path / "stats.json"
        done = subprocess.run([sys.executable, "-m", "tessera.cli", "render", str(stage_path), "-o", str(tmp_path / "out.png"),
                               "--resolution", "64x32", "--stats", str(stats), *flags], capture_output=True, text=True)
        return done, (__import__("json").loads(stats.read_text()) if done.returncode == 0 else None)

    _, default = run()
    assert default["refine_level"] == 0
    _, medium = run("--complexity", "1.1")
    _, alias = run("--refine-level", "1")
    assert medium["refine_level"] == alias["refine_level"] == 1
    assert medium["source_triangles"] == alias["source_triangles"] == 12 * 4 + 24
    bad, _ = run("--complexity", "0.5")
    assert bad.returncode != 0 and "complexity" in bad.stderr


@pytest.mark.parametrize("complexity", [1.0, 1.1])
def test_authored_normals_of_a_subdivision_surface_are_ignored_as_storm_ignores_them(complexity):
    """UsdImaging's mesh adapter reads normals only where subdivisionScheme is none: a subdivision surface shades with
    smooth normals from its geometry, at the control cage as at any refine level. Two quads facing the camera author
    normals tilted 37 degrees towards +X: the `none` one shows them, the catmullClark one faces the camera."""
    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 20))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(20.0)
    for name, x, scheme in (("Subdiv", -4, "catmullClark"), ("Polygons", 4, "none")):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        mesh.GetPointsAttr().Set([(x - 3, -3, 0), (x + 3, -3, 0), (x + 3, 3, 0), (x - 3, 3, 0)])
        mesh.GetFaceVertexCountsAttr().Set([4])
        mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
        mesh.GetSubdivisionSchemeAttr().Set(scheme)
        mesh.GetNormalsAttr().Set([(0.6, 0, 0.8)] * 4)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=(200, 100), aovs=("normal",),
                                                            complexity=complexity)
    assert not result.errors, result.errors
    normals = np.asarray(result["normal"].pixels)[..., :3]
    assert np.allclose(normals[50, 100 - 40], (0, 0, 1), atol=0.01), f"catmullClark: smooth normals, {normals[50, 60]}"
    assert np.allclose(normals[50, 100 + 40], (0.6, 0, 0.8), atol=0.01), f"none: the authored normals, {normals[50, 140]}"
