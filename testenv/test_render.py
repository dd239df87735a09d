"""Image tests: each scene in testenv/<test>/ renders on the Vulkan device and matches its baseline."""

from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

import tessera
from conftest import TESTENV
from imagecompare import assert_matches_baseline

NO_HIT = 0xFFFFFFFF


def render_and_compare(render, tmp_path, test, stage_file, **kwargs):
    result = render(TESTENV / test / stage_file, **kwargs)
    out = tmp_path / f"{Path(stage_file).stem}.png"
    result.write(out)
    assert_matches_baseline(out, TESTENV / test / "baseline" / out.name)
    return result


def test_cube(render, tmp_path):
    result = render_and_compare(render, tmp_path, "testCube", "cube.usda")
    assert result.stats["instances"] == 1
    assert result.stats["source_triangles"] == 12


def test_holes_and_left_handed_orientation(render, tmp_path):
    result = render_and_compare(render, tmp_path, "testHolesLeftHanded", "holes_left_handed.usda", resolution=(320, 200),
                                aovs=("color", "primId"))
    ids = result["primId"].ids()
    paths = {result.prim_path(int(i)) for i in np.unique(ids) if i != NO_HIT}
    assert paths == {"/RightHandedWithHole", "/LeftHanded"}, "both single-sided grids face the camera"
    # The hole (the left grid's centre face) shows the background; the faces around it do not.
    # The hole's centre is at x = -2, 9 units away; 35 mm lens, the 24 mm aperture widened to 320/200 of it.
    left_centre_x = int(round(160 + (-2.0 / 9.0) * (35.0 / (24.0 * 320 / 200)) * 320))
    row = ids[100]
    assert row[left_centre_x] == NO_HIT
    assert row[left_centre_x - 22] != NO_HIT and row[left_centre_x + 22] != NO_HIT


def test_point_instancer(render, tmp_path):
    result = render_and_compare(render, tmp_path, "testPointInstancer", "point_instancer.usda", resolution=(320, 240))
    # 48 instances, 2 masked by invisibleIds; the nested "Pair" prototype draws 2 cubes per instance.
    assert result.stats["instances"] == 15 + 15 + 16 * 2
    assert result.stats["rprims"] == 3, "one rprim per prototype mesh, however many instances"


def test_native_instancing_builds_the_prototype_once(render, tmp_path):
    result = render_and_compare(render, tmp_path, "testNativeInstancing", "native_instancing.usda", resolution=(320, 240))
    assert result.stats["rprims"] == 2, "the prototype's two gprims are read and built once"
    assert result.stats["instances"] == 24 * 2, "24 visible instances (one is invisible) of two gprims"
    assert result.session.index.sync_counts["mesh"] == 2


def _cube_stage(offset=None):
    """An in-memory stage referencing the cube scene (its camera included), optionally moved far away.
    (Editing the opened file would change the layer every other test shares.)"""
    stage = Usd.Stage.CreateInMemory()
    root = UsdGeom.Xform.Define(stage, "/Root")
    root.GetPrim().GetReferences().AddReference(str(TESTENV / "testCube" / "cube.usda"), "/World")
    if offset is not None:
        root.AddTranslateOp().Set(Gf.Vec3d(offset, -offset, offset))
    return stage


def test_far_from_origin_renders_like_the_origin(render):
    near = render(_cube_stage(0.0), aovs=("color", "primId"))
    far = render(_cube_stage(1.0e6), aovs=("color", "primId"))
    assert np.array_equal(near["primId"].ids(), far["primId"].ids())
    assert np.abs(near["color"].pixels - far["color"].pixels).max() < 1e-3


def test_aovs_hold_real_values(render, tmp_path):
    result = render(TESTENV / "testHolesLeftHanded" / "holes_left_handed.usda", resolution=(320, 200),
                    aovs=("depth", "normal", "instanceId", "primId"))
    depth = result["depth"].pixels[..., 0]
    covered = np.isfinite(depth)
    assert covered.any() and np.allclose(depth[covered], 9.0, atol=1e-3), "both grids lie 9 units in front of the camera"
    normal = result["normal"].pixels[..., :3][covered]
    assert np.allclose(normal, [0.0, 0.0, 1.0], atol=1e-3)
    instances = result["instanceId"].ids()
    assert set(np.unique(instances[covered])) == {0, 1}
    # Id AOVs are stored as uint32 in EXR (read back through a float conversion that normalises them).
    exr = tmp_path / "prim.exr"
    result["primId"].write(str(exr), tessera.ocio_config_path())
    stored = np.rint(tessera.read_image(str(exr))[..., 0].astype(np.float64) * 4294967295.0).astype(np.uint32)
    assert np.array_equal(stored, result["primId"].ids())


def test_renders_are_deterministic(render):
    stage = TESTENV / "testPointInstancer" / "point_instancer.usda"
    first = render(stage, resolution=(200, 150), aovs=("color", "primId", "instanceId", "triangleId"))
    second = render(stage, resolution=(200, 150), aovs=("color", "primId", "instanceId", "triangleId"))
    for aov in ("color", "primId", "instanceId", "triangleId"):
        assert first[aov].pixels.tobytes() == second[aov].pixels.tobytes(), aov


