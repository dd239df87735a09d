"""Translating a stage reads only what prims author (plugin/usd/scene_delegate.py): these are the cases where what a
walk saw must not be trusted, and where the work it skips (material bindings on a stage without materials) must come
back when the stage changes."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

import tessera
from conftest import stage_with_camera

NO_HIT = 0xFFFFFFFF


def _stage():
    stage = stage_with_camera()
    quad = UsdGeom.Mesh.Define(stage, "/Quad")
    quad.GetPointsAttr().Set([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.GetFaceVertexCountsAttr().Set([4])
    quad.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr("none")
    return stage, quad


def _centre_colour(result):
    pixels = result["color"].pixels
    return pixels[pixels.shape[0] // 2, pixels.shape[1] // 2, :3]


def test_attributes_authored_after_the_walk_are_read():
    """The session walks the stage when it is made; a displayColor, a hidden state and doubleSided authored before
    its first render are all seen (the walk's notes on those prims are dropped with the edit)."""
    stage, quad = _stage()
    session = tessera.Session(stage, validation=True)
    quad.CreateDisplayColorAttr([(0.9, 0.1, 0.1)])
    result = session.render(camera="/Camera", resolution=(80, 40), aovs=("color",))
    r, g, b = _centre_colour(result)
    assert r > 3 * g and r > 3 * b, "the red authored after the walk"
    quad.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    hidden = session.render(camera="/Camera", resolution=(80, 40), aovs=("primId",))
    assert (hidden["primId"].ids() == NO_HIT).all()


def test_a_fresh_session_sees_authored_visibility_and_purpose():
    stage, quad = _stage()
    other = UsdGeom.Mesh.Define(stage, "/Guide")
    other.GetPointsAttr().Set([(2, -1, 0), (4, -1, 0), (4, 1, 0), (2, 1, 0)])
    other.GetFaceVertexCountsAttr().Set([4])
    other.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    other.CreatePurposeAttr(UsdGeom.Tokens.guide)
    quad.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=(80, 40), aovs=("primId",))
    assert result.stats["rprims"] == 1, "the guide is not read"
    assert (result["primId"].ids() == NO_HIT).all(), "the quad is hidden"


def test_the_first_material_on_a_stage_binds_what_bound_it_already():
    """A stage without materials skips binding resolution; a material defined later (the binding was authored
    before it existed) is bound at once."""
    stage, quad = _stage()
    binding = UsdShade.MaterialBindingAPI.Apply(quad.GetPrim())
    binding.GetDirectBindingRel().SetTargets(["/Looks/Green"])  # a target that does not exist yet
    session = tessera.Session(stage, validation=True)
    grey = _centre_colour(session.render(camera="/Camera", resolution=(80, 40)))
    assert abs(grey[0] - grey[1]) < 0.02, "no material: the fallback grey"
    material = UsdShade.Material.Define(stage, "/Looks/Green")
    shader = UsdShade.Shader.Define(stage, "/Looks/Green/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.05, 0.8, 0.05))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    r, g, b = _centre_colour(session.render(camera="/Camera", resolution=(80, 40)))
    assert g > 3 * r and g > 3 * b, "bound to the material that now exists"


def test_meshes_no_rendered_view_sees_are_not_built_until_one_does():
    """Model only what the render needs: a mesh whose authored extent the render's camera does not see is not built
    (not even read); it is built at the first render whose view sees it. A mesh without an extent is built anyway, and
    so is everything when no stage camera is given (the framing camera sees the whole stage)."""
    stage, _ = _stage()  # the camera at z = 10 sees x in about [-9, 9]
    def quad(path, x, extent=True):
        mesh = UsdGeom.Mesh.Define(stage, path)
        points = [(x - 1, -1, 0), (x + 1, -1, 0), (x + 1, 1, 0), (x - 1, 1, 0)]
        mesh.GetPointsAttr().Set(points)
        mesh.GetFaceVertexCountsAttr().Set([4])
        mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
        mesh.CreateSubdivisionSchemeAttr("none")
        if extent:
            mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(points))
        return mesh

    quad("/Far", 40.0)
    quad("/FarNoExtent", -40.0, extent=False)
    session = tessera.Session(stage, validation=True)

    def render(camera="/Camera"):
        result = session.render(camera=camera, resolution=(80, 40), aovs=("primId",))
        assert not result.errors, result.errors
        drawn = {result.prim_path(int(i)) for i in set(result["primId"].ids().ravel()) if i != NO_HIT}
        return result.stats, drawn

    stats, drawn = render()
    assert stats["meshes_out_of_view"] == 1 and stats["meshes_built"] + stats["meshes_cached"] == 2, "/Far waits"
    assert drawn == {"/Quad"}
    stats, _ = render()
    assert stats["meshes_out_of_view"] == 1 and stats["meshes_built"] + stats["meshes_cached"] == 0

    stage.GetPrimAtPath("/Far").GetAttribute("points").Set([(38, -1, 0), (42, -1, 0), (42, 1, 0), (38, 1, 0)])
    stats, _ = render()
    assert stats["meshes_out_of_view"] == 1 and stats["meshes_built"] + stats["meshes_cached"] == 0, "an edit out of view builds nothing"

    stage.GetPrimAtPath("/Camera").GetAttribute("xformOp:translate").Set(Gf.Vec3d(40, 0, 10))
    stats, drawn = render()
    assert stats["meshes_out_of_view"] == 0 and stats["meshes_built"] + stats["meshes_cached"] == 1, "built once seen"
    assert drawn == {"/Far"}

    fresh = tessera.Session(stage, validation=True).render(resolution=(80, 40), aovs=("primId",))  # framing camera
    assert fresh.stats["meshes_out_of_view"] == 0 and fresh.stats["meshes_built"] + fresh.stats["meshes_cached"] == 3


