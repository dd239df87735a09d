"""Native instances and purpose and visibility, as UsdImaging draws them (plugin/usd/scene_delegate.py `_walk`,
`_binding_partitions`): an invisible instance draws nothing; an instance's purpose is what its prototype's prims
inherit, so an instance of a purpose not rendered draws only the prims inside that author a purpose that is rendered;
prims inside honour their own purpose and visibility. Instances are grouped by (material, strength, purpose), one
rprim per prototype gprim and part, all sharing one built mesh."""

import numpy as np
from pxr import Gf, UsdGeom

import tessera
from tessera import _tessera
from conftest import stage_with_camera

DIRTY = _tessera.dirty
RESOLUTION = (200, 100)  # the camera sees x in [-4, 4], y in [-2, 2]: 25 pixels per unit
COLUMNS = {"T0": 25, "T1": 75, "T2": 125, "T3": 175}  # pixel column of each tile's centre (x = -3, -1, 1, 3)
# Rows (and column offsets) of the prototype's gprims: Geo (no purpose) in the middle, Always (purpose render) above,
# Guide (purpose guide) and Hidden (invisible) below, side by side.
ROWS = {"Geo": (50, 0), "Always": (32, 0), "Guide": (67, -3), "Hidden": (67, 3)}


def _square(stage, path, x0, y0, x1, y1):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    return mesh


def _stage():
    """Four native instances of one tile in a row, seen from z = 10: T1 invisible, T2 of purpose proxy."""
    stage = stage_with_camera()
    assets = UsdGeom.Scope.Define(stage, "/Assets")
    assets.GetVisibilityAttr().Set(UsdGeom.Tokens.invisible)
    UsdGeom.Xform.Define(stage, "/Assets/Tile")
    _square(stage, "/Assets/Tile/Geo", -0.4, -0.4, 0.4, 0.4)
    _square(stage, "/Assets/Tile/Always", -0.2, 0.5, 0.2, 0.9).CreatePurposeAttr(UsdGeom.Tokens.render)
    _square(stage, "/Assets/Tile/Guide", -0.3, -0.9, -0.02, -0.5).CreatePurposeAttr(UsdGeom.Tokens.guide)
    _square(stage, "/Assets/Tile/Hidden", 0.02, -0.9, 0.3, -0.5).CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    UsdGeom.Xform.Define(stage, "/Tiles")
    for name, column in COLUMNS.items():
        tile = UsdGeom.Xform.Define(stage, f"/Tiles/{name}")
        tile.AddTranslateOp().Set(Gf.Vec3d((column - 100) / 25, 0, 0))
        tile.GetPrim().GetReferences().AddInternalReference("/Assets/Tile")
        tile.GetPrim().SetInstanceable(True)
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tiles/T1")).CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tiles/T2")).CreatePurposeAttr(UsdGeom.Tokens.proxy)
    return stage


def _render(session):
    result = session.render(camera="/Camera", resolution=RESOLUTION, aovs=("color",))
    assert not result.errors, result.errors
    return result, dict(session.index.last_synced)


def _drawn(result):
    """{tile: sorted names of the prototype gprims drawn there}."""
    lit = np.asarray(result["color"].pixels)[..., :3].max(axis=2) > 0
    return {tile: sorted(g for g, (row, dx) in ROWS.items() if lit[row, column + dx]) for tile, column in COLUMNS.items()}


def test_invisible_instances_draw_nothing_and_an_instances_purpose_reaches_only_prims_without_their_own():
    session = tessera.Session(_stage(), validation=True)
    result, _ = _render(session)
    assert _drawn(result) == {"T0": ["Always", "Geo"], "T1": [], "T2": ["Always"], "T3": ["Always", "Geo"]}
    assert result.stats["instances"] == 5
    # One mesh per prototype gprim drawn, however many parts: built once, shared on the GPU.
    assert result.stats["meshes_built"] + result.stats["meshes_cached"] == 2
    assert sorted(id for id in session.scene.rprims if id.startswith("/__Prototype")) == [
        "/__Prototype_1/Always{/__Prototype_1(proxy)}", "/__Prototype_1/Always{/__Prototype_1}", "/__Prototype_1/Geo{/__Prototype_1}"]


def test_proxy_purpose_when_asked_draws_the_proxy_instance_whole():
    session = tessera.Session(_stage(), validation=True, purposes=("render", "proxy"))
    result, _ = _render(session)
    assert _drawn(result) == {"T0": ["Always", "Geo"], "T1": [], "T2": ["Always", "Geo"], "T3": ["Always", "Geo"]}
    assert result.stats["instances"] == 6


def test_a_visibility_edit_on_one_instance_re_syncs_its_parts_copies_alone():
    stage = _stage()
    session = tessera.Session(stage, validation=True)
    _render(session)
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tiles/T1")).GetVisibilityAttr().Set(UsdGeom.Tokens.inherited)
    result, synced = _render(session)
    assert _drawn(result)["T1"] == ["Always", "Geo"] and result.stats["instances"] == 7
    # The default part gained a copy: its two rprims re-read their instances, nothing is rebuilt; the proxy part is untouched.
    assert synced == {"/__Prototype_1/Always{/__Prototype_1}": DIRTY.INSTANCER, "/__Prototype_1/Geo{/__Prototype_1}": DIRTY.INSTANCER}
    assert result.stats["meshes_built"] == 0
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tiles/T2")).MakeInvisible()
    result, synced = _render(session)
    assert _drawn(result)["T2"] == [] and result.stats["instances"] == 6
    assert "/__Prototype_1/Always{/__Prototype_1(proxy)}" not in session.scene.rprims, "its only instance is hidden"
    assert all(bits == DIRTY.INSTANCER for bits in synced.values()), synced


def test_a_purpose_edit_moves_an_instance_between_parts():
    stage = _stage()
    session = tessera.Session(stage, validation=True)
    _render(session)
    UsdGeom.Imageable(stage.GetPrimAtPath("/Tiles/T2")).GetPurposeAttr().Set(UsdGeom.Tokens.render)
    result, synced = _render(session)
    assert _drawn(result)["T2"] == ["Always", "Geo"] and result.stats["instances"] == 6
    # T2 is now of purpose render, a part of its own (as UsdImaging groups by the purpose instances pass down); the
    # proxy part is gone. The new part's rprims are new (they sync whole) but their meshes are the ones built already.
    parts = sorted(id for id in session.scene.rprims if id.startswith("/__Prototype"))
    assert parts == ["/__Prototype_1/Always{/__Prototype_1(render)}", "/__Prototype_1/Always{/__Prototype_1}",
                     "/__Prototype_1/Geo{/__Prototype_1(render)}", "/__Prototype_1/Geo{/__Prototype_1}"], parts
    assert set(synced) == {"/__Prototype_1/Always{/__Prototype_1(render)}", "/__Prototype_1/Geo{/__Prototype_1(render)}"}, synced
    assert result.stats["meshes_built"] == 0 and result.stats["meshes_shared"] == 2
