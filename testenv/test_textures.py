"""UsdPreviewSurface textures: what the scene delegate reads from a UsdUVTexture network (file resolved against the
layer that authored it, wrap modes, scale, bias, fallback, colour space, output channel, UsdTransform2d, the primvar
reader's varname through a material interface input), and how the renderer treats missing and shared files."""

import struct
import zlib

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from tessera import _tessera

NO_HIT = 0xFFFFFFFF


def write_png(path, rgba: np.ndarray) -> None:
    """An 8-bit RGBA PNG (rows top first), written with zlib alone."""
    height, width, _ = rgba.shape
    raw = b"".join(b"\0" + rgba[y].astype(np.uint8).tobytes() for y in range(height))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def checker(size=8, a=(255, 255, 255, 255), b=(0, 0, 0, 255)) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size]
    return np.where(((x + y) % 2 == 0)[..., None], np.array(a), np.array(b))


def _quad(stage, path, x=0.0):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x - 0.4, -0.4, 0), (x + 0.4, -0.4, 0), (x + 0.4, 0.4, 0), (x - 0.4, 0.4, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st1", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    return mesh


def _camera(stage, aperture=10.0):
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    camera.GetHorizontalApertureAttr().Set(aperture * 4)
    camera.GetVerticalApertureAttr().Set(aperture)


def _textured_material(stage, path, file, *, input_name="diffuseColor", output="rgb", **texture_inputs):
    """A preview surface whose `input_name` reads `output` of a UsdUVTexture of `file`, its st from primvar st1 (named
    by the material's interface input uvSet) through a UsdTransform2d."""
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    texture = UsdShade.Shader.Define(stage, f"{path}/Texture")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    for name, (kind, value) in texture_inputs.items():
        texture.CreateInput(name, kind).Set(value)
    kind = Sdf.ValueTypeNames.Color3f if output == "rgb" else Sdf.ValueTypeNames.Float
    surface.CreateInput(input_name, kind).ConnectToSource(texture.ConnectableAPI(), output)
    transform = UsdShade.Shader.Define(stage, f"{path}/Transform")
    transform.CreateIdAttr("UsdTransform2d")
    transform.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(90.0)
    transform.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(2, 3))
    transform.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(0.25, 0.5))
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(transform.ConnectableAPI(), "result")
    reader = UsdShade.Shader.Define(stage, f"{path}/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    uv_set = material.CreateInput("uvSet", Sdf.ValueTypeNames.Token)
    uv_set.Set("st1")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).ConnectToSource(uv_set)
    transform.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    return material


def test_a_uv_texture_network_becomes_a_texture_slot(tmp_path):
    # The material lives in a layer of its own, in another folder; its texture path is relative to that layer.
    (tmp_path / "asset" / "tex").mkdir(parents=True)
    write_png(tmp_path / "asset" / "tex" / "checker.png", checker())
    looks = Usd.Stage.CreateNew(str(tmp_path / "asset" / "looks.usda"))
    _textured_material(looks, "/Looks/Checker", "./tex/checker.png", output="rgb",
                       wrapS=(Sdf.ValueTypeNames.Token, "mirror"), wrapT=(Sdf.ValueTypeNames.Token, "black"),
                       scale=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(2, 2, 2, 1)), bias=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(-1, -1, -1, 0)),
                       fallback=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.1, 0.2, 0.3, 1)),
                       sourceColorSpace=(Sdf.ValueTypeNames.Token, "raw"))
    _textured_material(looks, "/Looks/Broken", "./tex/missing.png")
    looks.GetRootLayer().Save()
    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    stage.DefinePrim("/Looks").GetReferences().AddReference("./asset/looks.usda", "/Looks")
    _quad(stage, "/Quad")
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Quad")).Bind(UsdShade.Material(stage.GetPrimAtPath("/Looks/Checker")))

    from tessera.usd import UsdSceneDelegate

    index = _tessera.RenderIndex(_tessera.RenderDelegate(validation=True))
    delegate = UsdSceneDelegate(stage, index)
    desc = delegate.get_material("/Looks/Checker")
    assert not delegate.warnings, delegate.warnings
    (slot,) = desc.textures
    assert slot.input == _tessera.MaterialInput.diffuseColor
    assert slot.file == str(tmp_path / "asset" / "tex" / "checker.png"), "resolved against the layer that authored it"
    assert slot.channel == _tessera.TextureChannel.rgb
    assert (slot.wrap_s, slot.wrap_t) == (_tessera.TextureWrap.mirror, _tessera.TextureWrap.black)
    assert slot.color_space == _tessera.ColorSpace.raw
    assert tuple(slot.scale) == (2, 2, 2, 1) and tuple(slot.bias) == (-1, -1, -1, 0)
    assert np.allclose(slot.fallback, (0.1, 0.2, 0.3, 1))
    # UsdTransform2d: scale (2, 3), rotate 90 degrees, translate (0.25, 0.5): st' = (-3 t + 0.25, 2 s + 0.5).
    assert np.allclose(slot.transform, (0, -3, 0.25, 2, 0, 0.5), atol=1e-6), list(slot.transform)
    assert desc.uv_primvar == "st1", "the reader's varname, through the material's interface input"
    assert delegate.uv_primvar(stage.GetPrimAtPath("/Quad")) == "st1", "the UV set the quad is built with"
    _quad(stage, "/Unbound", 2.0)
    assert delegate.uv_primvar(stage.GetPrimAtPath("/Unbound")) is None, "no texture reads its UVs: none are read"
    # A file the resolver cannot find is still named by its path next to the layer that authored it.
    (broken,) = delegate.get_material("/Looks/Broken").textures
    assert broken.file == str(tmp_path / "asset" / "tex" / "missing.png")