def test_sessions_share_the_device_not_their_scenes():
    """Sessions of one process share its device and compiled pipelines (Device::shared); each keeps its own scene, and
    after the process lets go of the device, the next session makes a new one that draws the same."""
    cube, instancer = TESTENV / "testCube" / "cube.usda", TESTENV / "testPointInstancer" / "point_instancer.usda"
    aovs = ("color", "primId", "triangleId")

    def frame(session):
        result = session.render(camera=session.camera_paths()[0], resolution=(160, 120), aovs=aovs)
        assert not result.errors, result.errors
        return [result[aov].pixels.tobytes() for aov in aovs]

    first = tessera.Session(cube, validation=True)
    first_alone = frame(first)
    second = tessera.Session(instancer, validation=True)  # alive beside the first
    second_alone = frame(second)
    assert second_alone != first_alone
    assert frame(first) == first_alone and frame(second) == second_alone
    del first, second
    tessera._tessera.release_shared_devices()
    assert frame(tessera.Session(cube, validation=True)) == first_alone


def test_tiny_visible_cluster_list_grows_and_redraws_the_same_image(render):
    import tessera

    stage = TESTENV / "testPointInstancer" / "point_instancer.usda"
    session = tessera.Session(stage, validation=True)
    session.delegate.set_visible_cluster_capacity(2)
    tight = session.render(camera="/Camera", resolution=(160, 120), aovs=("primId",))
    assert tight.stats["overflow_redraws"] >= 1
    roomy = render(stage, resolution=(160, 120), aovs=("primId",))
    assert roomy.stats["overflow_redraws"] == 0
    assert np.array_equal(tight["primId"].ids(), roomy["primId"].ids())


def test_bad_meshes_are_named_and_the_rest_renders(render):
    result = render(TESTENV / "testBadInput" / "bad_meshes.usda", resolution=(200, 100), aovs=("primId",), expect_errors=True)
    text = "\n".join(result.warnings + result.errors)
    assert "/PartlyBroken: dropped 2 invalid face(s)" in text
    assert "/PartlyBroken: 1 point(s) are NaN" in text
    assert "/CountsDisagree: faceVertexCounts sum to 8 but faceVertexIndices has 4 entries" in text
    assert "/NegativeIndex: no drawable faces" in text
    drawn = {result.prim_path(int(i)) for i in np.unique(result["primId"].ids()) if i != NO_HIT}
    assert drawn == {"/Good", "/PartlyBroken"}, "the valid mesh and the valid face still render"


def test_a_prim_whose_data_usd_rejects_is_skipped_by_name(render):
    stage = _cube_stage()
    bad = UsdGeom.Mesh.Define(stage, "/Root/BadXform")
    bad.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    bad.GetFaceVertexCountsAttr().Set([3])
    bad.GetFaceVertexIndicesAttr().Set([0, 1, 2])
    op = bad.GetPrim().CreateAttribute("xformOp:scale", Sdf.ValueTypeNames.Double)  # scale must be a vector
    op.Set(2.0)
    bad.GetPrim().CreateAttribute("xformOpOrder", Sdf.ValueTypeNames.TokenArray).Set(["xformOp:scale"])
    result = render(stage, aovs=("primId",), expect_errors=True)
    assert any(e.startswith("/Root/BadXform: ") for e in result.errors), result.errors
    assert all("\n" not in e for e in result.errors)
    assert (result["primId"].ids() != NO_HIT).any(), "the cube still renders"


def _quad(stage, path, x, color=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x - 0.4, -0.4, 0), (x + 0.4, -0.4, 0), (x + 0.4, 0.4, 0), (x - 0.4, 0.4, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if color:
        mesh.CreateDisplayColorAttr([color])
    return mesh


def _looking_at_quads(stage):
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(10.0)
    return camera


def test_purpose_visibility_and_time(render):
    from pxr import UsdShade

    stage = Usd.Stage.CreateInMemory()
    _looking_at_quads(stage)
    _quad(stage, "/Default", -1.5, (1, 1, 1))
    UsdGeom.Imageable(_quad(stage, "/Proxy", -0.5, (1, 1, 1))).GetPurposeAttr().Set(UsdGeom.Tokens.proxy)
    hidden = UsdGeom.Xform.Define(stage, "/Hidden")
    hidden.GetVisibilityAttr().Set(UsdGeom.Tokens.invisible)
    _quad(stage, "/Hidden/Child", 0.5, (1, 1, 1))  # invisible through its parent
    moving = _quad(stage, "/Moving", 1.5, (1, 1, 1))
    translate = moving.AddTranslateOp()
    translate.Set(Gf.Vec3d(0, 0, 0), 1.0)
    translate.Set(Gf.Vec3d(0, 2, 0), 10.0)  # at frame 10 it has moved out of the frame
    # A UsdPreviewSurface bound to /Default: its diffuseColor wins over displayColor.
    material = UsdShade.Material.Define(stage, "/Looks/Blue")
    shader = UsdShade.Shader.Define(stage, "/Looks/Blue/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.05, 0.1, 0.9))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Default")).Bind(material)
    light = UsdLux.DistantLight.Define(stage, "/Sun")
    light.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 0.0))  # yellow light on a blue surface: little comes back in blue

    def drawn(frame):
        result = render(stage, resolution=(400, 100), aovs=("primId", "color"), frame=frame)
        return result, {result.prim_path(int(i)) for i in np.unique(result["primId"].ids()) if i != NO_HIT}

    first, paths = drawn(1.0)
    assert paths == {"/Default", "/Moving"}, "proxy purpose and invisible parents are not drawn"
    assert drawn(10.0)[1] == {"/Default"}, "--frame reads time samples"
    centre = first["color"].pixels[50, 200 - 150]  # /Default's centre: x = -1.5 at 5 units, 50 mm over 40 mm
    # Yellow light: no blue comes back. The specular lobe (a dielectric, F0 = 0.04) returns red and green alike; the
    # diffuse (0.05, 0.1, 0.9) returns twice as much green as red. A white displayColor would return them equally.
    assert centre[2] < 0.02 and centre[1] > centre[0] + 0.02 and centre[0] > 0.0, f"blue diffuse lit by a yellow light, got {centre}"