# -- world transforms computed by the walk (scene_delegate._WorldTransforms) against UsdGeom.XformCache ------------

def _cube(stage, path):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([3])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2])
    return mesh


def _layered_transform_stage():
    """Transforms from every place a stage gets them: a sublayer overridden by the root layer, a reference with a
    layer offset over time samples, a variant, resetXformStack, a mesh's own ops, a Scope (not Xformable: ops it
    authors do not count), an instance (so the walk also meets prototypes) and a hidden subtree."""
    asset = Sdf.Layer.CreateAnonymous("asset.usda")
    asset_stage = Usd.Stage.Open(asset)
    root = UsdGeom.Xform.Define(asset_stage, "/Asset")
    op = root.AddTranslateOp()
    op.Set(Gf.Vec3d(1, 0, 0), 0)
    op.Set(Gf.Vec3d(11, 0, 0), 10)
    root.AddRotateZOp().Set(30.0)
    _cube(asset_stage, "/Asset/Body").AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
    weak = Sdf.Layer.CreateAnonymous("weak.usda")
    weak_stage = Usd.Stage.Open(weak)
    world = UsdGeom.Xform.Define(weak_stage, "/World")
    world.AddTranslateOp().Set(Gf.Vec3d(0, 5, 0))
    world.AddScaleOp().Set(Gf.Vec3f(1, 1, 3))
    _cube(weak_stage, "/World/Group/Mesh")
    UsdGeom.Xform.Define(weak_stage, "/World/Group").AddTranslateOp().Set(Gf.Vec3d(0, 0, 1))

    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().subLayerPaths.append(weak.identifier)
    # The root layer's opinions win: the group moves elsewhere and gains a rotation.
    group = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Group"))
    group.GetOrderedXformOps()[0].Set(Gf.Vec3d(4, 0, 0))
    group.AddRotateXOp().Set(90.0)
    placed = stage.DefinePrim("/World/Placed")
    placed.GetReferences().AddReference(Sdf.Reference(asset.identifier, "/Asset", Sdf.LayerOffset(offset=5.0)))
    reset = UsdGeom.Xform.Define(stage, "/World/Group/Reset")
    reset.SetResetXformStack(True)
    reset.AddTranslateOp().Set(Gf.Vec3d(0, 0, 7))
    _cube(stage, "/World/Group/Reset/Mesh").AddRotateYOp().Set(45.0)
    only_reset = UsdGeom.Xform.Define(stage, "/World/Group/OnlyReset")
    only_reset.SetResetXformStack(True)
    _cube(stage, "/World/Group/OnlyReset/Mesh")
    scope = UsdGeom.Scope.Define(stage, "/World/Scope")
    scope.GetPrim().CreateAttribute("xformOp:translate", Sdf.ValueTypeNames.Double3).Set(Gf.Vec3d(100, 0, 0))
    scope.GetPrim().CreateAttribute("xformOpOrder", Sdf.ValueTypeNames.TokenArray).Set(["xformOp:translate"])
    _cube(stage, "/World/Scope/Mesh")
    switch = UsdGeom.Xform.Define(stage, "/World/Switch")
    variants = switch.GetPrim().GetVariantSets().AddVariantSet("place")
    for name, offset in (("near", 1.0), ("far", 50.0)):
        variants.AddVariant(name)
        variants.SetVariantSelection(name)
        with variants.GetVariantEditContext():
            UsdGeom.Xform(switch.GetPrim()).AddTranslateOp().Set(Gf.Vec3d(offset, 0, 0))
            _cube(stage, "/World/Switch/Mesh")
    variants.SetVariantSelection("far")
    hidden = UsdGeom.Xform.Define(stage, "/World/Hidden")
    hidden.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    _cube(stage, "/World/Hidden/Mesh")
    instance = stage.DefinePrim("/World/Instance")
    instance.GetReferences().AddReference(Sdf.Reference(asset.identifier, "/Asset"))
    instance.SetInstanceable(True)
    return stage, (asset, weak)


