"""Runtime tessellation with displacement: UsdPreviewSurface's displacement (constant or textured) read with Tessera's
tessera:displacement:* settings, diced on the GPU into micro-triangles without cracks (hard edges, a UV wrap seam,
poles), bounds widened by the displacement, faded out where it is too small to see, and matching the same surface
pre-tessellated on the CPU and drawn at full detail."""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

import tessera
from conftest import TESTENV, shared_asset
from imagecompare import assert_matches_baseline
from tessera.bench import psnr
from tessera.bench_displacement import displaced_material, sample_bilinear, write_stages

NO_HIT = 0xFFFFFFFF


def enclosed_background(covered: np.ndarray) -> int:
    """Pixels nothing covers that the image border cannot reach through other such pixels: holes in a silhouette."""
    outside = np.zeros_like(covered)
    outside[0, :], outside[-1, :], outside[:, 0], outside[:, -1] = ~covered[0, :], ~covered[-1, :], ~covered[:, 0], ~covered[:, -1]
    while True:
        grown = outside.copy()
        grown[1:] |= outside[:-1]
        grown[:-1] |= outside[1:]
        grown[:, 1:] |= outside[:, :-1]
        grown[:, :-1] |= outside[:, 1:]
        grown &= ~covered
        if (grown == outside).all():
            return int((~covered & ~outside).sum())
        outside = grown


def bind(prim, material):
    UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(material)


def camera_at(stage, eye, target=(0, 0, 0), focal=35.0):
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.GetFocalLengthAttr().Set(focal)
    camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.05, 100))
    view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0))
    camera.AddTransformOp().Set(view.GetInverse())


