"""Translating a stage reads only what prims author (plugin/usd/scene_delegate.py): these are the cases where what a
walk saw must not be trusted, and where the work it skips (material bindings on a stage without materials) must come
back when the stage changes."""

from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

import tessera

NO_HIT = 0xFFFFFFFF


def _stage():
    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(20.0)
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