def test_preview_surface_inputs(render):
    """Four quads in a uniform dome of radiance 1, each with one UsdPreviewSurface input set. Seen head on, a quad
    returns (1 - metallic) * diffuse * occlusion plus the specular lobe's share of the environment."""
    from pxr import UsdShade

    stage = Usd.Stage.CreateInMemory()
    _looking_at_quads(stage)
    UsdLux.DomeLight.Define(stage, "/Dome").CreateIntensityAttr(1.0)

    def quad_with(path, x, **inputs):
        mesh = _quad(stage, path, x)
        material = UsdShade.Material.Define(stage, f"/Looks{path}")
        shader = UsdShade.Shader.Define(stage, f"/Looks{path}/Surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.25, 0.125))
        for name, value in inputs.items():
            kind = Sdf.ValueTypeNames.Color3f if isinstance(value, Gf.Vec3f) else Sdf.ValueTypeNames.Float
            shader.CreateInput(name, kind).Set(value)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)

    quad_with("/Plastic", -1.5)
    quad_with("/Occluded", -0.5, occlusion=0.0)
    quad_with("/Metal", 0.5, metallic=1.0, roughness=0.2)
    quad_with("/Masked", 1.5, opacity=0.3, opacityThreshold=0.5)
    result = render(stage, resolution=(400, 100), aovs=("primId", "color"))
    colour = lambda x: result["color"].pixels[50, x, :3]  # quad centres at x = -1.5 ... 1.5 -> columns 50, 150, 250, 350
    plastic, occluded, metal = colour(50), colour(150), colour(250)
    # Dielectric: the diffuse colour plus a grey specular share of a few percent, the same in every channel.
    specular = plastic - np.array([0.5, 0.25, 0.125])
    assert 0.01 < specular[0] < 0.1 and np.allclose(specular, specular[0], atol=1e-4), plastic
    assert np.all(occluded == 0.0), "occlusion 0 takes the whole dome away"
    # Metal: no diffuse; it reflects albedo * a + b of the environment, a linear function of the albedo (a near 0.9
    # for roughness 0.2 seen head on). A diffuse left in would double a.
    a = (metal[0] - metal[1]) / 0.25
    b = metal[0] - 0.5 * a
    assert 0.8 < a < 0.95 and 0.0 <= b < 0.02 and abs(metal[2] - (0.125 * a + b)) < 1e-3, metal
    assert result["primId"].ids()[50, 350] == NO_HIT, "opacity below opacityThreshold masks the quad"
    assert "/Plastic" in {result.prim_path(int(i)) for i in np.unique(result["primId"].ids()) if i != NO_HIT}


