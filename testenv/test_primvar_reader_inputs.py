"""UsdPrimvarReader nodes driving UsdPreviewSurface inputs other than diffuseColor (emissiveColor, specularColor,
metallic, roughness, opacity under a threshold, occlusion), as Storm reads them: a primvar that varies over the mesh is
packed into the mesh's vertex channel and interpolated over the surface (plugin/usd/vertex_channel.py, the material's
vertex_inputs, shaders/surface.h `vertex_input`); a constant primvar, or the reader's fallback where the mesh lacks it,
is folded into a copy of the material and costs nothing per vertex."""

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

import tessera
from conftest import stage_with_camera

RESOLUTION = (200, 100)  # the camera sees x in [-4, 4], y in [-2, 2]: 25 pixels per unit
_TYPES = {1: Sdf.ValueTypeNames.Float, 3: Sdf.ValueTypeNames.Color3f}
_READERS = {1: "UsdPrimvarReader_float", 3: "UsdPrimvarReader_float3"}


def _stage():
    stage = stage_with_camera()
    return stage


def _quad(stage, path, x=0.0, size=3.0, material=None):
    h = size / 2
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x - h, -h, 0), (x + h, -h, 0), (x + h, h, 0), (x - h, h, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _material(stage, path, constants=None, readers=None):
    """A preview surface with `constants` {input: value} and `readers` {input: (varname, components, fallback or None)}."""
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    for name, value in (constants or {}).items():
        kind = Sdf.ValueTypeNames.Color3f if isinstance(value, tuple) else Sdf.ValueTypeNames.Float
        surface.CreateInput(name, kind).Set(Gf.Vec3f(*value) if isinstance(value, tuple) else value)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    for name, (varname, components, fallback) in (readers or {}).items():
        node = UsdShade.Shader.Define(stage, f"{path}/Read_{name}")
        node.CreateIdAttr(_READERS[components])
        node.CreateOutput("result", _TYPES[components])
        node.CreateInput("varname", Sdf.ValueTypeNames.String).Set(varname)
        if fallback is not None:
            node.CreateInput("fallback", _TYPES[components]).Set(Gf.Vec3f(*fallback) if components == 3 else fallback)
        surface.CreateInput(name, _TYPES[components]).ConnectToSource(node.ConnectableAPI(), "result")
    return material


def _primvar(mesh, name, values, interpolation=UsdGeom.Tokens.vertex):
    kind = Sdf.ValueTypeNames.Color3fArray if isinstance(values[0], tuple) else Sdf.ValueTypeNames.FloatArray
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(name, kind, interpolation).Set(values)


def _render(stage, **kwargs):
    result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=RESOLUTION, **kwargs)
    assert not result.errors, result.errors
    return result


def _pixel(result, x, y=0.0):
    return np.asarray(result["color"].pixels[int(50 - 25 * y), int(100 + 25 * x), :3], np.float64)


def test_a_vertex_primvar_drives_emissive_color_across_a_quad():
    stage = _stage()
    look = _material(stage, "/Looks/Glow", {"diffuseColor": (0.0, 0.0, 0.0)}, {"emissiveColor": ("glow", 3, None)})
    quad = _quad(stage, "/World/Quad", material=look)
    _primvar(quad, "glow", [(4, 0, 0), (0, 0, 4), (0, 0, 4), (4, 0, 0)])  # red on the left, blue on the right
    result = _render(stage)
    left, middle, right = _pixel(result, -1.4), _pixel(result, 0.0), _pixel(result, 1.4)
    assert left[0] > 3.0 and left[2] < 0.5, left
    assert right[2] > 3.0 and right[0] < 0.5, right
    assert abs(middle[0] - middle[2]) < 0.4 and 1.5 < middle[0] < 2.5, f"interpolated halfway: {middle}"


# Per input: the other constants and a light that make the input show. Roughness shows in a mirror-like metal's
# reflection of a small sphere light in front of the quad (sharp: nothing at the edges; rough: a broad glow).
_SETUPS = {"roughness": ({"diffuseColor": (1.0, 1.0, 1.0), "metallic": 1.0}, True),
           "metallic": ({"diffuseColor": (0.8, 0.3, 0.3)}, False),
           "occlusion": ({"diffuseColor": (0.8, 0.8, 0.8)}, False)}