def hard_cube(stage, path, half=0.5):
    """A cube with a normal per face (hard edges: every corner is three split vertices) and a UV island per face."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    h = half
    points = [(-h, -h, -h), (h, -h, -h), (h, h, -h), (-h, h, -h), (-h, -h, h), (h, -h, h), (h, h, h), (-h, h, h)]
    faces = [(4, 5, 6, 7), (1, 0, 3, 2), (5, 1, 2, 6), (0, 4, 7, 3), (7, 6, 2, 3), (0, 1, 5, 4)]
    normals = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    mesh.GetPointsAttr().Set(points)
    mesh.GetFaceVertexCountsAttr().Set([4] * 6)
    mesh.GetFaceVertexIndicesAttr().Set([i for f in faces for i in f])
    mesh.GetSubdivisionSchemeAttr().Set("none")
    mesh.GetNormalsAttr().Set([n for n in normals for _ in range(4)])
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)] * 6)
    return mesh


def session_render(stage_path, *, resolution=(256, 256), aovs=("color", "primId"), complexity=1.0, **kwargs):
    session = tessera.Session(str(stage_path), validation=True, complexity=complexity)
    result = session.render(camera="/Camera", resolution=resolution, aovs=aovs, **kwargs)
    assert not result.errors, "\n".join(result.errors)
    result.session = session
    return result


def covered(result) -> np.ndarray:
    return result["primId"].ids() != NO_HIT


def test_material_reads_displacement_and_settings(tmp_path):
    from tessera.usd.materials import material_desc

    stage = Usd.Stage.CreateInMemory()
    constant = displaced_material(stage, "/Constant", constant=0.25, magnitude=2.0, center=0.1, fade=(8.0, 2.0))
    textured = displaced_material(stage, "/Textured", texture=tmp_path / "h.png")
    undisplaced = UsdShade.Material.Define(stage, "/Flat")  # displacement authored, but the material's output is not connected
    surface = UsdShade.Shader.Define(stage, "/Flat/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("displacement", Sdf.ValueTypeNames.Float).Set(0.5)
    undisplaced.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    warnings = []
    desc = material_desc(constant.GetPrim(), Usd.TimeCode.Default(), warnings)
    assert (desc.displacement, desc.displacement_magnitude, desc.displacement_center) == pytest.approx((0.25, 2.0, 0.1))
    assert (desc.displacement_fade_start, desc.displacement_fade_end) == (8.0, 2.0)
    desc = material_desc(textured.GetPrim(), Usd.TimeCode.Default(), warnings)
    slots = [s for s in desc.textures if s.input == tessera._tessera.MaterialInput.displacement]
    assert len(slots) == 1 and slots[0].channel == tessera._tessera.TextureChannel.r and desc.uv_primvar == "st"
    assert (desc.displacement_magnitude, desc.displacement_center) == (1.0, 0.0), "USD's own meaning without tessera attributes"
    assert material_desc(undisplaced.GetPrim(), Usd.TimeCode.Default(), warnings).displacement == 0.0, "Storm displaces only through the output"
    assert warnings == []


def test_hard_edged_cube_does_not_tear(tmp_path):
    """Faces with their own normals meet at hard edges: displaced along those normals they would part and show the
    background through the gaps; displaced along the mean normal of each position they stay closed."""
    path = tmp_path / "cube.usda"
    stage = Usd.Stage.CreateNew(str(path))
    cube = hard_cube(stage, "/Cube")
    bind(cube, displaced_material(stage, "/Looks/Puffy", constant=0.2))
    camera_at(stage, (1.6, 1.3, 2.0))
    stage.GetRootLayer().Save()
    result = session_render(path, dicing_rate=4.0)
    assert result.stats["tessellated_triangles"] == 12 and result.stats["micro_triangles"] > 12 * 4, "the cube is diced"
    assert enclosed_background(covered(result)) == 0, "no background shows inside the displaced cube"
    # The displacement moved the surface: more pixels are covered than by the cube as modelled.
    stage.GetPrimAtPath("/Looks/Puffy/Surface").GetAttribute("inputs:displacement").Set(0.0)
    stage.GetRootLayer().Save()
    flat = session_render(path, dicing_rate=4.0)
    assert flat.stats["micro_triangles"] == 0, "a displacement of 0 moves nothing: nothing is diced"
    assert covered(result).sum() > 1.3 * covered(flat).sum()


def test_textured_cube_does_not_tear_at_uv_seams(tmp_path):
    """Every face of the cube is a UV island of its own, and the height map differs where islands meet (heights grow
    with u and v): read at each side's own coordinates the faces would part along every edge; read seam-aware they
    meet."""
    from tessera.bench_textures import write_png

    u, v = np.meshgrid((np.arange(16) + 0.5) / 16, (np.arange(16) + 0.5) / 16)
    write_png(tmp_path / "ramp.png", np.round((0.7 * u + 0.3 * v) * 255)[::-1].astype(np.uint8))
    path = tmp_path / "cube.usda"
    stage = Usd.Stage.CreateNew(str(path))
    cube = hard_cube(stage, "/Cube")
    bind(cube, displaced_material(stage, "/Looks/Ramp", texture=tmp_path / "ramp.png", magnitude=0.4))
    camera_at(stage, (1.6, 1.3, 2.0))
    stage.GetRootLayer().Save()
    result = session_render(path, dicing_rate=2.0)
    assert result.stats["micro_triangles"] > 12 * 16
    assert enclosed_background(covered(result)) == 0, "no background shows through the cube's UV seams"


def test_textured_sphere_does_not_tear_at_its_wrap_seam_or_poles(tmp_path):
    """The wrap seam's split vertices read u = 0 and u = 1 (and the seam-aware read averages them)."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    result = session_render(runtime_stage, dicing_rate=2.0)
    assert result.stats["micro_triangles"] > 10 * result.stats["tessellated_triangles"] > 0
    assert enclosed_background(covered(result)) == 0


def test_runtime_tessellation_matches_the_surface_pre_tessellated_on_the_cpu(tmp_path):
    """The reference: every triangle of the sphere cut into 24 x 24 on the CPU, displaced by the same bilinear samples
    along the same normals, drawn at full detail (--no-lod)."""
    runtime_stage, reference_stage = write_stages(tmp_path, n=24)
    runtime = session_render(runtime_stage, dicing_rate=1.0)
    reference = session_render(reference_stage, lod=False)
    same_coverage = (covered(runtime) == covered(reference)).mean()
    assert same_coverage >= 0.995, f"silhouettes agree on {same_coverage:.2%} of pixels"
    quality = psnr(runtime["color"].pixels[..., :3], reference["color"].pixels[..., :3])
    assert quality >= 35.0, f"PSNR {quality:.1f} dB against the pre-tessellated reference"
    assert 0 < 100 * runtime.stats["geometry_bytes"] < reference.stats["geometry_bytes"], "the detail is made, not stored"
    # The sphere is cached either way; drawn displaced, its streams stay on the host (the displacement bounds read them),
    # drawn plain they go once on the GPU.
    assert runtime.stats["host_mesh_bytes"] > 0 and reference.stats["host_mesh_bytes"] == 0