def test_texture_inputs_defaults_channels_and_constant_st(tmp_path):
    write_png(tmp_path / "grey.png", checker())
    stage = Usd.Stage.CreateInMemory()
    material = _textured_material(stage, "/Looks/Rough", str(tmp_path / "grey.png"), input_name="roughness", output="g")
    # A chain of two transforms over a constant st (no primvar): the inner one moves s by 1.
    inner = UsdShade.Shader.Define(stage, "/Looks/Rough/Inner")
    inner.CreateIdAttr("UsdTransform2d")
    inner.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(1, 0))
    inner.CreateInput("in", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(0.3, 0.7))
    transform = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Rough/Transform"))
    transform.GetInput("in").ConnectToSource(inner.ConnectableAPI(), "result")
    from tessera.usd import materials

    warnings = []
    desc = materials.material_desc(material.GetPrim(), Usd.TimeCode.Default(), warnings)
    assert not warnings, warnings
    (slot,) = desc.textures
    assert slot.input == _tessera.MaterialInput.roughness and slot.channel == _tessera.TextureChannel.g
    assert (slot.wrap_s, slot.wrap_t) == (_tessera.TextureWrap.repeat, _tessera.TextureWrap.repeat), "useMetadata reads as repeat"
    assert slot.color_space == _tessera.ColorSpace.auto
    assert tuple(slot.scale) == (1, 1, 1, 1) and tuple(slot.bias) == (0, 0, 0, 0) and tuple(slot.fallback) == (0, 0, 0, 1)
    # A constant st: (0.3, 0.7), moved to (1.3, 0.7), then (-3 t + 0.25, 2 s + 0.5) = (-1.85, 3.1), whatever the primvars.
    assert np.allclose(slot.transform, (0, 0, -1.85, 0, 0, 3.1), atol=1e-6), list(slot.transform)
    assert desc.uv_primvar == "", "no primvar reader, no UV set"


def test_unsupported_connections_and_values_are_named():
    stage = Usd.Stage.CreateInMemory()
    material = _textured_material(stage, "/Looks/Odd", "x.png", wrapS=(Sdf.ValueTypeNames.Token, "sideways"))
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Odd/Surface"))
    noise = UsdShade.Shader.Define(stage, "/Looks/Odd/Noise")
    noise.CreateIdAttr("SomeNoise")
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).ConnectToSource(noise.ConnectableAPI(), "out")
    from tessera.usd import materials

    warnings = []
    desc = materials.material_desc(material.GetPrim(), Usd.TimeCode.Default(), warnings)
    assert desc.metallic == 0.0
    assert any("/Looks/Odd" in w and "sideways" in w for w in warnings), warnings
    assert any("metallic" in w and "/Looks/Odd/Noise" in w for w in warnings), warnings


def _missing_texture_stage(tmp_path):
    stage = Usd.Stage.CreateInMemory()
    _camera(stage)
    UsdLux.DomeLight.Define(stage, "/Dome").CreateIntensityAttr(1.0)
    for name, x in (("Missing", -1.0), ("Plain", 1.0)):
        _quad(stage, f"/{name}", x)
    material = _textured_material(stage, "/Looks/Missing", str(tmp_path / "nowhere" / "wood.png"),
                                  fallback=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.25, 0.5, 0.75, 1)))
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Missing")).Bind(material)
    return stage