def test_texture_coordinates(tmp_path):
    """primvars:st of each interpolation reaches the resolve pass (--vis uv: red fract(u), green fract(v)); subdivided
    meshes carry their UV islands through OpenSubdiv; a wrongly typed st is a warning naming the prim."""
    session = tessera.Session(TESTENV / "testUvs" / "uvs.usda", validation=True, complexity=1.2)  # the cube refined twice
    result = session.render(camera="/Camera", resolution=(480, 320), vis="uv", aovs=("color", "primId"))
    assert not result.errors, "\n".join(result.errors)
    assert any("/WrongType: primvars:st is float3[]" in w for w in result.warnings)
    out = tmp_path / "uvs.png"
    result.write(out)
    assert_matches_baseline(out, TESTENV / "testUvs" / "baseline" / "uvs.png")

    color = np.asarray(result["color"].pixels)
    # The face-varying quad spans st (0, 0)-(1, 1) over 2 units; the camera sits 9 units away (35 mm, 36 mm
    # aperture over 480 pixels): 51.85 pixels per unit, centre at pixel (110.4, 92.6).
    per_unit = 35.0 / 18.0 / 9.0 * 240.0
    centre_x, centre_y = 240.0 - 2.5 * per_unit, 160.0 - 1.3 * per_unit
    for du, dv in [(0.0, 0.0), (0.3, 0.0), (0.0, 0.3), (-0.35, -0.35), (0.4, -0.2)]:
        x, y = int(centre_x + du * 2 * per_unit), int(centre_y - dv * 2 * per_unit)
        expected_u = 0.5 + ((x + 0.5) - centre_x) / (2 * per_unit)
        expected_v = 0.5 - ((y + 0.5) - centre_y) / (2 * per_unit)
        assert color[y, x, 0] == pytest.approx(expected_u, abs=0.01), (x, y)
        assert color[y, x, 1] == pytest.approx(expected_v, abs=0.01), (x, y)
    # The meshes without (usable) texture coordinates show magenta.
    ids = result["primId"].ids()
    for path in ("/NoUvs", "/WrongType"):
        mask = ids == next(i for i in np.unique(ids) if i != NO_HIT and result.prim_path(int(i)) == path)
        assert np.allclose(color[mask][:, :3], [1.0, 0.0, 1.0], atol=1e-6), path
    # The subdivided cube: six islands spanning st 0..0.9, refined smoothly within each.
    cube = ids == next(i for i in np.unique(ids) if i != NO_HIT and result.prim_path(int(i)) == "/SubdividedCube")
    assert cube.sum() > 3000
    shade = color[cube][:, :2]
    assert shade.max() > 0.6 and shade.min() < 0.15, "the islands' range of st shows"


@pytest.mark.parametrize("material_bins", ["1", "0"])
def test_geom_subsets_bind_materials_per_face(render, tmp_path, monkeypatch, material_bins):
    """GeomSubsets of family materialBind give one mesh several materials: its triangles carry material slots through
    every DAG level, and each slot's pixels land in its material's bin (a GPU's way, $TESSERA_MATERIAL_BINS=1), or, on
    a CPU device, each pixel reads its slot's material itself: the same image either way."""
    monkeypatch.setenv("TESSERA_MATERIAL_BINS", material_bins)
    result = render_and_compare(render, tmp_path, "testGeomSubsets", "geom_subsets.usda", resolution=(480, 320))
    assert any("/Strip/RedFaces: 1 face indices outside 0..3" in w for w in result.warnings)
    assert result.stats["rprims"] == 1
    if material_bins == "1":
        assert result.stats["shading_bins"] == 3 and not result.stats["pixel_materials"]
    elif result.session.delegate.software_device:
        assert result.stats["shading_bins"] == 1 and result.stats["pixel_materials"]
    color = np.asarray(result["color"].pixels)
    # Quad centres: x = -3, -1, 1, 3 at 10 units (35 mm lens, 36 mm aperture over 480 pixels: 18.9 px per unit).
    per_unit = 35.0 / 18.0 / 10.0 * 240.0
    expected = ["blue", "red", "green", "red"]
    for quad, name in enumerate(expected):
        x = int(240 + (-3 + 2 * quad) * per_unit)
        channel = int(np.argmax(color[160, x, :3]))
        assert ["red", "green", "blue"][channel] == name, (quad, color[160, x])


def test_every_aov_shows_the_same_background_first_or_not(render):
    """A one-material frame writes its first AOV's background in the pass that lists the covered pixels, and the other
    AOVs' in the background pass: each AOV must come out the same, bit for bit, whichever place it has."""
    stage = Usd.Stage.Open(str(TESTENV / "testCube" / "cube.usda"))
    first = render(stage, resolution=(96, 64), aovs=("color", "depth", "normal", "primId"))
    assert first.stats["shading_bins"] == 1
    ids = first["primId"].ids()
    background = ids == NO_HIT
    assert 0 < background.sum() < background.size, "the cube covers part of the frame"
    assert np.all(np.isinf(first["depth"].pixels[..., 0][background]))
    for leading in ("depth", "normal", "primId"):
        others = tuple(a for a in ("color", "depth", "normal", "primId") if a != leading)
        moved = render(stage, resolution=(96, 64), aovs=(leading,) + others)
        for aov in ("color", "depth", "normal", "primId"):
            assert np.array_equal(moved[aov].pixels, first[aov].pixels, equal_nan=True), f"{aov} with {leading} first"


def test_a_plain_background_reaches_every_uncovered_pixel_at_any_height():
    """A background whose four words differ (a dome's colour with alpha 1) is one row written, then copied onto the rows
    below in blocks that double: heights of one row, a power of two and not, all covered to the last row."""
    stage = Usd.Stage.CreateInMemory()  # no dome light: the background is the one asked for
    quad = UsdGeom.Mesh.Define(stage, "/Quad")
    quad.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0.3, 0.2, 6.0))
    session = tessera.Session(stage, validation=True)
    for resolution in ((1, 1), (96, 64), (97, 67), (33, 129)):
        result = session.render(camera="/Camera", resolution=resolution, aovs=("color", "primId"), background=(0.1, 0.2, 0.3, 1.0))
        assert not result.errors, result.errors
        background = result["primId"].ids() == NO_HIT
        color = result["color"].pixels
        assert np.all(color[background] == np.float32([0.1, 0.2, 0.3, 1.0])), resolution
        if resolution != (1, 1):
            assert 0 < background.sum() < background.size, f"{resolution}: the cube covers part of the frame"
            assert not np.any(np.all(color[~background] == np.float32([0.1, 0.2, 0.3, 1.0]), axis=-1)), resolution


