"""Material bindings on or above a native instance reach its prototype's gprims, by UsdShade's rules (the instance's
own resolution: direct and collection bindings, bindMaterialAs strength), while the prototype's mesh is read and built
once: instances that inherit different materials are drawn as one rprim per material (plugin/usd/scene_delegate.py,
`_binding_partitions`), whose meshes share one GPU scene mesh."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

import tessera
from tessera import _tessera
from conftest import preview_material

DIRTY = _tessera.dirty
RESOLUTION = (200, 100)  # the camera sees x in [-4, 4], y in [-2, 2]: 25 pixels per unit
COLUMNS = {"T0": 25, "T1": 75, "T2": 125, "T3": 175}  # pixel column of each tile's centre (x = -3, -1, 1, 3)
COLOURS = {"red": (0.8, 0.05, 0.05), "green": (0.05, 0.8, 0.05), "blue": (0.05, 0.05, 0.8)}


def _stage(inner_binding=None):
    """Four native instances of one quad tile in a row, seen from z = 10; `inner_binding`: a material bound to the
    prototype's gprim itself."""
    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(20.0)
    for name, colour in COLOURS.items():
        preview_material(stage, f"/Looks/{name.capitalize()}", colour)
    assets = UsdGeom.Scope.Define(stage, "/Assets")
    assets.GetVisibilityAttr().Set(UsdGeom.Tokens.invisible)
    UsdGeom.Xform.Define(stage, "/Assets/Tile")
    mesh = UsdGeom.Mesh.Define(stage, "/Assets/Tile/Geo")
    mesh.GetPointsAttr().Set([(-0.4, -0.4, 0), (0.4, -0.4, 0), (0.4, 0.4, 0), (-0.4, 0.4, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if inner_binding:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(UsdShade.Material.Get(stage, f"/Looks/{inner_binding}"))
    for name, column in COLUMNS.items():
        tile = UsdGeom.Xform.Define(stage, f"/Tiles/{name}")
        tile.AddTranslateOp().Set(Gf.Vec3d((column - 100) / 25, 0, 0))
        tile.GetPrim().GetReferences().AddInternalReference("/Assets/Tile")
        tile.GetPrim().SetInstanceable(True)
        UsdShade.MaterialBindingAPI.Apply(tile.GetPrim())
    return stage


def _bind(stage, path, material, strength=UsdShade.Tokens.weakerThanDescendants):
    UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(path)).Bind(UsdShade.Material.Get(stage, f"/Looks/{material}"), strength)


def _render(session):
    result = session.render(camera="/Camera", resolution=RESOLUTION, aovs=("color",))
    assert not result.errors, result.errors
    return result, dict(session.index.last_synced)


def _colour_of(result, tile):
    """The name of the dominant channel at a tile's centre ("grey" when none dominates)."""
    r, g, b = result["color"].pixels[50, COLUMNS[tile], :3]
    top = max(r, g, b)
    assert top > 0, f"{tile} is not drawn"
    for name, value in (("red", r), ("green", g), ("blue", b)):
        if value == top and value > 3 * (r + g + b - value) / 2:
            return name
    return "grey"


def test_instances_draw_the_material_their_own_binding_resolves():
    stage = _stage()
    _bind(stage, "/Tiles/T1", "Blue")
    _bind(stage, "/Tiles/T2", "Red")
    _bind(stage, "/Tiles/T3", "Blue")
    session = tessera.Session(stage, validation=True)
    result, _ = _render(session)
    assert [_colour_of(result, t) for t in COLUMNS] == ["grey", "blue", "red", "blue"]
    # One prototype mesh, read for three materials (no binding, Blue, Red), built or loaded once and shared on the GPU.
    assert result.stats["meshes_built"] + result.stats["meshes_cached"] == 1
    assert result.stats["meshes_shared"] == 2
    assert result.stats["instances"] == 4


def test_an_ancestor_binding_reaches_the_instances_under_it():
    stage = _stage()
    _bind(stage, "/Tiles", "Green")
    _bind(stage, "/Tiles/T2", "Red")
    result, _ = _render(tessera.Session(stage, validation=True))
    assert [_colour_of(result, t) for t in COLUMNS] == ["green", "green", "red", "green"]


def test_binding_strength_decides_between_the_instance_and_the_prototype():
    stage = _stage(inner_binding="Green")  # the prototype's gprim binds Green itself
    _bind(stage, "/Tiles/T1", "Blue")  # weaker than descendants: the prototype's own binding wins
    _bind(stage, "/Tiles/T2", "Red", UsdShade.Tokens.strongerThanDescendants)  # wins over the prototype's
    _bind(stage, "/Tiles/T3", "Blue", UsdShade.Tokens.strongerThanDescendants)  # the same material as T1's, stronger
    _bind(stage, "/Tiles", "Blue")  # weaker, above the instances: the prototype's wins again
    result, _ = _render(tessera.Session(stage, validation=True))
    assert [_colour_of(result, t) for t in COLUMNS] == ["green", "green", "red", "blue"]


def test_a_collection_binding_on_an_ancestor_names_instances():
    stage = _stage()
    tiles = stage.GetPrimAtPath("/Tiles")
    collection = Usd.CollectionAPI.Apply(tiles, "reds")
    collection.CreateIncludesRel().SetTargets(["/Tiles/T0", "/Tiles/T3"])
    UsdShade.MaterialBindingAPI.Apply(tiles).Bind(collection, UsdShade.Material.Get(stage, "/Looks/Red"), "reds")
    result, _ = _render(tessera.Session(stage, validation=True))
    assert [_colour_of(result, t) for t in COLUMNS] == ["red", "grey", "grey", "red"]


def test_rebinding_an_instance_resyncs_the_copies_it_leaves_and_joins():
    stage = _stage()
    _bind(stage, "/Tiles/T1", "Blue")
    session = tessera.Session(stage, validation=True)
    _render(session)
    proto = str(stage.GetPrimAtPath("/Tiles/T0").GetPrototype().GetPath())
    plain, blue = f"{proto}/Geo{{{proto}}}", f"{proto}/Geo{{{proto}</Looks/Blue>}}"

    _bind(stage, "/Tiles/T2", "Blue")  # T2 leaves the unbound copies and joins T1's
    result, synced = _render(session)
    assert synced == {plain: DIRTY.INSTANCER, blue: DIRTY.INSTANCER}
    assert result.stats["meshes_built"] + result.stats["meshes_cached"] == 0
    assert [_colour_of(result, t) for t in COLUMNS] == ["grey", "blue", "blue", "grey"]

    _bind(stage, "/Tiles/T3", "Red")  # a material no copy had: its copies are a new rprim, its mesh the shared one
    result, synced = _render(session)
    red = f"{proto}/Geo{{{proto}</Looks/Red>}}"
    assert set(synced) == {plain, red, "/Looks/Red"} and synced[plain] == DIRTY.INSTANCER
    assert result.stats["meshes_built"] == 0 and result.stats["meshes_shared"] == 1
    assert [_colour_of(result, t) for t in COLUMNS] == ["grey", "blue", "blue", "red"]

    UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/Tiles/T3")).UnbindAllBindings()  # back with the unbound ones
    result, synced = _render(session)
    assert synced == {plain: DIRTY.INSTANCER}
    assert [_colour_of(result, t) for t in COLUMNS] == ["grey", "blue", "blue", "grey"]

    _bind(stage, "/Tiles/T0", "Red")  # moving a bound instance moves its copy alone
    _render(session)
    stage.GetPrimAtPath("/Tiles/T0").GetAttribute("xformOp:translate").Set(Gf.Vec3d(-3.5, 0, 0))
    result, synced = _render(session)
    assert synced == {red: DIRTY.INSTANCER}