def test_a_missing_texture_warns_naming_file_and_material_and_the_stage_renders(render, tmp_path):
    result = render(_missing_texture_stage(tmp_path), resolution=(160, 40), aovs=("color", "primId"))
    missing = str(tmp_path / "nowhere" / "wood.png")
    named = [w for w in result.warnings if missing in w and "/Looks/Missing" in w]
    assert named, result.warnings
    ids, color = result["primId"].ids(), result["color"].pixels
    assert result.prim_path(int(ids[20, 40])) == "/Missing" and result.prim_path(int(ids[20, 120])) == "/Plain"
    # The fallback is the diffuse colour: in a uniform dome of radiance 1 a quad seen head on returns its albedo plus
    # a few percent of grey specular (the default ior), the same in every channel.
    specular = color[20, 40, :3] - (0.25, 0.5, 0.75)
    assert 0.01 < specular[0] < 0.1 and np.allclose(specular, specular[0], atol=1e-4), color[20, 40]
    assert result.stats["textures"] == 0 and result.stats["texture_bytes"] == 0, "an unreadable file takes no texture memory"


def test_texture_memory_is_zero_without_textures_and_shared_files_are_stored_once(render, tmp_path):
    stage = Usd.Stage.CreateInMemory()
    _camera(stage)
    _quad(stage, "/Untextured")
    assert render(stage, resolution=(32, 32)).stats["texture_bytes"] == 0

    write_png(tmp_path / "checker.png", checker(8))
    for name, x in (("A", -1.0), ("B", 1.0)):
        _quad(stage, f"/{name}", x)
        material = _textured_material(stage, f"/Looks/{name}", str(tmp_path / "checker.png"))
        UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(f"/{name}")).Bind(material)
    stats = render(stage, resolution=(32, 32)).stats
    assert stats["textures"] == 1, "two materials reading one file share one image"
    # The record, an 8x8 RGBA8 chain (64 + 16 + 4 + 1 texels of 4 bytes) and two 64-byte slots.
    assert stats["texture_bytes"] == 16 + 4 * (64 + 16 + 4 + 1) + 2 * 64


# ---- Image tests ----

def _per_unit(width):
    """Pixels per scene unit at depth 9 for testTextures' camera (35 mm over a 36 mm aperture)."""
    return 35.0 / 18.0 / 9.0 * (width / 2.0)


def _prim_mask(result, path):
    ids = result["primId"].ids()
    prim = next(i for i in np.unique(ids) if i != NO_HIT and result.prim_path(int(i)) == path)
    return ids == prim