def _scalar_stage(name, constants, light):
    stage = _stage()
    if light:
        sphere = UsdLux.SphereLight.Define(stage, "/Light")
        sphere.AddTranslateOp().Set(Gf.Vec3d(0, 0, 4))
        sphere.CreateRadiusAttr(0.3)
        sphere.CreateIntensityAttr(200.0)
    return stage


@pytest.mark.parametrize("name", sorted(_SETUPS))
def test_a_vertex_primvar_drives_a_scalar_input_per_vertex(name):
    """The left edge of a quad whose primvar goes from 0 to 1 shades as a constant 0 does, its right edge as 1."""
    constants, light = _SETUPS[name]
    stage = _scalar_stage(name, constants, light)
    quad = _quad(stage, "/World/Quad", material=_material(stage, "/Looks/Vary", constants, {name: ("amount", 1, None)}))
    _primvar(quad, "amount", [0.0, 1.0, 1.0, 0.0])
    varying = _render(stage)
    for value, x in ((0.0, -1.45), (1.0, 1.45)):  # 1/60 of the way in from each edge
        flat = _scalar_stage(name, constants, light)
        _quad(flat, "/World/Quad", material=_material(flat, "/Looks/Flat", {**constants, name: value}))
        constant = _render(flat)
        near, expected, far = _pixel(varying, x), _pixel(constant, x), _pixel(varying, -x)
        assert np.allclose(near, expected, rtol=0.08, atol=0.01), (name, value, near, expected)
        assert not np.allclose(far, _pixel(constant, -x), rtol=0.08, atol=0.01), (name, value, far, _pixel(constant, -x))


def test_a_constant_primvar_and_a_missing_one_fold_into_the_material_at_no_cost_per_vertex():
    stage = _stage()
    look = _material(stage, "/Looks/Glow", {"diffuseColor": (0.0, 0.0, 0.0)},
                     {"emissiveColor": ("glow", 3, (0.0, 2.0, 0.0)), "roughness": ("rough", 1, 0.25)})
    authored = _quad(stage, "/World/Constant", x=-2.0, size=1.6, material=look)
    _primvar(authored, "glow", [(2.0, 0.0, 0.0)], UsdGeom.Tokens.constant)
    _quad(stage, "/World/Missing", x=2.0, size=1.6, material=look)  # the reader's fallbacks
    result = _render(stage)
    constant, missing = _pixel(result, -2.0), _pixel(result, 2.0)
    assert constant[0] > 1.5 and constant[1] < 0.3, f"the constant primvar: red {constant}"
    assert missing[1] > 1.5 and missing[0] < 0.3, f"the fallback: green {missing}"

    plain = _stage()
    flat = _material(plain, "/Looks/Flat", {"diffuseColor": (0.0, 0.0, 0.0), "emissiveColor": (2.0, 0.0, 0.0)})
    _quad(plain, "/World/Constant", x=-2.0, size=1.6, material=flat)
    _quad(plain, "/World/Missing", x=2.0, size=1.6, material=flat)
    assert result.stats["geometry_bytes"] == _render(plain).stats["geometry_bytes"], "no vertex channel uploaded"


@pytest.mark.parametrize("raster,displaced", [("software", False), ("hardware", False), ("software", True)])
def test_opacity_per_vertex_under_a_threshold_cuts_the_surface(raster, displaced):
    """Both cluster rasterizers and, on a displaced surface, the patch rasterizers test the interpolated opacity."""
    stage = _stage()
    look = _material(stage, "/Looks/Cut", {"diffuseColor": (0.8, 0.8, 0.8), "opacityThreshold": 0.5},
                     {"opacity": ("alpha", 1, None)})
    if displaced:  # a constant offset towards the camera: every cluster is diced
        surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Cut/Surface"))
        surface.CreateInput("displacement", Sdf.ValueTypeNames.Float).Set(0.05)
        look.CreateDisplacementOutput().ConnectToSource(surface.ConnectableAPI(), "displacement")
    quad = _quad(stage, "/World/Quad", material=look)
    _primvar(quad, "alpha", [0.0, 1.0, 1.0, 0.0])  # below the threshold on the left half
    result = _render(stage, aovs=("color", "primId"), raster=raster)  # both rasterizers run the mask test
    ids = np.asarray(result["primId"].pixels)[50, :, 0]
    covered = np.flatnonzero(~np.isnan(ids))  # NaN: background
    assert len(covered), "the right half is drawn"
    assert abs(covered.min() - 100) <= 2 and abs(covered.max() - 137) <= 2, (covered.min(), covered.max())
    if displaced:
        assert result.stats["tessellation_bytes"] > 0, "the surface was diced"