def test_cpu_reference_samples_like_the_gpu():
    """The reference's own sampler: texel centres, repeat wrap across u = 1, rows bottom first."""
    heights = np.array([[0, 255], [255, 255]], np.uint8)  # bottom row first: only the bottom-left texel is 0
    st = np.array([(0.25, 0.25), (0.5, 0.25), (1.25, 0.25), (0.0, 0.25)])
    assert sample_bilinear(heights, st) == pytest.approx([0.0, 0.5, 0.0, 0.5])


def test_bounds_widen_by_the_displacement(tmp_path):
    """A plane modelled below the view, displaced up into it: culling by its undisplaced bounds would drop it."""
    path = tmp_path / "plane.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Plane")
    mesh.GetPointsAttr().Set([(-1, -3, -1), (1, -3, -1), (1, -3, 1), (-1, -3, 1)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 3, 2, 1])  # facing +y
    mesh.GetSubdivisionSchemeAttr().Set("none")
    bind(mesh, displaced_material(stage, "/Looks/Lift", constant=3.0))
    camera_at(stage, (0, 1.5, 3), target=(0, 0, 0))
    stage.GetRootLayer().Save()
    result = session_render(path, dicing_rate=8.0)
    assert covered(result).mean() > 0.05, "the displaced plane is drawn where it ends up"


def test_cluster_bounds_follow_the_height_map_under_each_cluster(tmp_path):
    """Bounds per cluster come from the displacement texture's range under its UVs (min/max pyramids): a plane whose
    height map is flat but for one far corner keeps far fewer clusters around the view than the same plane under a
    height map with that range everywhere, though both materials bound their displacement alike (0 to 1 unit)."""
    from tessera.bench_displacement import write_height_png

    n, size = 64, 8.0
    xs = np.linspace(-size / 2, size / 2, n + 1)
    points = np.array([(x, 0.0, z) for z in xs for x in xs], np.float32)
    st = np.array([((x + size / 2) / size, (size / 2 - z) / size) for z in xs for x in xs], np.float32)
    quads = [(r * (n + 1) + c, (r + 1) * (n + 1) + c, (r + 1) * (n + 1) + c + 1, r * (n + 1) + c + 1) for r in range(n) for c in range(n)]
    corner = np.zeros((128, 128), np.uint8)
    corner[112:, 112:] = 255  # rows bottom first: the far corner where s and t near 1
    everywhere = np.zeros((128, 128), np.uint8)
    everywhere[::8, ::8] = 255

    def covered_clusters(name, heights):
        path = tmp_path / f"{name}.usda"
        write_height_png(tmp_path / f"{name}.png", heights)
        stage = Usd.Stage.CreateNew(str(path))
        mesh = UsdGeom.Mesh.Define(stage, "/Plane")
        mesh.GetPointsAttr().Set(points)
        mesh.GetFaceVertexCountsAttr().Set([4] * len(quads))
        mesh.GetFaceVertexIndicesAttr().Set([i for q in quads for i in q])
        mesh.GetSubdivisionSchemeAttr().Set("none")
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(st)
        bind(mesh, displaced_material(stage, "/Looks/Heights", texture=tmp_path / f"{name}.png", magnitude=1.0, center=0.0))
        camera_at(stage, (0.0, 1.2, 0.3), target=(0.0, 0.0, -0.2))  # looking down at the middle of the plane
        stage.GetRootLayer().Save()
        result = session_render(path, resolution=(96, 96), dicing_rate=8.0)
        assert covered(result).all()
        return result.stats["tessellated_clusters"]

    tight, loose = covered_clusters("corner", corner), covered_clusters("everywhere", everywhere)
    assert 0 < tight < 0.6 * loose, f"{tight} clusters tessellated under the flat middle, {loose} under bumps everywhere"