def _usd_world(stage, path, time):
    return np.asarray(UsdGeom.XformCache(time).GetLocalToWorldTransform(stage.GetPrimAtPath(path))).T.ravel()


def _delegate(stage, time=Usd.TimeCode.Default()):
    from tessera import _tessera
    from tessera.usd import UsdSceneDelegate

    index = _tessera.RenderIndex(_tessera.RenderDelegate(validation=True))
    delegate = UsdSceneDelegate(stage, index, time=time)
    delegate.populate()
    return delegate, index


@pytest.mark.parametrize("time", [Usd.TimeCode.Default(), Usd.TimeCode(7.5)])
def test_walked_world_transforms_are_usds(time):
    stage, _layers = _layered_transform_stage()
    from tessera import _tessera

    delegate, index = _delegate(stage, time)
    plain = sorted(id for id, record in delegate.rprims.items() if record.group is None)
    assert plain == ["/World/Group/Mesh", "/World/Group/OnlyReset/Mesh", "/World/Group/Reset/Mesh", "/World/Hidden/Mesh",
                     "/World/Placed/Body", "/World/Scope/Mesh", "/World/Switch/Mesh"]
    # The walk computed every plain mesh's transform: a shown mesh's went into the index with it (its first sync does
    # not ask for it), a hidden one's waits in the delegate for the sync that shows it.
    assert set(delegate._walked_worlds) == {"/World/Hidden/Mesh"}
    for id in plain:
        if id in delegate._walked_worlds:
            walked = np.array(delegate.get_transform(id))  # the first read takes the walk's
            assert id not in delegate._walked_worlds, "used once"
            assert np.array_equal(np.array(delegate.get_transform(id)), walked), "read again through USD: the same"
        else:
            assert index.rprim_defaults(id) & _tessera.dirty.TRANSFORM, id
            walked = np.array(index.rprim_transform(id))
        assert not np.isnan(walked).any()
        assert np.allclose(walked, _usd_world(stage, id, time), rtol=0, atol=1e-12), id