def test_several_primvars_of_different_interpolations_share_the_channel():
    """emissiveColor from a vertex primvar and roughness from a uniform one: 3 + 1 components, expanded to face-varying;
    each input reads its own components."""
    stage = _stage()
    look = _material(stage, "/Looks/Two", {"diffuseColor": (0.0, 0.0, 0.0)},
                     {"emissiveColor": ("glow", 3, None), "roughness": ("rough", 1, 0.5)})
    mesh = UsdGeom.Mesh.Define(stage, "/World/Two")
    mesh.GetPointsAttr().Set([(-2, -1, 0), (0, -1, 0), (2, -1, 0), (2, 1, 0), (0, 1, 0), (-2, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4, 4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 4, 5, 1, 2, 3, 4])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(look)
    _primvar(mesh, "glow", [(3, 0, 0), (3, 0, 0), (0, 0, 3), (0, 0, 3), (3, 0, 0), (3, 0, 0)])
    _primvar(mesh, "rough", [0.1, 0.9], UsdGeom.Tokens.uniform)
    result = _render(stage)
    assert result.stats["geometry_bytes"] > 0
    left, right = _pixel(result, -1.8), _pixel(result, 1.8)
    assert left[0] > 2.5 and left[2] < 0.3, left
    assert right[2] > 2.5 and right[0] < 0.3, right


def test_inputs_beyond_the_channel_warn_and_take_their_default():
    stage = _stage()
    look = _material(stage, "/Looks/Many", {}, {"diffuseColor": ("tint", 3, None), "emissiveColor": ("glow", 3, None)})
    quad = _quad(stage, "/World/Quad", material=look)
    _primvar(quad, "tint", [(1, 0, 0)] * 4)
    _primvar(quad, "glow", [(0, 0, 5)] * 4)
    session = tessera.Session(stage, validation=True)
    result = session.render(camera="/Camera", resolution=RESOLUTION)
    assert any("/Looks/Many" in w and "emissiveColor" in w and "4 components" in w for w in result.warnings), result.warnings
    c = _pixel(result, 0.0)
    assert c[0] > 0.3 and c[2] < 0.1, f"diffuseColor red from its primvar, emissiveColor its default (black), not blue: {c}"


def test_geom_subset_materials_reading_different_primvars_are_a_warning_naming_the_mesh():
    stage = _stage()
    glow = _material(stage, "/Looks/Glow", {"diffuseColor": (0.0, 0.0, 0.0)}, {"emissiveColor": ("glow", 3, None)})
    rough = _material(stage, "/Looks/Rough", {}, {"roughness": ("rough", 1, 0.5)})
    mesh = UsdGeom.Mesh.Define(stage, "/World/Two")
    mesh.GetPointsAttr().Set([(-2, -1, 0), (0, -1, 0), (2, -1, 0), (2, 1, 0), (0, 1, 0), (-2, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4, 4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 4, 5, 1, 2, 3, 4])
    _primvar(mesh, "glow", [(3, 0, 0)] * 6)
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for name, faces, material in (("Left", [0], glow), ("Right", [1], rough)):
        subset = binding.CreateMaterialBindSubset(name, [faces[0]])
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)
    result = tessera.Session(stage, validation=True).render(camera="/Camera", resolution=RESOLUTION)
    assert any(w.startswith("/World/Two:") and "/Looks/Rough" in w and "/Looks/Glow" in w for w in result.warnings), result.warnings
    assert _pixel(result, -1.0)[0] > 2.5, "the first material's channel is read"