def test_textured_materials(render, tmp_path):
    """testTextures: a repeated checker, the three wrap modes besides repeat, a receding checker floor, a textured
    opacity mask and a normal map with a roughness ramp, against the baseline, plus what each must show."""
    from imagecompare import assert_matches_baseline
    from conftest import TESTENV

    width, height = 480, 320
    result = render(TESTENV / "testTextures" / "textures.usda", resolution=(width, height), aovs=("color", "primId"))
    assert not result.warnings, result.warnings
    out = tmp_path / "textures.png"
    result.write(out)
    assert_matches_baseline(out, TESTENV / "testTextures" / "baseline" / "textures.png")
    assert result.stats["textures"] == 5, "checker.png and orientation.png are each read once however many materials use them"

    color = np.asarray(result["color"].pixels)
    per_unit = _per_unit(width)

    def pixel(x, y):  # a scene point on the z = 0 plane
        return color[int(height / 2 - y * per_unit), int(width / 2 + x * per_unit), :3]

    # Black: outside st 0..1 the texture is 0, so scale and bias leave exactly the bias.
    assert np.array_equal(pixel(3.3 - 0.8, 1.3 + 0.8), np.float32([0, 0, 0.2]))
    # Mirror and clamp agree inside st 0..1: at their centres, rows are alike (green follows t exactly); the pixel
    # columns fall half a pixel either side of the centres (red follows s, about 0.06 a pixel there).
    assert abs(pixel(-1.1, 1.3)[1] - pixel(1.1, 1.3)[1]) < 1e-5
    assert np.allclose(pixel(-1.1, 1.3), pixel(1.1, 1.3), atol=0.04)
    # Clamp: the blue block at st (0, 0) stretches over the whole lower-left third; sRGB (40, 80, 255) decoded.
    assert np.allclose(pixel(1.1 - 0.8, 1.3 - 0.8), [0.0212, 0.0802, 1.0], atol=2e-3), pixel(1.1 - 0.8, 1.3 - 0.8)
    # Mirror: st (-0.6, 0.6) reads what (0.6, 0.6) reads. The wrap cards span st -1..2 over 1.8 units.
    def card(x, y, s, t):
        return pixel(x - 0.9 + (s + 1) / 3 * 1.8, y - 0.9 + (t + 1) / 3 * 1.8)

    mirrored, direct = card(-1.1, 1.3, -0.6, 0.6), card(-1.1, 1.3, 0.6, 0.6)
    assert np.allclose(mirrored, direct, atol=0.03), (mirrored, direct)
    assert not np.allclose(card(1.1, 1.3, -0.6, 0.6), direct, atol=0.1), "clamp does not mirror"

    # The mask: the red card shows through the hole's centre, the orange card's corner is drawn.
    ids = result["primId"].ids()
    hole_x, hole_y = int(width / 2 + 1.2 * per_unit * 9 / 8.5), int(height / 2 + 1.4 * per_unit * 9 / 8.5)
    assert result.prim_path(int(ids[hole_y, hole_x])) == "/Cards/BehindTheHole"
    corner_x = int(width / 2 + (1.2 - 0.8) * per_unit * 9 / 8.5)
    assert result.prim_path(int(ids[hole_y, corner_x])) == "/Cards/Hole"

    # The floor: near rows alternate between the checker's colours; far rows, where a pixel covers many cells, are
    # their average (the mip chain), not a sample of one cell or the other (aliasing).
    floor = _prim_mask(result, "/Cards/Floor")
    rows = [y for y in range(height) if floor[y].sum() >= 20]
    near, far = rows[-1], rows[0]
    assert color[near][floor[near]][:, 1].std() > 0.15, "near the camera the checker's cells show"
    assert color[far][floor[far]][:, 1].std() < 0.02, "far away the cells average out"


@pytest.mark.parametrize("asset, stage_file", [("TextureCoordinateTest", "TextureCoordinateTest.usda"),
                                               ("TextureTransformTest", "TextureTransformTest.usd")])
def test_usd_wg_texture_assets(render, tmp_path, asset, stage_file):
    """The USD Working Group's texture tests: st orientation per card (TextureCoordinateTest) and UsdTransform2d
    offsets, rotation and scale (TextureTransformTest), framed like usdview; the baselines were checked against the
    assets' own screenshots."""
    from conftest import TESTENV, shared_asset
    from imagecompare import assert_matches_baseline

    stage = shared_asset(f"usd-wg/test_assets/{asset}/{stage_file}")
    result = render(stage, resolution=(256, 256), camera=None)
    assert not result.warnings, result.warnings
    out = tmp_path / f"{asset}.png"
    result.write(out)
    assert_matches_baseline(out, TESTENV / "testTextures" / "baseline" / f"{asset}.png")