def test_the_readback_span_times_the_aov_copies(render):
    """gpu_ms.readback holds the AOVs' copies to host memory; resolve no longer does. A CPU device's resolve writes
    each AOV where it is read (its image, or host-visible output memory): no copy. A GPU copies every AOV."""
    cube = TESTENV / "testCube" / "cube.usda"
    for aovs in (("color",), ("color", "primId")):
        for resolution in ((64, 64), (256, 256)):  # under a megabyte an image is not imported: read from the output
            result = render(cube, aovs=aovs, resolution=resolution)
            if resolution == (64, 64):
                assert not result.stats["aovs_imported"]
            if "llvmpipe" in result.session.device_name:
                assert result.stats["gpu_ms"]["readback"] == 0, (aovs, resolution, result.stats["gpu_ms"])
            else:
                assert result.stats["gpu_ms"]["readback"] > 0, (aovs, resolution, result.stats["gpu_ms"])


def test_pixel_samples_antialias_the_colour_and_keep_the_centres_ids():
    # Two quads, one behind the other, on no background (alpha 0): edges against the background and between prims.
    stage = Usd.Stage.CreateInMemory()
    for path, x, z in (("/Front", -0.3, 0.0), ("/Back", 0.3, -1.0)):
        mesh = UsdGeom.Mesh.Define(stage, path)
        mesh.GetPointsAttr().Set([(x - 0.5, -0.4, z), (x + 0.5, -0.5, z), (x + 0.45, 0.5, z), (x - 0.5, 0.45, z)])
        mesh.GetFaceVertexCountsAttr().Set([4])
        mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    session = tessera.Session(stage, validation=True)
    aovs = ("color", "primId", "depth", "normal")
    one = session.render(camera="/Camera", resolution=(64, 48), aovs=aovs)
    many = session.render(camera="/Camera", resolution=(64, 48), aovs=aovs, pixel_samples=8)
    assert not [e for e in many.errors if e.startswith("validation")]
    assert (one.stats["pixel_samples"], many.stats["pixel_samples"]) == (1, 8)
    for aov in ("primId", "depth", "normal"):  # the centre sample's, bit for bit
        assert np.array_equal(many[aov].pixels, one[aov].pixels, equal_nan=True), aov
    alpha, single = many["color"].pixels[..., 3], one["color"].pixels[..., 3]
    assert set(np.unique(single)) <= {0.0, 1.0}
    assert np.allclose(alpha * 8, np.round(alpha * 8), atol=1e-4), "coverage in eighths"
    partial = (alpha > 0) & (alpha < 1)
    assert partial.sum() > 40, "the silhouettes' pixels are partly covered"
    assert abs(alpha.sum() - single.sum()) < 0.02 * single.sum(), "the same area, spread over the edge pixels"
    # Inside a prim, away from any edge, the colour is the one sample's (the surface's shading barely moves in a pixel).
    ids = one["primId"].ids()
    inside = np.zeros(ids.shape, bool)
    inside[1:-1, 1:-1] = np.all([ids[1 + dy:ids.shape[0] - 1 + dy, 1 + dx:ids.shape[1] - 1 + dx] == ids[1:-1, 1:-1]
                                 for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    inside &= ids != NO_HIT
    assert inside.sum() > 500
    assert np.abs(many["color"].pixels[inside] - one["color"].pixels[inside]).max() < 0.02
    for bad in (0, 4097, 1.5, True):
        with pytest.raises(tessera.StageError, match="pixel samples"):
            session.render(camera="/Camera", resolution=(8, 8), pixel_samples=bad)
    # The Gaussian spreads each edge over a wider band of pixels, with the same area and the same ids.
    soft = session.render(camera="/Camera", resolution=(64, 48), aovs=aovs, pixel_samples=8, pixel_filter="gaussian")
    assert np.array_equal(soft["primId"].ids(), one["primId"].ids())
    soft_alpha = soft["color"].pixels[..., 3]
    assert ((soft_alpha > 0) & (soft_alpha < 1)).sum() > partial.sum()
    assert abs(soft_alpha.sum() - single.sum()) < 0.04 * single.sum()
    offsets = np.array([tessera.pixel_sample_offset(k, "gaussian") for k in range(64)])
    assert np.abs(offsets).max() < 1 and (np.abs(offsets).max(axis=1) > 0.5).any(), "over two pixels' width"
    assert (np.abs(offsets).max(axis=1) < 0.25).sum() > 64 / 6, "denser towards the centre"
    with pytest.raises(tessera.StageError, match="unknown pixel filter 'tent'"):
        session.render(camera="/Camera", resolution=(8, 8), pixel_filter="tent")


ALL_AOVS = ("color", "depth", "normal", "primId", "instanceId", "clusterId", "triangleId")


@pytest.mark.parametrize("stage_file, settings, environment", [
    ("testTextures/textures.usda", {}, {}),                                  # textured materials: listed bins
    ("testTextures/textures.usda", {}, {"TESSERA_IMPORT_AOVS": "0"}),        # slices of the output, read where written
    ("testGeomSubsets/geom_subsets.usda", {"vis": "clusters"}, {}),          # a debug view
    ("testGeomSubsets/geom_subsets.usda", {"vis": "overdraw"}, {}),          # the view that reads no triangle
    ("testLights/dome_texture.usda", {"pixel_samples": 4}, {}),              # a dome's background, samples summed
    ("testLights/dome_texture.usda", {"pixel_samples": 4}, {"TESSERA_IMPORT_AOVS": "0"}),
    ("testPointInstancer/point_instancer.usda", {}, {}),
])
def test_aovs_written_together_are_each_as_written_alone(monkeypatch, stage_file, settings, environment):
    """Resolve writes the AOVs of a frame in one pass, each through a binding of its own (its image, imported on a CPU
    device, or its slice of the output; the colour first): each must be the same bit for bit as the AOV rendered alone
    (its own variant), in any order and subset. 256 x 256: images of a megabyte, imported where the device can."""
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    session = tessera.Session(TESTENV / stage_file, validation=True)
    camera = session.camera_paths()[0]
    alone = {}
    for aov in ALL_AOVS:
        frame = session.render(camera=camera, resolution=(256, 256), aovs=(aov,), **settings)
        assert not frame.errors, frame.errors
        alone[aov] = np.asarray(frame[aov].pixels).view(np.uint32)
    for aovs in (ALL_AOVS, ALL_AOVS[::-1], ("primId", "color"), ("normal", "depth", "triangleId")):
        frame = session.render(camera=camera, resolution=(256, 256), aovs=aovs, **settings)
        assert not frame.errors, frame.errors
        if environment.get("TESSERA_IMPORT_AOVS") == "0":
            assert not frame.stats["aovs_imported"]
        for aov in aovs:
            assert np.array_equal(np.asarray(frame[aov].pixels).view(np.uint32), alone[aov]), f"{aov} among {aovs}"


def _wall_and_box_stage():
    """A bumpy wall of one material filling a camera's view, a box before it, and a second camera far away."""
    stage = Usd.Stage.CreateInMemory()
    n = 16
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    x, y = np.meshgrid(np.linspace(-4, 4, n + 1), np.linspace(-4, 4, n + 1), indexing="ij")
    wall = UsdGeom.Mesh.Define(stage, "/Wall")
    wall.CreatePointsAttr([(float(px), float(py), 0.2 * float(np.sin(3 * px) * np.cos(2 * py))) for px, py in zip(x.ravel(), y.ravel())])
    wall.CreateFaceVertexCountsAttr([4] * (n * n))
    wall.CreateFaceVertexIndicesAttr(np.stack([a, a + n + 1, a + n + 2, a + 1], -1).ravel().tolist())
    box = UsdGeom.Cube.Define(stage, "/Box")
    box.AddTranslateOp().Set(Gf.Vec3d(0.3, -0.2, 2.0))
    box.AddScaleOp().Set(Gf.Vec3f(0.4))
    for name, distance in (("/Near", 6.0), ("/Far", 60.0)):
        UsdGeom.Camera.Define(stage, name).AddTranslateOp().Set(Gf.Vec3d(0.1, 0.1, distance))
    return stage


@pytest.mark.parametrize("dome", [False, True], ids=["plain background", "textured dome"])
@pytest.mark.parametrize("pixels_per_thread, sparse", [("1", "listed"), ("16", "packed")])
def test_a_one_bin_frame_is_resolved_over_every_pixel_as_the_listed_one(monkeypatch, tmp_path, pixels_per_thread, sparse, dome):
    """A one-material frame skips classify where resolve reads every pixel: in place after a frame that covered most
    pixels, else, with several pixels per thread (a CPU device), each subgroup's covered pixels packed first; with one
    (a GPU) a sparsely covered frame is listed. Every AOV must match bit for bit whichever way, the background of the
    pixels nothing covers too (resolve in place stores it itself, but where a textured dome drew it), and the covered
    pixels counted must be those a surface covers."""
    monkeypatch.setenv("TESSERA_SHADE_PIXELS_PER_THREAD", pixels_per_thread)
    stage = _wall_and_box_stage()
    if dome:
        import sys

        sys.path.insert(0, str(TESTENV / "testTextures"))
        from make_textures import write_png

        sky = np.zeros((16, 32, 3), np.uint8)
        sky[..., 0] = np.arange(32, dtype=np.uint8)[None, :] * 8  # red rises around the horizon, green towards the top
        sky[..., 1] = np.arange(16, dtype=np.uint8)[:, None] * 16
        write_png(tmp_path / "sky.png", sky)
        UsdLux.DomeLight.Define(stage, "/Sky").GetTextureFileAttr().Set(Sdf.AssetPath(str(tmp_path / "sky.png")))
    session = tessera.Session(stage, validation=True)
    aovs = ("color", "depth", "normal", "primId", "instanceId", "clusterId")
    frames = [session.render(camera=camera, resolution=(97, 67), aovs=aovs) for camera in ("/Near", "/Near", "/Far", "/Far")]
    for frame in frames:
        assert not frame.errors, frame.errors
        assert frame.stats["covered_pixels"] == int((frame["primId"].ids() != NO_HIT).sum())
        assert frame.stats["shading_bins"] == 1
        assert frame.stats["shade_pixels_per_thread"] == int(pixels_per_thread)
    assert [f.stats["resolve_pixels"] for f in frames] == [sparse, "in place", "in place", sparse]
    assert frames[1].stats["covered_pixels"] == 97 * 67 and frames[2].stats["covered_pixels"] < 0.5 * 97 * 67
    for one, other in ((frames[0], frames[1]), (frames[3], frames[2])):
        for aov in aovs:
            assert np.array_equal(np.asarray(one[aov].pixels).view(np.uint32), np.asarray(other[aov].pixels).view(np.uint32)), aov
    uncovered = np.asarray(frames[2]["color"].pixels)[frames[2]["primId"].ids() == NO_HIT]
    assert len(np.unique(uncovered, axis=0)) > (10 if dome else 0) and (dome or np.all(uncovered == uncovered[0]))


@pytest.mark.parametrize("pixels_per_thread", ["1", "16"])
def test_several_materials_read_by_each_pixel_draw_what_their_bins_draw(monkeypatch, pixels_per_thread):
    """A CPU device's frame of several materials skips classify: its resolve reads every pixel (in place or packed, as a
    one-material frame's) and each pixel its own material, through one variant for all of them. Every AOV and the
    shading-bins view must match the frame classified into bins bit for bit, and no bin list is made."""
    from pxr import UsdShade
    from conftest import preview_material

    monkeypatch.setenv("TESSERA_SHADE_PIXELS_PER_THREAD", pixels_per_thread)
    stage = _wall_and_box_stage()
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Box")).Bind(preview_material(stage, "/Looks/Red", (0.8, 0.1, 0.1)))
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Wall")).Bind(preview_material(stage, "/Looks/Grey", (0.4, 0.4, 0.45)))
    aovs = ("color", "depth", "normal", "primId")
    frames = {}
    for bins in ("1", "0"):
        monkeypatch.setenv("TESSERA_MATERIAL_BINS", bins)
        session = tessera.Session(stage, validation=True)
        frames[bins] = [session.render(camera=camera, resolution=(97, 67), aovs=aovs, vis=vis)
                        for camera, vis in (("/Near", None), ("/Near", None), ("/Far", None), ("/Near", "shading-bins"))]
        for frame in frames[bins]:
            assert not frame.errors, frame.errors
    for frame in frames["1"]:
        assert frame.stats["resolve_pixels"] == "listed" and not frame.stats["pixel_materials"]
    if session.delegate.software_device and pixels_per_thread == "16":
        pixel = frames["0"]
        assert all(f.stats["pixel_materials"] and f.stats["shading_bins"] == 1 for f in pixel)
        assert [f.stats["resolve_pixels"] for f in pixel] == ["packed", "in place", "in place", "packed"]
        assert pixel[-1].stats["pixel_bytes"] < frames["1"][-1].stats["pixel_bytes"], "no bin list"
    for binned, read in zip(frames["1"], frames["0"]):
        for aov in aovs:
            assert np.array_equal(np.asarray(binned[aov].pixels).view(np.uint32), np.asarray(read[aov].pixels).view(np.uint32)), aov
    colours = np.asarray(frames["0"][-1]["color"].pixels)[..., :3].reshape(-1, 3)
    assert len(np.unique(colours, axis=0)) >= 3, "the shading-bins view tells the two materials and the background apart"


def test_a_frame_that_lists_no_pixels_makes_no_bin_list(monkeypatch):
    """The material bins' pixel list (4 bytes a pixel) is made by the first frame that lists its pixels: frames of one
    material that read every pixel never make it; a second material's frame does."""
    from pxr import UsdShade
    from conftest import preview_material

    monkeypatch.setenv("TESSERA_SHADE_PIXELS_PER_THREAD", "16")  # packs rather than lists on any device
    monkeypatch.setenv("TESSERA_MATERIAL_BINS", "1")  # classifies several materials on any device
    stage = _wall_and_box_stage()
    session = tessera.Session(stage, validation=True)
    one = [session.render(camera="/Far", resolution=(97, 67)) for _ in range(2)]
    assert [f.stats["resolve_pixels"] for f in one] == ["packed", "packed"]
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/Box")).Bind(preview_material(stage, "/Looks/Red", (0.8, 0.1, 0.1)))
    two = session.render(camera="/Far", resolution=(97, 67))
    assert not two.errors, two.errors
    assert two.stats["resolve_pixels"] == "listed" and two.stats["shading_bins"] == 2
    assert two.stats["pixel_bytes"] - one[1].stats["pixel_bytes"] == 4 * 97 * 67


def _cubes_stage(wall: bool):
    """A row of 24 small cubes and a ball seen from the front, with or without a wall before them that hides them all."""
    stage = Usd.Stage.CreateInMemory()
    for k in range(24):
        cube = UsdGeom.Cube.Define(stage, f"/Cube{k}")
        cube.AddTranslateOp().Set(Gf.Vec3d(-2.3 + 0.2 * k, 0.0, -3.0))
        cube.AddScaleOp().Set(Gf.Vec3f(0.08))
    UsdGeom.Sphere.Define(stage, "/Ball").AddTranslateOp().Set(Gf.Vec3d(0.0, 0.8, -2.0))  # its back clusters face away
    if wall:
        quad = UsdGeom.Mesh.Define(stage, "/Wall")
        quad.CreatePointsAttr([(-6, -4, 0), (6, -4, 0), (6, 4, 0), (-6, 4, 0)])
        quad.CreateFaceVertexCountsAttr([4])
        quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdGeom.Camera.Define(stage, "/Camera").AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 6.0))
    return stage


