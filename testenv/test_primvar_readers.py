"""UsdPrimvarReader nodes and the primvars a mesh reads for its materials (plugin/usd/materials.py `PrimvarNeeds`,
scene_delegate.py `_vertex_channel`): a reader driving diffuseColor routes its primvar into the mesh's vertex channel
(any interpolation, through material interface inputs, inherited constant primvars included), the reader's fallback
where the gprim lacks it; primvars no bound material reads (UVs without a texture that reads them, displayColor when
something else drives diffuseColor) are neither read nor uploaded."""

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade

import tessera
from tessera import _tessera
from conftest import stage_with_camera

RESOLUTION = (200, 100)  # the camera sees x in [-4, 4], y in [-2, 2]: 25 pixels per unit


def _stage():
    stage = stage_with_camera()
    return stage


def _quad(stage, path, x, size=1.6):
    h = size / 2
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x - h, -h, 0), (x + h, -h, 0), (x + h, h, 0), (x - h, h, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    return mesh


def _reader_material(stage, path, reader="UsdPrimvarReader_float3", varname="tint", fallback=None, interface=False,
                     diffuse=(1.0, 0.0, 1.0)):
    """A preview surface whose diffuseColor comes from a primvar reader (its varname from the Material's own
    `inputs:primvarName` when `interface`); the surface's own diffuseColor is magenta, which must never show."""
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    node = UsdShade.Shader.Define(stage, f"{path}/Reader")
    node.CreateIdAttr(reader)
    output_type = Sdf.ValueTypeNames.Float if reader == "UsdPrimvarReader_float" else Sdf.ValueTypeNames.Float3
    node.CreateOutput("result", output_type)
    name = node.CreateInput("varname", Sdf.ValueTypeNames.String)
    if interface:
        material.CreateInput("primvarName", Sdf.ValueTypeNames.String).Set(varname)
        name.ConnectToSource(material.GetInput("primvarName"))
    else:
        name.Set(varname)
    if fallback is not None:
        node.CreateInput("fallback", output_type).Set(fallback)
    surface.GetInput("diffuseColor").ConnectToSource(node.ConnectableAPI(), "result")
    return material


def _render(stage, **kwargs):
    result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=RESOLUTION, **kwargs)
    assert not result.errors, result.errors
    return result


def _rgb(result, x, y=0.0):
    """The colour at scene point (x, y), normalised by its largest channel (lighting aside)."""
    c = np.asarray(result["color"].pixels[int(50 - 25 * y), int(100 + 25 * x), :3], np.float64)
    assert c.max() > 0, f"nothing lit at ({x}, {y})"
    return c / c.max()


def _is(colour, expected):
    return np.allclose(colour, expected, atol=0.08)