def test_displacement_fades_out_where_it_is_too_small_to_see(tmp_path):
    path = tmp_path / "faded.usda"
    stage = Usd.Stage.CreateNew(str(path))
    cube = hard_cube(stage, "/Cube")
    bind(cube, displaced_material(stage, "/Looks/Puffy", constant=0.2, fade=(1e6, 1e5)))  # never large enough to show
    camera_at(stage, (1.6, 1.3, 2.0))
    stage.GetRootLayer().Save()
    faded = session_render(path)
    assert faded.stats["tessellated_clusters"] == 0 and faded.stats["micro_triangles"] == 0
    stage.GetPrimAtPath("/Looks/Puffy").GetAttribute("tessera:displacement:fadeStart").Set(0.0)
    stage.GetPrimAtPath("/Looks/Puffy").GetAttribute("tessera:displacement:fadeEnd").Set(0.0)
    stage.GetRootLayer().Save()
    shown = session_render(path)
    assert shown.stats["tessellated_clusters"] > 0 and covered(shown).sum() > covered(faded).sum()


def test_a_patch_list_overflow_redraws_the_same_image(tmp_path):
    runtime_stage, _ = write_stages(tmp_path, n=1)
    roomy = session_render(runtime_stage, resolution=(128, 128), dicing_rate=2.0)
    session = tessera.Session(str(runtime_stage), validation=True)
    session.delegate.set_patch_capacity(8)
    tight = session.render(camera="/Camera", resolution=(128, 128), aovs=("color", "primId"), dicing_rate=2.0)
    assert not tight.errors
    assert tight.stats["overflow_redraws"] >= 1 and tight.stats["patches"] > 8
    assert np.array_equal(tight["primId"].ids(), roomy["primId"].ids())
    assert np.array_equal(tight["color"].pixels, roomy["color"].pixels)


def test_micro_triangles_resolve_alike_from_kept_points_and_diced_again(tmp_path):
    """Resolve reads a micro-triangle from the points the compute patch rasterizer kept (a bin and a shader variant of
    their own), or, where the pool had no room, dices it again: the same micro-triangles, the same pixels."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    aovs = ("color", "depth", "normal", "primId")
    kept = session_render(runtime_stage, aovs=aovs, dicing_rate=2.0)
    session = tessera.Session(str(runtime_stage), validation=True)
    session.delegate.set_point_capacity(1)  # no patch's points fit: every micro-triangle is diced again
    diced = session.render(camera="/Camera", resolution=(256, 256), aovs=aovs, dicing_rate=2.0)
    assert not diced.errors
    assert kept.stats["kept_micro_pixels"] > 1000 and kept.stats["diced_micro_pixels"] == 0
    assert diced.stats["kept_micro_pixels"] == 0 and diced.stats["diced_micro_pixels"] == kept.stats["kept_micro_pixels"]
    assert np.array_equal(diced["primId"].ids(), kept["primId"].ids())
    # The id variant reads micro-triangles' payloads through their patches: every covered pixel names the sphere.
    ids = kept["primId"].ids()
    assert {kept.prim_path(int(i)) for i in np.unique(ids) if i != NO_HIT} == {"/Sphere"}
    for aov in ("color", "depth", "normal"):
        np.testing.assert_allclose(diced[aov].pixels, kept[aov].pixels, atol=1e-5, err_msg=aov)


def test_vertex_colours_on_micro_triangles_blend_with_their_corner_weights(tmp_path):
    """Vertex colours need each micro-triangle's corner weights on its source triangle, which kept points do not hold:
    their patches keep no points and resolve dices them again. The sphere is red at the top, blue at the bottom."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    stage = Usd.Stage.Open(str(runtime_stage))
    sphere = UsdGeom.Mesh(stage.GetPrimAtPath("/Sphere"))
    heights = np.asarray(sphere.GetPointsAttr().Get())[:, 1]
    colours = np.where(heights[:, None] > 0, [1.0, 0.05, 0.05], [0.05, 0.05, 1.0]).astype(np.float32)
    sphere.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(colours)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Bumps/Surface"))
    reader = UsdShade.Shader.Define(stage, "/Looks/Bumps/DisplayColor")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("displayColor")
    surface.GetInput("diffuseColor").ConnectToSource(reader.ConnectableAPI(), "result")
    stage.GetRootLayer().Save()

    result = session_render(runtime_stage, dicing_rate=2.0)
    assert result.stats["diced_micro_pixels"] > 1000 and result.stats["kept_micro_pixels"] == 0
    rows = np.nonzero(covered(result).any(axis=1))[0]
    top, bottom = rows[0] + (rows[-1] - rows[0]) // 5, rows[-1] - (rows[-1] - rows[0]) // 10  # the view is from above
    colour = result["color"].pixels[..., :3]
    upper, lower = colour[rows[0]:top][covered(result)[rows[0]:top]], colour[bottom:rows[-1]][covered(result)[bottom:rows[-1]]]
    assert (upper[:, 0] > 2 * upper[:, 2]).mean() > 0.95, "the top is red"
    assert (lower[:, 2] > 2 * lower[:, 0]).mean() > 0.9, "the bottom is blue"