def test_a_last_render_builds_no_depth_pyramid_for_a_next_one():
    """`last=True` (a batch render's last frame): the frame's own two-pass occlusion as ever, the same image, but no HZB
    of the whole frame for a next render; a render after it tests nothing, as a first one does."""
    aovs = ("color", "primId")
    frames = {}
    for last in (False, True):
        session = tessera.Session(_cubes_stage(wall=False), validation=True)
        frames[last] = session.render(camera="/Camera", resolution=(96, 64), aovs=aovs, occlusion="always", last=last)
        after = session.render(camera="/Camera", resolution=(96, 64), aovs=aovs, occlusion="always")
        assert after.stats["occlusion_tested"] != last
    assert frames[False].stats["post_pass_clusters"] > 0, "the small cubes wait for the post pass"
    assert frames[False].stats["hzb_builds"] == 2 and frames[True].stats["hzb_builds"] == 1, "after the main pass, and the frame's"
    for aov in aovs:
        assert np.array_equal(np.asarray(frames[False][aov].pixels).view(np.uint32), np.asarray(frames[True][aov].pixels).view(np.uint32))


def test_occlusion_rests_where_it_culls_little_and_tries_again_against_the_frame_before():
    """On a CPU device, a frame whose occlusion culled under a quarter of its instances and clusters lets the next 15
    frames skip its HZB passes (no HZB, no post pass; normal cones still cull); the last of them builds its HZB all the
    same, so that the 17th frame tests against the frame before it. A wall that hides everything keeps occlusion every
    frame; "always" and False never rest. The images never change."""
    aovs = ("color", "primId")
    session = tessera.Session(_cubes_stage(wall=False), validation=True)
    if not session.delegate.software_device:
        pytest.skip("occlusion rests by default only on a CPU device")
    frames = [session.render(camera="/Camera", resolution=(96, 64), aovs=aovs) for _ in range(18)]
    assert all(not f.errors for f in frames)
    assert [f.stats["occlusion_rested"] for f in frames] == [False] + [True] * 15 + [False, True]
    assert [f.stats["hzb_builds"] for f in frames[1:15]] == [0] * 14, "a resting frame builds no HZB"
    assert frames[15].stats["hzb_builds"] == 1, "the last resting frame builds the next one's"
    assert frames[16].stats["occlusion_tested"], "the frame that tries again tests against the frame before it"
    assert all(f.stats["backface_clusters"] == frames[0].stats["backface_clusters"] > 0 for f in frames), \
        "a resting frame still culls clusters facing away"
    for frame in frames[1:]:
        for aov in aovs:
            assert np.array_equal(np.asarray(frame[aov].pixels).view(np.uint32), np.asarray(frames[0][aov].pixels).view(np.uint32))
    for occlusion in ("always", False):
        again = [session.render(camera="/Camera", resolution=(96, 64), aovs=aovs, occlusion=occlusion) for _ in range(3)]
        assert [f.stats["occlusion_rested"] for f in again] == [False] * 3
        assert all(bool(f.stats["hzb_builds"]) == (occlusion == "always") for f in again[1:])

    hidden = tessera.Session(_cubes_stage(wall=True), validation=True)
    frames = [hidden.render(camera="/Camera", resolution=(96, 64), aovs=aovs) for _ in range(4)]
    assert [f.stats["occlusion_rested"] for f in frames] == [False] * 4
    assert all(f.stats["occluded_instances"] >= 20 for f in frames), "the wall hides every cube in view (the row's ends are outside it)"
    assert all(f.stats["visible_instances"] == 1 for f in frames[1:]), "and the ball, once the frame before shows the wall"
    with pytest.raises(tessera.StageError, match="occlusion must be one of"):
        hidden.render(camera="/Camera", resolution=(96, 64), occlusion="sometimes")