def test_walked_world_transforms_are_dropped_by_edits_and_time():
    """A mesh's walked transform is used only by the first sync after the walk: an edit above it, or another
    time, before that sync (a hidden mesh waits for its first show) means reading it again."""
    from tessera.usd import ChangeTracker

    from tessera import _tessera

    stage, _layers = _layered_transform_stage()
    delegate, index = _delegate(stage)
    changes = ChangeTracker(stage)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World")).GetOrderedXformOps()[0].Set(Gf.Vec3d(0, -8, 0))
    delegate.apply_changes(*changes.take())
    for id in ("/World/Hidden/Mesh", "/World/Group/Mesh"):
        assert np.allclose(delegate.get_transform(id), _usd_world(stage, id, Usd.TimeCode.Default()), atol=1e-12), id
    # The index forgot the transform the walk handed it (the edit dirtied it): the first sync reads it again.
    assert not index.rprim_defaults("/World/Placed/Body") & _tessera.dirty.TRANSFORM
    index.sync_all(delegate)
    assert np.allclose(index.rprim_transform("/World/Placed/Body"), _usd_world(stage, "/World/Placed/Body", Usd.TimeCode.Default()),
                       atol=1e-12)
    delegate.set_time(Usd.TimeCode(3.0))  # re-walked prims then a new time: the walk's time no longer applies
    assert np.allclose(delegate.get_transform("/World/Placed/Body"), _usd_world(stage, "/World/Placed/Body", Usd.TimeCode(3.0)),
                       atol=1e-12)
    # A re-walked subtree (a variant switch) notes fresh transforms.
    stage.GetPrimAtPath("/World/Switch").GetVariantSets().SetSelection("place", "near")
    delegate.apply_changes(*changes.take())
    assert "/World/Switch/Mesh" in delegate._walked_worlds
    assert np.allclose(delegate.get_transform("/World/Switch/Mesh"), _usd_world(stage, "/World/Switch/Mesh", Usd.TimeCode(3.0)),
                       atol=1e-12)


@pytest.mark.parametrize("orientation, double_sided, scheme", [
    (None, None, None), (UsdGeom.Tokens.leftHanded, None, "none"), (UsdGeom.Tokens.leftHanded, True, "none"),
    (UsdGeom.Tokens.rightHanded, False, "catmullClark"), (None, True, "loop")])
def test_the_short_mesh_read_matches_the_full_one(orientation, double_sided, scheme):
    """A mesh that authors no primvars, normals or holes is read by a short path (_plain_mesh_source); an empty
    holeIndices sends the same mesh through the full reader: both render the same."""
    images = []
    for full in (False, True):
        stage, quad = _stage()
        quad.GetPointsAttr().Set([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (0, 0, 0.5)])
        quad.GetFaceVertexCountsAttr().Set([3, 3, 3, 3])
        quad.GetFaceVertexIndicesAttr().Set([0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4])
        quad.GetPrim().RemoveProperty("subdivisionScheme")  # unauthored unless the case authors it
        for attribute, value in ((quad.GetOrientationAttr(), orientation), (quad.GetDoubleSidedAttr(), double_sided),
                                 (quad.GetSubdivisionSchemeAttr(), scheme)):
            if value is not None:
                attribute.Set(value)
        if full:
            quad.GetHoleIndicesAttr().Set([])
        # Refined once, so that the scheme each path reads shows.
        result = tessera.Session(stage, validation=True, complexity=1.1).render(camera="/Camera", resolution=(64, 32),
                                                                                aovs=("primId", "normal"))
        images.append((result["primId"].ids(), result["normal"].pixels))
    (ids, normals), (full_ids, full_normals) = images
    assert (ids != NO_HIT).any() or orientation == UsdGeom.Tokens.leftHanded, "the pyramid shows"
    assert np.array_equal(ids, full_ids)
    assert np.array_equal(normals, full_normals)


def test_the_short_read_borrows_arrays_of_any_shape_and_refuses_other_types():
    """plain_mesh_source (the short path's one call) takes USD's points as numpy gives them, (N, 3), without a copy,
    and names the mesh when an array is of another type."""
    points = np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0)], np.float32)
    counts, indices = np.array([3], np.int32), np.array([0, 1, 2], np.int32)
    from tessera import _tessera

    assert isinstance(_tessera.plain_mesh_source("/Tri", points, counts, indices, False, True, "none", 0), _tessera.MeshSource)
    with pytest.raises(ValueError, match="/Tri: points must be contiguous float32"):
        _tessera.plain_mesh_source("/Tri", points.astype(np.float64), counts, indices, False, False, "none", 0)
    with pytest.raises(ValueError, match="/Tri: .*int32"):
        _tessera.plain_mesh_source("/Tri", points, counts.astype(np.int64), indices, False, False, "none", 0)