def test_a_reader_reads_its_primvar_else_an_inherited_one_else_its_fallback():
    stage = _stage()
    material = _reader_material(stage, "/Looks/Tint", fallback=Gf.Vec3f(0, 1, 0))
    own = _quad(stage, "/World/Own", -2.5)
    UsdGeom.PrimvarsAPI(own).CreatePrimvar("tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(0, 0, 1)])
    UsdGeom.PrimvarsAPI(UsdGeom.Xform.Define(stage, "/World/Group")).CreatePrimvar(
        "tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(1, 0, 0)])
    inherited = _quad(stage, "/World/Group/Inherited", 0.0)
    missing = _quad(stage, "/World/Missing", 2.5)
    for mesh in (own, inherited, missing):
        UsdShade.MaterialBindingAPI(mesh.GetPrim()).Bind(material)
    result = _render(stage)
    assert _is(_rgb(result, -2.5), (0, 0, 1)), "the gprim's own constant primvar"
    assert _is(_rgb(result, 0.0), (1, 0, 0)), "a constant primvar inherited from an ancestor"
    assert _is(_rgb(result, 2.5), (0, 1, 0)), "the reader's fallback"
    assert not result.warnings, result.warnings  # Storm says nothing of a missing primvar with a reader


def test_a_reader_without_a_fallback_reads_zero_where_the_primvar_is_missing():
    stage = _stage()
    material = _reader_material(stage, "/Looks/Tint")
    UsdShade.MaterialBindingAPI(_quad(stage, "/World/Missing", 0.0).GetPrim()).Bind(material)
    c = np.asarray(_render(stage)["color"].pixels[50, 100, :3])
    assert np.ptp(c) < 0.01 and c.max() < 0.1, f"black (but for the grey specular), as Storm draws it, not magenta: {c}"


def test_a_vertex_primvar_through_an_interface_input_varies_across_the_mesh():
    stage = _stage()
    material = _reader_material(stage, "/Looks/Shade", reader="UsdPrimvarReader_float", varname="shade", interface=True,
                                fallback=0.5)
    quad = _quad(stage, "/World/Ramp", 0.0, size=3.0)
    UsdGeom.PrimvarsAPI(quad).CreatePrimvar("shade", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set([0.05, 1, 1, 0.05])
    UsdShade.MaterialBindingAPI(quad.GetPrim()).Bind(material)
    result = _render(stage)
    left, right = (result["color"].pixels[50, int(100 + 25 * x), :3] for x in (-1.3, 1.3))
    assert _is(_rgb(result, -1.3), (1, 1, 1)) and _is(_rgb(result, 1.3), (1, 1, 1)), "a float reads as grey"
    assert right.mean() > 5 * left.mean(), (left, right)


def test_a_uniform_primvar_colours_each_face():
    stage = _stage()
    material = _reader_material(stage, "/Looks/Tint")
    mesh = UsdGeom.Mesh.Define(stage, "/World/Two")
    mesh.GetPointsAttr().Set([(-2, -1, 0), (0, -1, 0), (2, -1, 0), (2, 1, 0), (0, 1, 0), (-2, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4, 4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 4, 5, 1, 2, 3, 4])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform).Set(
        [(1, 0, 0), (0, 0, 1)])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    result = _render(stage)
    assert _is(_rgb(result, -1.0), (1, 0, 0)) and _is(_rgb(result, 1.0), (0, 0, 1))


def test_display_color_is_read_only_where_it_drives_diffuse_color():
    stage = _stage()
    constant = UsdShade.Material.Define(stage, "/Looks/Constant")
    surface = UsdShade.Shader.Define(stage, "/Looks/Constant/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 1))
    constant.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reads = _reader_material(stage, "/Looks/Reads", varname="displayColor")
    for x, material in ((-2.5, constant), (0.0, reads), (2.5, None)):
        quad = _quad(stage, f"/World/Q{int(x * 10 + 25)}", x)
        quad.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set([(1, 0, 0), (1, 0, 0), (0, 1, 0), (0, 1, 0)])
        if material:
            UsdShade.MaterialBindingAPI(quad.GetPrim()).Bind(material)
    result = _render(stage)
    assert _is(_rgb(result, -2.5), (0, 0, 1)), "the constant diffuseColor, no displayColor read"
    for x, what in ((0.0, "displayColor, per vertex"), (2.5, "no material: displayColor")):
        low, high = _rgb(result, x, -0.6), _rgb(result, x, 0.6)  # 1/8 of the way from one row's colour to the other's
        assert low[0] > 0.9 > 0.4 > low[1] and high[1] > 0.9 > 0.4 > high[0] and low[2] < 0.1 > high[2], (what, low, high)


def _textured_material(stage, path):
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    texture = UsdShade.Shader.Define(stage, f"{path}/Texture")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("missing.png")  # the fallback is drawn, st still read
    texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    reader = UsdShade.Shader.Define(stage, f"{path}/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(texture.ConnectableAPI(), "rgb")
    return material


@pytest.mark.parametrize("material", ["untextured", "textured", "none"])
def test_uvs_are_uploaded_only_for_a_texture_that_reads_them(material):
    """The same grid with and without a face-varying st: its UVs (seams split vertices) cost geometry memory only
    when its material has a texture that reads them. The `uv` debug view reads every mesh's st (magenta where it has
    none)."""
    sizes, magenta = {}, {}
    for with_st in (False, True):
        stage = _stage()
        grid = UsdGeom.Mesh.Define(stage, "/World/Grid")
        n = 8
        grid.GetPointsAttr().Set([(x / n * 3 - 1.5, y / n * 3 - 1.5, 0) for y in range(n + 1) for x in range(n + 1)])
        grid.GetFaceVertexCountsAttr().Set([4] * n * n)
        grid.GetFaceVertexIndicesAttr().Set([i for y in range(n) for x in range(n) for i in
                                             (y * (n + 1) + x, y * (n + 1) + x + 1, (y + 1) * (n + 1) + x + 1, (y + 1) * (n + 1) + x)])
        if with_st:  # one UV island per face: every corner is its own vertex
            st = UsdGeom.PrimvarsAPI(grid).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
            st.Set([(0, 0), (1, 0), (1, 1), (0, 1)] * n * n)
        if material != "none":
            bound = _textured_material(stage, "/Looks/M") if material == "textured" else _reader_material(
                stage, "/Looks/M", fallback=Gf.Vec3f(0.5, 0.5, 0.5))
            UsdShade.MaterialBindingAPI.Apply(grid.GetPrim()).Bind(bound)
        session = tessera.Session(stage, validation=True)
        result = session.render(camera="/Camera", resolution=RESOLUTION)
        sizes[with_st] = result.stats["geometry_bytes"]
        vis = session.render(camera="/Camera", resolution=RESOLUTION, vis="uv")["color"].pixels[50, 100, :3]
        magenta[with_st] = vis[0] > 0.5 and vis[2] > 0.5 and vis[1] < 0.1
    if material == "textured":
        assert sizes[True] > sizes[False], sizes
    else:
        assert sizes[True] == sizes[False], sizes
    assert magenta == {False: True, True: False}, magenta


def test_an_edit_of_what_a_material_reads_re_reads_its_meshes_primvars():
    stage = _stage()
    material = _reader_material(stage, "/Looks/Tint", interface=True)
    quad = _quad(stage, "/World/Quad", 0.0)
    for name, colour in (("tint", (0, 0, 1)), ("other", (1, 0, 0))):
        UsdGeom.PrimvarsAPI(quad).CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([colour])
    UsdShade.MaterialBindingAPI(quad.GetPrim()).Bind(material)
    session = tessera.Session(stage, validation=True)
    render = lambda: session.render(camera="/Camera", resolution=RESOLUTION)
    assert _is(_rgb(render(), 0.0), (0, 0, 1))
    material.GetInput("primvarName").Set("other")  # the Material's interface input names another primvar
    result = render()
    assert dict(session.index.last_synced) == {"/Looks/Tint": _tessera.dirty.PARAMS, "/World/Quad": _tessera.dirty.PRIMVAR}
    assert _is(_rgb(result, 0.0), (1, 0, 0))
    material.GetInput("roughness") or UsdShade.Shader(stage.GetPrimAtPath("/Looks/Tint/Surface")).CreateInput(
        "roughness", Sdf.ValueTypeNames.Float).Set(0.2)  # reads nothing new: the material alone
    render()
    assert dict(session.index.last_synced) == {"/Looks/Tint": _tessera.dirty.PARAMS}


def test_the_fallback_surface_inherits_a_constant_display_color_and_follows_its_edits():
    """A mesh with no material and no displayColor of its own takes a constant one authored on an ancestor, as
    UsdImaging's primvar inheritance gives it; its own wins. An edit of the ancestor's primvar re-reads the meshes below
    it (and only those), and so does an edit of a primvar a reader inherits."""
    from tessera.usd import ChangeTracker

    stage = _stage()
    group = UsdGeom.PrimvarsAPI(UsdGeom.Xform.Define(stage, "/World/Group"))
    group.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(1, 0, 0)])
    group.CreatePrimvar("tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(0, 0, 1)])
    inherits = _quad(stage, "/World/Group/Inherits", -3.0)
    own = _quad(stage, "/World/Group/Own", -1.0)
    own.CreateDisplayColorAttr([(0, 1, 0)])
    tinted = _quad(stage, "/World/Group/Tinted", 1.0)
    UsdShade.MaterialBindingAPI(tinted.GetPrim()).Bind(_reader_material(stage, "/Looks/Tint", fallback=Gf.Vec3f(1, 1, 1)))
    _quad(stage, "/World/Outside", 3.0)

    session = tessera.Session(stage, validation=True)
    tracker = ChangeTracker(stage)

    def render():
        session.scene.apply_changes(*tracker.take())
        result = session.render(camera="/Camera", resolution=RESOLUTION)
        assert not result.errors, result.errors
        return result

    result = render()
    assert _is(_rgb(result, -3.0), (1, 0, 0)), "inherited from /World/Group"
    assert _is(_rgb(result, -1.0), (0, 1, 0)), "its own displayColor wins"
    assert _is(_rgb(result, 1.0), (0, 0, 1)), "the reader's inherited primvar"
    assert _is(_rgb(result, 3.0), (1, 1, 1)), "Hydra's grey outside the group"

    group.GetPrimvar("displayColor").Set([(1, 1, 0)])
    group.GetPrimvar("tint").Set([(0, 1, 1)])
    result = render()
    assert _is(_rgb(result, -3.0), (1, 1, 0)) and _is(_rgb(result, 1.0), (0, 1, 1)), "edits of the ancestor's primvars"
    assert set(session.index.last_synced) == {"/World/Group/Inherits", "/World/Group/Own", "/World/Group/Tinted"}

    group.CreatePrimvar("unread", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.constant).Set([0.5])
    render()
    assert not session.index.last_synced, "a primvar no material reads dirties nothing"
    group.GetPrimvar("tint").Set([(1, 0, 1)])
    result = render()
    assert set(session.index.last_synced) == {"/World/Group/Tinted"}, "only the mesh whose reader reads it"
    assert _is(_rgb(result, 1.0), (1, 0, 1))