def test_both_rasterizers_cut_a_textured_mask_at_the_same_pixels(tmp_path):
    """A finely tessellated card with a round hole from its texture's alpha: small triangles, so the compute
    rasterizer takes them (in each of its variants: shared vertices, each thread its own corners); forced through
    hardware raster instead, the same pixels are cut."""
    import tessera
    from conftest import TESTENV

    stage = Usd.Stage.CreateInMemory()
    _camera(stage, aperture=12.0)
    n = 24
    mesh = UsdGeom.Mesh.Define(stage, "/Card")
    points, st = [], []
    for j in range(n + 1):
        for i in range(n + 1):
            points.append((i / n * 2 - 1, j / n * 2 - 1, 0))
            st.append((i / n, j / n))
    mesh.GetPointsAttr().Set(points)
    mesh.GetFaceVertexCountsAttr().Set([4] * n * n)
    mesh.GetFaceVertexIndicesAttr().Set([v for j in range(n) for i in range(n)
                                         for v in (j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)])
    mesh.GetSubdivisionSchemeAttr().Set("none")
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(st)
    behind = _quad(stage, "/Behind")
    behind.AddTranslateOp().Set(Gf.Vec3d(0, 0, -1))
    material = _textured_material(stage, "/Looks/Hole", str(TESTENV / "testTextures" / "hole.png"), input_name="opacity", output="a")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/Hole/Surface")).CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    material.GetInput("uvSet").Set("st")
    transform = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Hole/Transform"))
    transform.GetInput("rotation").Set(0.0)
    transform.GetInput("scale").Set(Gf.Vec2f(1, 1))
    transform.GetInput("translation").Set(Gf.Vec2f(0, 0))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)

    session = tessera.Session(stage, validation=True)
    renders = {"hardware": ("hardware", "auto"), "shared": ("software", "shared"), "per-triangle": ("software", "per-triangle")}
    results = {name: session.render(camera="/Camera", resolution=(240, 240), aovs=("primId",), raster=raster,
                                    raster_vertices=vertices, lod=False) for name, (raster, vertices) in renders.items()}
    for result in results.values():
        assert not result.errors, result.errors
    assert results["hardware"].stats["sw_triangles"] == 0
    hardware = results["hardware"]["primId"].ids()
    card = _prim_mask(results["hardware"], "/Card")
    seen_behind = _prim_mask(results["hardware"], "/Behind")
    assert seen_behind[120, 120] and card[120, 75], "the hole shows the card behind; the card's edge is drawn"
    assert seen_behind.sum() > 1000, "all of the card behind shows through the hole"
    for vertices in ("shared", "per-triangle"):
        stats = results[vertices].stats
        assert stats["sw_raster_vertices"] == vertices
        assert stats["sw_triangles"] == stats["source_triangles"], "the small triangles go to the compute rasterizer"
        software = results[vertices]["primId"].ids()
        assert np.array_equal(software, hardware), f"{vertices}: {(software != hardware).sum()} pixels differ"
    with pytest.raises(tessera.StageError, match="raster vertices"):
        session.render(camera="/Camera", resolution=(8, 8), raster_vertices="sideways")


def test_a_mask_on_one_geom_subset_cuts_only_its_faces(render):
    """Two faces of one mesh, each its own GeomSubset: the left one's material cuts a round hole (textured opacity),
    the right one's is plain; a card behind shows through the left face's hole only."""
    from conftest import TESTENV

    stage = Usd.Stage.CreateInMemory()
    _camera(stage, aperture=12.0)
    mesh = UsdGeom.Mesh.Define(stage, "/Pair")
    mesh.GetPointsAttr().Set([(-2, -1, 0), (0, -1, 0), (0, 1, 0), (-2, 1, 0), (2, -1, 0), (2, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4, 4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3, 1, 4, 5, 2])
    mesh.GetSubdivisionSchemeAttr().Set("none")
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)] * 2)  # each face spans the whole texture
    behind = _quad(stage, "/Behind")
    behind.GetPointsAttr().Set([(-2.5, -0.4, 0), (2.5, -0.4, 0), (2.5, 0.4, 0), (-2.5, 0.4, 0)])
    behind.AddTranslateOp().Set(Gf.Vec3d(0, 0, -1))
    hole = _textured_material(stage, "/Looks/Hole", str(TESTENV / "testTextures" / "hole.png"), input_name="opacity", output="a")
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/Hole/Surface")).CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    hole.GetInput("uvSet").Set("st")
    transform = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Hole/Transform"))
    transform.GetInput("rotation").Set(0.0)
    transform.GetInput("scale").Set(Gf.Vec2f(1, 1))
    transform.GetInput("translation").Set(Gf.Vec2f(0, 0))
    plain = UsdShade.Material.Define(stage, "/Looks/Plain")
    surface = UsdShade.Shader.Define(stage, "/Looks/Plain/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    plain.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for name, face, material in (("Left", 0, hole), ("Right", 1, plain)):
        subset = binding.CreateMaterialBindSubset(name, [face])
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)

    result = render(stage, resolution=(240, 60), aovs=("primId",))
    assert not [w for w in result.warnings if "Looks" in w], result.warnings
    ids = result["primId"].ids()
    at = lambda x: result.prim_path(int(ids[30, x]))
    # 50 pixels a unit: the left face's centre (x = -1) is pixel 70, the right face's (x = 1) pixel 170; the hole's
    # radius is 0.625 units (31 pixels).
    assert at(70) == "/Behind", "the hole of the masked subset"
    assert at(170) == "/Pair", "the other subset keeps its centre"
    assert at(30) == "/Pair", "the masked face outside its hole"