def test_the_short_read_converts_arrays_authored_with_other_types():
    """The short read hands USD's arrays to C++ as they are; points authored as double3[] and indices as int64[] (not
    the schema's types) are converted and draw as the schema's types do."""
    images = []
    for converted in (False, True):
        stage, quad = _stage()
        if converted:
            spec = stage.GetRootLayer().GetPrimAtPath("/Quad")
            for name in ("points", "faceVertexIndices"):
                spec.RemoveProperty(spec.properties[name])
            Sdf.AttributeSpec(spec, "points", Sdf.ValueTypeNames.Double3Array).default = \
                Vt.Vec3dArray([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
            Sdf.AttributeSpec(spec, "faceVertexIndices", Sdf.ValueTypeNames.Int64Array).default = Vt.Int64Array([0, 1, 2, 3])
            assert isinstance(quad.GetPointsAttr().Get(), Vt.Vec3dArray)
        result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=(64, 32), aovs=("primId",))
        assert not result.errors and not result.warnings, (result.errors, result.warnings)
        images.append(result["primId"].ids())
    assert (images[0] != NO_HIT).any() and np.array_equal(images[0], images[1])

def test_the_first_sync_asks_for_no_default_the_walk_saw():
    """A mesh the walk saw visible and without a material is inserted with those defaults and its world transform: its
    first sync does not call back for them. A hidden mesh and a bound one are asked, and marking a default's bit dirty
    (an edit) makes the next sync ask again."""
    from tessera import _tessera
    from tessera.usd import UsdSceneDelegate

    stage, _ = _stage()
    _cube(stage, "/Plain")
    _cube(stage, "/Hidden").MakeInvisible()
    bound = _cube(stage, "/Bound")
    material = UsdShade.Material.Define(stage, "/Looks/Red")
    UsdShade.MaterialBindingAPI.Apply(bound.GetPrim()).Bind(material)
    asked = []

    class Counting(UsdSceneDelegate):
        def get_visible(self, id):
            asked.append(("visible", id))
            return super().get_visible(id)

        def get_material_id(self, id):
            asked.append(("material", id))
            return super().get_material_id(id)

        def get_transform(self, id):
            asked.append(("transform", id))
            return super().get_transform(id)

    index = _tessera.RenderIndex(_tessera.RenderDelegate(validation=True))
    delegate = Counting(stage, index)
    delegate.populate()
    dirty = _tessera.dirty
    index.mark_dirty("/Plain", dirty.VISIBILITY | dirty.MATERIAL_ID)  # as an edit before the first sync
    index.mark_dirty("/Bound", dirty.TRANSFORM)
    index.sync_all(delegate)
    assert sorted(asked) == [("material", "/Bound"), ("material", "/Plain"), ("transform", "/Bound"), ("visible", "/Hidden"),
                             ("visible", "/Plain")], "only what is not a default (/Quad is asked nothing; /Hidden shows no transform)"
    built = index.take_diagnostics()
    assert built["meshes_built"] + built["meshes_shared"] == 3, "the plain meshes are built all the same (not the hidden one)"


def test_a_transform_usd_rejects_is_left_to_the_sync():
    """Ops USD cannot evaluate (a scale of one double) stop the walk's transforms below that prim, and only there:
    the meshes under it read theirs in their sync, which reports the prim by name (test_render.py); a reset below
    it starts afresh."""
    stage, _ = _stage()
    bad = UsdGeom.Xform.Define(stage, "/Bad")
    bad.GetPrim().CreateAttribute("xformOp:scale", Sdf.ValueTypeNames.Double).Set(2.0)
    bad.GetPrim().CreateAttribute("xformOpOrder", Sdf.ValueTypeNames.TokenArray).Set(["xformOp:scale"])
    _cube(stage, "/Bad/Mesh")
    reset = UsdGeom.Xform.Define(stage, "/Bad/Reset")
    reset.SetResetXformStack(True)
    reset.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
    _cube(stage, "/Bad/Reset/Mesh")
    _cube(stage, "/Good/Mesh").AddTranslateOp().Set(Gf.Vec3d(1, 0, 0))
    from tessera import _tessera

    delegate, index = _delegate(stage)
    assert {id for id in delegate.rprims if index.rprim_defaults(id) & _tessera.dirty.TRANSFORM} == \
        {"/Quad", "/Bad/Reset/Mesh", "/Good/Mesh"}, "the walk's transforms, handed to the index"
    for id in ("/Bad/Reset/Mesh", "/Good/Mesh"):
        assert np.allclose(index.rprim_transform(id), _usd_world(stage, id, Usd.TimeCode.Default()), atol=1e-12)
        assert np.allclose(delegate.get_transform(id), _usd_world(stage, id, Usd.TimeCode.Default()), atol=1e-12)
    with pytest.raises(Exception, match="opType"):
        delegate.get_transform("/Bad/Mesh")
    # A subtree walked again under the rejected ops (a prim added there) is left to the sync the same way.
    from tessera.usd import ChangeTracker

    changes = ChangeTracker(stage)
    _cube(stage, "/Bad/Added")
    delegate.apply_changes(*changes.take())
    assert "/Bad/Added" in delegate.rprims and "/Bad/Added" not in delegate._walked_worlds


def test_shared_and_failed_builds_report_by_prim_and_draw_every_mesh():
    """Identical meshes are built once (MeshTable), and a build's warning or error names each prim that authored it:
    150 distinct quads, two identical meshes that lose a face (a warning each) and two identical meshes with no face
    left (an error each; the rest renders)."""
    stage, _ = _stage()
    stage.RemovePrim("/Quad")
    UsdGeom.Xformable(stage.GetPrimAtPath("/Camera")).GetOrderedXformOps()[0].Set(Gf.Vec3d(0, 0, 50))  # sees 40 x 20

    def mesh(path, x, y, size, counts, indices):
        m = UsdGeom.Mesh.Define(stage, path)
        m.GetPointsAttr().Set([(x, y, 0), (x + size, y, 0), (x + size, y + size, 0), (x, y + size, 0)])
        m.GetFaceVertexCountsAttr().Set(counts)
        m.GetFaceVertexIndicesAttr().Set(indices)
        m.CreateSubdivisionSchemeAttr("none")

    for i in range(150):  # a 15 x 10 grid of quads, each a little larger than the last: 150 builds
        mesh(f"/Quads/Q{i}", -15 + 2 * (i % 15), -8 + 1.6 * (i // 15), 1.2 + 1e-4 * i, [4], [0, 1, 2, 3])
    for name, x in (("LossyA", -4), ("LossyB", 4)):  # one good triangle, one with an index past the points
        UsdGeom.Xform.Define(stage, f"/{name}").AddTranslateOp().Set(Gf.Vec3d(x, 0, 0))
        mesh(f"/{name}/Mesh", 0, -9.5, 1.0, [3, 3], [0, 1, 2, 0, 2, 7])
    for name in ("BrokenA", "BrokenB"):
        mesh(f"/{name}", 0, 9, 1.0, [3], [0, 1, 9])
    session = tessera.Session(stage, validation=True)
    result = session.render(camera="/Camera", resolution=(400, 200), aovs=("primId",))

    assert sorted(e.split(":")[0] for e in result.errors) == ["/BrokenA", "/BrokenB"], result.errors
    assert all(e.endswith("; the mesh is skipped") for e in result.errors), result.errors
    lossy = [w for w in result.warnings if "/Lossy" in w]
    assert sorted(w.split(":")[0] for w in lossy) == ["/LossyA/Mesh", "/LossyB/Mesh"], result.warnings
    assert result.stats["meshes_built"] + result.stats["meshes_cached"] == 151, "150 quads and one lossy mesh"
    drawn = {result.prim_path(int(i)) for i in set(result["primId"].ids().ravel()) if i != NO_HIT}
    assert drawn == {f"/Quads/Q{i}" for i in range(150)} | {"/LossyA/Mesh", "/LossyB/Mesh"}

    # A broken mesh added later is reported by its own name.
    mesh("/BrokenC", 0, 9, 1.0, [3], [0, 1, 9])
    again = session.render(camera="/Camera", resolution=(400, 200), aovs=("primId",))
    assert [e.split(":")[0] for e in again.errors] == ["/BrokenC"], again.errors