def test_patches_hidden_by_the_previous_frame_are_deferred_and_tested_again(tmp_path):
    """Occlusion culling of patches: in a second frame the previous frame's HZB hides the back of the sphere, whose
    patches the main pass defers and the post pass drops; after the camera orbits to the other side, the deferred
    patches that came into view are drawn. Either way the image is the one a first frame draws."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    stage = Usd.Stage.Open(str(runtime_stage))
    orbit = UsdGeom.Camera.Define(stage, "/Orbit")
    orbit.GetFocalLengthAttr().Set(35.0)
    orbit.GetClippingRangeAttr().Set(Gf.Vec2f(0.05, 100))
    view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(-1.2, 0.8, -3.2), Gf.Vec3d(0, 0, 0), Gf.Vec3d(0, 1, 0))
    orbit.AddTransformOp().Set(view.GetInverse())
    stage.GetRootLayer().Save()

    def frame(session, camera):  # occlusion every frame: a sphere's back hides little of it, and occlusion would rest
        result = session.render(camera=camera, resolution=(192, 192), aovs=("color", "primId"), dicing_rate=2.0, occlusion="always")
        assert not result.errors
        return result

    session = tessera.Session(str(runtime_stage), validation=True)
    first, second = frame(session, "/Camera"), frame(session, "/Camera")
    assert first.stats["deferred_patches"] == 0, "a first frame has no previous HZB"
    assert second.stats["deferred_patches"] > 0 and second.stats["occluded_patches"] > 0
    assert second.stats["micro_triangles"] < first.stats["micro_triangles"]
    assert np.array_equal(second["primId"].ids(), first["primId"].ids())
    assert np.array_equal(second["color"].pixels, first["color"].pixels)

    moved = frame(session, "/Orbit")
    fresh = frame(tessera.Session(str(runtime_stage), validation=True), "/Orbit")
    assert moved.stats["deferred_patches"] > moved.stats["occluded_patches"], "some deferred patches came into view"
    assert np.array_equal(moved["primId"].ids(), fresh["primId"].ids())
    assert np.array_equal(moved["color"].pixels, fresh["color"].pixels)


def test_tessellation_memory_follows_the_view_down_as_well_as_up(tmp_path):
    """The kept-point pool and the patch lists grow to what a fine dicing rate asks (for the next frame), and drop back
    once a frame asks far less, so a view that moved away does not keep its peak memory."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    session = tessera.Session(str(runtime_stage), validation=True)

    def frame(rate):
        result = session.render(camera="/Camera", resolution=(640, 640), aovs=("primId",), dicing_rate=rate)
        assert not result.errors
        return result.stats["tessellation_bytes"]

    coarse = frame(8.0)
    frame(0.35)  # asks for more than the pool holds: it grows for the next frame
    fine = frame(0.35)
    assert fine > 4 * coarse, (coarse, fine)
    frame(8.0)  # still drawn with the grown pool, which is then found far too large
    assert frame(8.0) < fine / 4


@pytest.mark.parametrize("vis", [None, "tessellation"])
def test_openusd_displacement_scene(tmp_path, vis):
    """OpenUSD's testUsdImagingGLDisplacement: subdivided quad and triangle meshes displaced by a height map."""
    stage = shared_asset("openusd-testenv/testUsdImagingGLDisplacement/testUsdImagingGLDisplacement.usda")
    # Refined twice (Storm's baselines are at usdview's Very High, 1.3; ours were made at 1.2).
    result = session_render(stage, resolution=(320, 240), aovs=("color",), vis=vis, dicing_rate=2.0, complexity=1.2)
    assert result.stats["micro_triangles"] > 0
    name = "displacement" if vis is None else f"displacement_vis_{vis}"
    result.write(tmp_path / f"{name}.png")
    assert_matches_baseline(tmp_path / f"{name}.png", TESTENV / "testDisplacement" / "baseline" / f"{name}.png")


def bricks_height_map(width=256, height=128, rows=8, columns=4, mortar=0.06) -> np.ndarray:
    """A brick wall's heights: bricks at 1 with bevelled edges, mortar at 0, every other row offset by half a brick."""
    t = (np.arange(height) + 0.5) / height * rows
    s = (np.arange(width) + 0.5) / width * columns
    row = np.floor(t)[:, None]
    u = (s[None, :] + 0.5 * (row % 2)) % 1.0
    v = (t % 1.0)[:, None]
    edge = np.minimum(np.minimum(u, 1 - u) * 2.0, np.minimum(v, 1 - v))  # distance to the nearest joint (brick units)
    heights = np.clip((edge - mortar) / 0.08, 0.0, 1.0)
    return np.round(heights * 255).astype(np.uint8)


def test_bricks_height_map(tmp_path):
    """A flat, 2-triangle wall displaced by a bricks height map, seen at a grazing angle: the bricks stand out of the
    mortar towards the camera, and the image matches its baseline."""
    from tessera.bench_textures import write_png

    write_png(tmp_path / "bricks.png", bricks_height_map()[::-1])
    path = tmp_path / "wall.usda"
    stage = Usd.Stage.CreateNew(str(path))
    wall = UsdGeom.Mesh.Define(stage, "/Wall")
    wall.GetPointsAttr().Set([(-2, -1, 0), (2, -1, 0), (2, 1, 0), (-2, 1, 0)])
    wall.GetFaceVertexCountsAttr().Set([4])
    wall.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    wall.GetSubdivisionSchemeAttr().Set("none")
    st = UsdGeom.PrimvarsAPI(wall).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    bind(wall, displaced_material(stage, "/Looks/Bricks", texture=tmp_path / "bricks.png", magnitude=0.08))
    camera_at(stage, (-2.6, 0.4, 2.2), target=(0.3, 0, 0))
    stage.GetRootLayer().Save()
    result = session_render(path, resolution=(320, 200), aovs=("color", "depth", "primId"), dicing_rate=1.0)
    assert result.stats["tessellated_triangles"] == 2 and result.stats["micro_triangles"] > 10_000
    stage.GetPrimAtPath("/Looks/Bricks").GetAttribute("tessera:displacement:magnitude").Set(0.0)
    stage.GetRootLayer().Save()
    flat = session_render(path, resolution=(320, 200), aovs=("depth", "primId"))
    both = covered(result) & covered(flat)
    raised = flat["depth"].pixels[..., 0][both] - result["depth"].pixels[..., 0][both]
    assert 0.5 < (raised > 0.04).mean() < 0.97, "most of the wall is brick, standing out towards the camera"
    assert (np.abs(raised) < 0.01).mean() > 0.02, "the mortar stays where the wall was"
    result.write(tmp_path / "wall.png")
    assert_matches_baseline(tmp_path / "wall.png", TESTENV / "testDisplacement" / "baseline" / "bricks.png")


def test_opacity_masks_cut_micro_triangles(tmp_path):
    """A displaced quad whose textured opacity cuts holes (opacityThreshold): the holes show what lies behind, as they
    do on the same quad undisplaced."""
    from test_textures import checker, write_png as write_rgba_png

    write_rgba_png(tmp_path / "holes.png", checker(4, a=(255, 255, 255, 255), b=(255, 255, 255, 0)))
    path = tmp_path / "cut.usda"
    stage = Usd.Stage.CreateNew(str(path))
    quad = UsdGeom.Mesh.Define(stage, "/Quad")
    quad.GetPointsAttr().Set([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.GetFaceVertexCountsAttr().Set([4])
    quad.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    quad.GetSubdivisionSchemeAttr().Set("none")
    st = UsdGeom.PrimvarsAPI(quad).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    material = displaced_material(stage, "/Looks/Cut", constant=0.1)
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Cut/Surface"))
    surface.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    reader = UsdShade.Shader.Define(stage, "/Looks/Cut/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    holes = UsdShade.Shader.Define(stage, "/Looks/Cut/Holes")
    holes.CreateIdAttr("UsdUVTexture")
    holes.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(tmp_path / "holes.png"))
    holes.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(holes.ConnectableAPI(), "a")
    bind(quad, material)
    camera_at(stage, (0, 0, 3))
    stage.GetRootLayer().Save()
    for raster in ("auto", "hardware"):  # the compute patch rasterizer and the patch raster's hardware path
        displaced = session_render(path, resolution=(128, 128), dicing_rate=4.0, raster=raster)
        assert displaced.stats["micro_triangles"] > 0
        inside = covered(displaced)[24:104, 24:104]  # the quad fills the middle of the image
        assert 0.35 < inside.mean() < 0.65, f"{raster}: half the checker is cut away ({inside.mean():.2f} covered)"


def test_static_displacement_bakes_the_detail_into_the_mesh(tmp_path):
    """tessera:displacement:bake: the sphere is diced and displaced when it is built, so the DAG carries the detail: no
    runtime tessellation, many more source triangles, no cracks, and the same surface as the CPU reference."""
    runtime_stage, reference_stage = write_stages(tmp_path, n=24)
    stage = Usd.Stage.Open(str(runtime_stage))
    stage.GetPrimAtPath("/Looks/Bumps").CreateAttribute("tessera:displacement:bake", Sdf.ValueTypeNames.Bool).Set(True)
    stage.GetRootLayer().Save()
    baked = session_render(runtime_stage, lod=False)
    assert baked.stats["micro_triangles"] == 0 and baked.stats["tessellation_bytes"] == 0, "nothing is diced at render time"
    assert baked.stats["source_triangles"] > 20 * 528, "the 528-triangle sphere was diced to about a texel of its height map"
    assert enclosed_background(covered(baked)) == 0
    reference = session_render(reference_stage, lod=False)
    assert (covered(baked) == covered(reference)).mean() >= 0.995
    quality = psnr(baked["color"].pixels[..., :3], reference["color"].pixels[..., :3])
    assert quality >= 35.0, f"PSNR {quality:.1f} dB against the pre-tessellated reference"
    again = session_render(runtime_stage, lod=False)
    assert again.stats["meshes_cached"] == 1 and again.stats["meshes_built"] == 0, "a baked mesh is built once"


def test_editing_a_baked_displacement_builds_its_mesh_again(tmp_path):
    """A baked displacement lives in the built mesh: an edit of the material's bake (its magnitude, then the bake turned
    off) builds the bound mesh again; an edit that leaves the bake alone (the colour) builds nothing."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    stage = Usd.Stage.Open(str(runtime_stage))
    looks = stage.GetPrimAtPath("/Looks/Bumps")
    looks.CreateAttribute("tessera:displacement:bake", Sdf.ValueTypeNames.Bool).Set(True)
    session = tessera.Session(stage, validation=True)

    def render():
        result = session.render(camera="/Camera", resolution=(128, 128), aovs=("primId",))
        assert not result.errors, result.errors
        return result, result.stats["meshes_built"] + result.stats["meshes_cached"]

    baked, loaded = render()
    assert loaded == 1 and baked.stats["source_triangles"] > 20 * 528 and baked.stats["micro_triangles"] == 0
    stage.GetPrimAtPath("/Looks/Bumps/Surface").GetAttribute("inputs:diffuseColor").Set(Gf.Vec3f(0.2, 0.5, 0.8))
    recoloured, loaded = render()
    assert loaded == 0 and dict(session.index.last_synced) == {"/Looks/Bumps": tessera._tessera.dirty.PARAMS}
    looks.GetAttribute("tessera:displacement:magnitude").Set(0.4)
    taller, loaded = render()
    assert loaded == 1 and "/Sphere" in dict(session.index.last_synced)
    assert covered(taller).sum() > covered(baked).sum(), "the bumps grew"
    looks.GetAttribute("tessera:displacement:bake").Set(False)
    runtime, loaded = render()
    assert loaded == 1 and runtime.stats["source_triangles"] == 528 and runtime.stats["micro_triangles"] > 0
    assert (covered(runtime) == covered(taller)).mean() > 0.99, "the same surface, displaced at render time"


def test_static_displacement_does_not_tear_at_hard_edges_or_uv_seams(tmp_path):
    """The cube of hard edges and a UV island per face, its ramp height map differing across every edge, baked."""
    from tessera.bench_textures import write_png

    u, v = np.meshgrid((np.arange(16) + 0.5) / 16, (np.arange(16) + 0.5) / 16)
    write_png(tmp_path / "ramp.png", np.round((0.7 * u + 0.3 * v) * 255)[::-1].astype(np.uint8))
    path = tmp_path / "cube.usda"
    stage = Usd.Stage.CreateNew(str(path))
    cube = hard_cube(stage, "/Cube")
    material = displaced_material(stage, "/Looks/Ramp", texture=tmp_path / "ramp.png", magnitude=0.4)
    material.GetPrim().CreateAttribute("tessera:displacement:bake", Sdf.ValueTypeNames.Bool).Set(True)
    bind(cube, material)
    camera_at(stage, (1.6, 1.3, 2.0))
    stage.GetRootLayer().Save()
    result = session_render(path)
    assert result.stats["source_triangles"] > 12 * 16 and result.stats["micro_triangles"] == 0
    assert enclosed_background(covered(result)) == 0, "no background shows through the baked cube's edges"


def test_edits_beside_displaced_meshes_keep_their_displacement_data_and_draw_what_a_fresh_session_draws(tmp_path):
    """A mesh drawn displaced gets its displacement normals, UV seams and UV boxes once (`displaced_meshes_prepared`),
    and they go up with its streams, kept in place after: a second displaced mesh, a quad edited beside them and a
    removal make and write none again, and each frame is the one a fresh session draws of the stage as it then is (the
    second sphere's seam words placed after the first's)."""
    runtime_stage, _ = write_stages(tmp_path, n=1)
    stage = Usd.Stage.Open(str(runtime_stage))
    stage.SetEditTarget(stage.GetSessionLayer())
    live = tessera.Session(stage, validation=True)

    def render(session):
        result = session.render(camera="/Camera", resolution=(160, 160), aovs=("color", "primId"), dicing_rate=2.0)
        assert not result.errors, "\n".join(result.errors)
        return result

    def expect_fresh(result, what):
        assert np.array_equal(result["color"].pixels, render(tessera.Session(stage, validation=True))["color"].pixels), what

    first = render(live)
    assert first.stats["displaced_meshes_prepared"] == 1 and first.stats["micro_triangles"] > 0
    assert render(live).stats["displaced_meshes_prepared"] == 0, "nothing changed"

    sphere = UsdGeom.Mesh(stage.GetPrimAtPath("/Sphere"))
    second = UsdGeom.Mesh.Define(stage, "/Small")
    second.GetPointsAttr().Set([Gf.Vec3f(0.4 * p[0] + 0.9, 0.4 * p[1] + 0.6, 0.4 * p[2] + 0.5) for p in sphere.GetPointsAttr().Get()])
    for name in ("faceVertexCounts", "faceVertexIndices", "normals", "subdivisionScheme", "primvars:st"):
        source = sphere.GetPrim().GetAttribute(name)
        target = second.GetPrim().CreateAttribute(name, source.GetTypeName())
        target.Set(source.Get())
        for key in ("interpolation",):
            if source.HasMetadata(key):
                target.SetMetadata(key, source.GetMetadata(key))
    bind(second, UsdShade.MaterialBindingAPI(sphere.GetPrim()).GetDirectBinding().GetMaterial())
    added = render(live)
    assert added.stats["displaced_meshes_prepared"] == 1, "the small sphere's alone"
    assert len(set(added["primId"].ids().ravel()) - {NO_HIT}) == 2
    expect_fresh(added, "a second displaced mesh")

    quad = UsdGeom.Mesh.Define(stage, "/Quad")
    quad.GetFaceVertexCountsAttr().Set([4])
    quad.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    for step in range(2):
        x = -1.2 + 0.1 * step
        quad.GetPointsAttr().Set([(x, -1.0, 0.8), (x + 0.5, -1.0, 0.8), (x + 0.5, -0.5, 0.8), (x, -0.5, 0.8)])
        edited = render(live)
        assert edited.stats["displaced_meshes_prepared"] == 0
        assert 0 < edited.stats["geometry_upload_bytes"] < 1000, "the quad's streams alone, not the spheres' normals and seams"
        expect_fresh(edited, f"a quad edited beside them ({step})")
    stage.RemovePrim("/Small")
    removed = render(live)
    assert removed.stats["displaced_meshes_prepared"] == 0
    expect_fresh(removed, "the small sphere removed")
    # A displacement edit: the per-cluster bounds kept through the edits above are made again from the new magnitude.
    material = UsdShade.MaterialBindingAPI(sphere.GetPrim()).GetDirectBinding().GetMaterial().GetPrim()
    material.GetAttribute("tessera:displacement:magnitude").Set(0.3)
    deeper = render(live)
    assert not np.array_equal(deeper["color"].pixels, removed["color"].pixels)
    expect_fresh(deeper, "the displacement magnitude edited")
