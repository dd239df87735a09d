"""OpenUSD's own Hydra test scenes against their Storm baselines, compared loosely, since Storm lights the scenes
with its camera light and Tessera with its default key and dome:

* the silhouettes must agree: intersection over union (IoU) of covered pixels at the baselines' 640x480, with the
  camera of the command that made each baseline (usdImagingGL-CMakeLists.txt: `-frameAll` is Tessera's framing
  camera, `-camera` the stage's, its window matched vertically as the test program does, neither the test
  program's default view, rebuilt here; `-complexity 1.N` is refine level N, Hydra's convention, none level 0);
* where the scene is about materials, every region drawn (one per prim and instance) must have Storm's colour
  there: the same hue, or both grey (`imagecompare.colour_class`), so a wrong binding fails; regions Storm leaves
  black (turned away from its camera light) are not compared.

Differences that remain, and why (also in docs/overview.md):
* Storm tessellates implicit spheres coarsely (10 segments) where Tessera's are round: IoU ~0.89-0.96 on spheres.
* Tiny objects (ni_pi's 40 spheres of ~6 px) lose about a fifth of their IoU to edge pixels alone.
* BasisCurves and Points are not drawn (instance.usda: IoU 0.77, with a warning naming each prim).
* Subdivision tags are read (interpolateBoundary, creases, corners, holes): subdivMesh agrees at IoU ~0.98, the
  pixels that differ lie along its outline.
* UsdPrimvarReaders drive every colour and scalar input of UsdPreviewSurface (the mesh's vertex channel carries the
  primvars; constant ones fold into the material): testPreviewSurfaceConnectedScalar's roughness per sphere is
  checked by its highlights below. testPreviewSurfacePrimvarReaderOpacity (an opacity reader without a threshold:
  Storm blends it) is not compared: Tessera has no translucency.
"""

import math

import numpy as np
import pytest

import tessera
from conftest import shared_asset
from imagecompare import colour_class, coverage_mask, intersection_over_union, same_colour

IMAGING = "openusd-testenv/testUsdImagingGL"
STORM_CAMERA = "/StormTestCamera"


def case(stage, baseline, min_iou, *, colours=False, camera=None, complexity=1.0, xfail_colours=None):
    """`camera`: None frames the stage (-frameAll), STORM_CAMERA is the test program's default view, else a stage
    camera. `complexity`: the baseline command's -complexity (1.0, the default, under which a cube mesh stays a cube).
    `xfail_colours`: why the colour check is known to fail."""
    name = stage.rsplit("/", 1)[-1].removesuffix(".usda") + (f"-complexity{complexity}" if complexity != 1.0 else "")
    marks = [pytest.mark.xfail(reason=xfail_colours, strict=True)] if xfail_colours else []
    return pytest.param(stage, baseline, min_iou, colours, camera, complexity, id=name, marks=marks)


CASES = [
    # PointInstancer: nesting either way, prototypes at the root, siblings, which orientations win, materials.
    case("PointInstancer/pi.usda", "PointInstancer/baseline/pi.png", 0.95),
    case("PointInstancer/pi_ni.usda", "PointInstancer/baseline/pi_ni.png", 0.95),
    case("PointInstancer/ni_pi.usda", "PointInstancer/baseline/ni_pi.png", 0.95),
    case("PointInstancer/pi_pi.usda", "PointInstancer/baseline/pi_pi.png", 0.94, colours=True),
    case("PointInstancer/pi_ni_pi.usda", "PointInstancer/baseline/pi_ni_pi.png", 0.95, colours=True),
    case("PointInstancer/pi_pi_which_rot.usda", "PointInstancer/baseline/pi_pi_which_rot.png", 0.95, colours=True),
    case("PointInstancer/pi_root_prototype.usda", "PointInstancer/baseline/pi_root_prototype.png", 0.94),
    case("PointInstancer/pi_sibling_pi.usda", "PointInstancer/baseline/pi_sibling_pi.png", 0.96),
    case("PointInstancer/pi_ni_material.usda", "PointInstancer/baseline/pi_ni_material.png", 0.95, colours=True),
    # Native instancing.
    case("Instancing/instancedCubes.usda", "Instancing/baseline/testUsdImagingGLInstancing_instancedCubes.png", 0.95),
    case("Instancing/nestedInstancedCubes.usda", "Instancing/baseline/testUsdImagingGLInstancing_nestedInstancedCubes.png", 0.94),
    case("Instancing/internal_ni.usda", "Instancing/baseline/testUsdImagingGLInstancing_internal_ni.png", 0.96),
    case("Instancing/ni_pi.usda", "Instancing/baseline/testUsdImagingGLInstancing_ni_pi.png", 0.78),
    case("Instancing/pi_ni_xform.usda", "Instancing/baseline/testUsdImagingGLInstancing_pi_ni_xform.png", 0.97,
         camera="/main_cam"),
    # Materials on native instances: the prototype's, the instance's (and its ancestors') inherited down, strength.
    case("InstancingWithMaterials/ni_2instances.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_2instances.png", 0.95, colours=True),
    case("InstancingWithMaterials/ni_2instances_per_instance_overrides_noshading.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_2instances_per_instance_overrides_noshading.png",
         0.95, colours=True),
    case("InstancingWithMaterials/ni_2instances_shaded.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_2instances_shaded.png", 0.95, colours=True),
    case("InstancingWithMaterials/ni_2instances_shaded_overrides.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_2instances_shaded_overrides.png",
         0.95, colours=True),
    case("InstancingWithMaterials/ni_ni_material_outside_prototype.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_ni_material_outside_prototype.png",
         0.93, colours=True, camera="/main_cam"),
    case("InstancingWithMaterials/ni_ni_material_binding_resolution.usda",
         "InstancingWithMaterials/baseline/testUsdImagingGLInstancingWithMaterials_ni_ni_material_binding_resolution.png",
         0.93, colours=True),
    # PreviewSurface: fallbacks and primvar-driven colours.
    case("PreviewSurface/testPreviewSurfaceFallback.usda", "PreviewSurface/baseline/testPreviewSurfaceFallback.png", 0.91),
    case("PreviewSurface/testPreviewSurfaceSpecular.usda", "PreviewSurface/baseline/testPreviewSurfaceSpecular.png", 0.93),
    case("PreviewSurface/testPreviewSurfaceConnectedScalar.usda",
         "PreviewSurface/baseline/testPreviewSurfaceConnectedScalar.png", 0.95, colours=True),
    case("PreviewSurface/testPreviewSurfaceTextureFallback.usda",
         "PreviewSurface/baseline/testPreviewSurfaceTextureFallback.png", 0.98, colours=True),
    case("PreviewSurface/testPreviewSurfaceTextureNoFile.usda",
         "PreviewSurface/baseline/testPreviewSurfaceTextureNoFile.png", 0.98, colours=True),
    # Storm draws it black (a primvar reader without its primvar or a fallback reads 0), as Tessera does. Black is what
    # the colour check cannot tell from an unlit face, so only the silhouette is compared.
    case("PreviewSurface/testPreviewSurfaceFallbackPrimvar.usda",
         "PreviewSurface/baseline/testPreviewSurfaceFallbackPrimvar.png", 0.98),
    case("PreviewSurface/testPreviewSurfacePrimvarFallback.usda",
         "PreviewSurface/baseline/testPreviewSurfacePrimvarFallback.png", 0.98, colours=True),
    case("PreviewSurface/testPreviewSurfaceMaterialInterface.usda",
         "PreviewSurface/baseline/testPreviewSurfaceMaterialInterface.png", 0.93, colours=True),
    case("PreviewSurface/testPreviewSurfaceInstancedMaterial.usda",
         "PreviewSurface/baseline/testPreviewSurfaceInstancedMaterial.png", 0.95, colours=True),
    # Subdivision (creases, corners, holes; a left-handed mesh) at -complexity 1.1 to 1.3. subdivMesh's tags
    # (interpolateBoundary edgeOnly, creases, corners) round its outer corners as Storm does: IoU 0.98 (0.87 without
    # the tags, which kept those corners sharp).
    case("SubdivisionOsd3/subdivMesh.usda", "SubdivisionOsd3/baseline/testUsdImagingGLSubdivision_1_1.png", 0.96,
         camera=STORM_CAMERA, complexity=1.1),
    case("SubdivisionOsd3/subdivMesh.usda", "SubdivisionOsd3/baseline/testUsdImagingGLSubdivision_1_3.png", 0.96,
         camera=STORM_CAMERA, complexity=1.3),
    case("SubdivisionOsd3/lefthandedMesh.usda", "SubdivisionOsd3/baseline/testUsdImagingGLSubdivision_lefthanded_1_2.png",
         0.98, complexity=1.2),
]


def storm_default_camera(stage) -> str:
    """Adds (in the session layer) testUsdImagingGLBasicDrawing's view when given neither -camera nor -frameAll: from
    (0, 1000, 2500) down -Z in its Y-up view, a 60 degree vertical field of view, Z-up stages turned to Y-up first."""
    from pxr import Gf, Usd, UsdGeom

    view = Gf.Matrix4d().SetTranslate(Gf.Vec3d(0, -1000, -2500))
    if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z:
        view = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(1, 0, 0), -90)) * view
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        camera = UsdGeom.Camera.Define(stage, STORM_CAMERA)
        camera.AddTransformOp().Set(view.GetInverse())
        vertical = 2 * 50.0 * math.tan(math.radians(30))
        camera.GetFocalLengthAttr().Set(50.0)
        camera.GetVerticalApertureAttr().Set(vertical)
        camera.GetHorizontalApertureAttr().Set(vertical * 640 / 480)
        camera.GetClippingRangeAttr().Set(Gf.Vec2f(1, 100000))
    return STORM_CAMERA


def match_vertically(stage, camera_path):
    """The test program conforms a stage camera's window to the image by keeping its vertical aperture (the
    horizontal one cropped or grown), where Tessera fits the window (both apertures stay in view: the smaller grows).
    Conformed here, in the session layer, so that the comparison is of what the scene places, not of the policy."""
    from pxr import Usd, UsdGeom

    camera = UsdGeom.Camera(stage.GetPrimAtPath(camera_path))
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        camera.GetHorizontalApertureAttr().Set(camera.GetVerticalApertureAttr().Get() * 640 / 480)


def storm_baseline(relative):
    storm = np.asarray(tessera.read_image(str(shared_asset(f"{IMAGING}{relative}"))))[..., :3]
    return storm, coverage_mask(storm, storm[2, 2])  # the corner is the clear colour


def colour_mismatches(result, storm, storm_covered, min_pixels=40):
    """Regions (one per prim and instance drawn) whose colour differs from Storm's at the same pixels."""
    ours = np.asarray(result["color"].pixels)[..., :3]
    prims = np.asarray(result["primId"].ids()).astype(np.uint64)
    regions = prims << np.uint64(32) | np.asarray(result["instanceId"].ids()).astype(np.uint64)
    regions[prims == 0xFFFFFFFF] = np.iinfo(np.uint64).max
    mismatches = []
    for region in np.unique(regions[storm_covered]):
        pixels = (regions == region) & storm_covered
        if region == np.iinfo(np.uint64).max or pixels.sum() < min_pixels:
            continue
        expected, found = colour_class(storm[pixels]), colour_class(ours[pixels])
        if expected[0] == "dark":
            continue  # faces Storm's camera light leaves black say nothing of their material
        if not same_colour(expected, found):
            prim = result.prim_path(int(region >> np.uint64(32)))
            mismatches.append(f"{prim} instance {int(region & np.uint64(0xFFFFFFFF))}: Storm {expected}, ours {found}")
    return mismatches


@pytest.mark.parametrize("stage,baseline,min_iou,colours,camera,complexity", CASES)
def test_matches_storm(render, tmp_path, stage, baseline, min_iou, colours, camera, complexity):
    from pxr import Usd

    storm, storm_covered = storm_baseline(baseline)
    opened = Usd.Stage.Open(str(shared_asset(f"{IMAGING}{stage}")))
    if camera == STORM_CAMERA:
        storm_default_camera(opened)
    elif camera is not None:
        match_vertically(opened, camera)
    result = render(opened, camera=camera, resolution=(640, 480), aovs=("color", "primId", "instanceId"),
                    complexity=complexity)
    result.write(tmp_path / "ours.png")  # kept for a look when the test fails
    ours_covered = np.asarray(result["primId"].ids()) != 0xFFFFFFFF
    iou = intersection_over_union(ours_covered, storm_covered)
    assert iou >= min_iou, f"silhouette IoU with Storm's baseline is {iou:.3f}"
    if colours:
        mismatches = colour_mismatches(result, storm, storm_covered)
        assert not mismatches, "colours differ from Storm's:\n" + "\n".join(mismatches)


@pytest.mark.parametrize("stage,baseline,frames", [
    ("PointInstancer/pi_basic.usda", "PointInstancer/baseline/pi_basic_{:03d}.png", (1, 2)),
    ("PointInstancer/pi_masking.usda", "PointInstancer/baseline/pi_masking_{:03d}.png", (0, 1, 2, 3, 4)),
], ids=["pi_basic", "pi_masking"])
def test_time_samples_match_storm(stage, baseline, frames):
    """Animated prototypes and invisibleIds over time, one session moved from frame to frame (Storm's -times)."""
    session = tessera.Session(shared_asset(f"{IMAGING}{stage}"), frame=frames[0], validation=True, complexity=1.0)
    for frame in frames:
        session.set_time(frame)
        result = session.render(camera=None, resolution=(640, 480), aovs=("primId",))
        assert not result.errors, "\n".join(result.errors)
        storm, storm_covered = storm_baseline(baseline.format(frame))
        iou = intersection_over_union(np.asarray(result["primId"].ids()) != 0xFFFFFFFF, storm_covered)
        assert iou >= 0.93, f"frame {frame}: silhouette IoU with Storm's baseline is {iou:.3f}"


def test_teapot_renders_as_a_refined_subdivision_surface(render):
    teapot = shared_asset("usd-wg/full_assets/Teapot/Teapot.usd")
    cage = render(teapot, camera=None, resolution=(320, 240), aovs=("primId",), complexity=1.0)
    refined = render(teapot, camera=None, resolution=(320, 240), aovs=("primId",), complexity=1.2)
    assert refined.stats["source_triangles"] > 10 * cage.stats["source_triangles"], "catmullClark refined twice: about 16x"
    coverage = float((refined["primId"].ids() != 0xFFFFFFFF).mean())
    assert 0.05 < coverage < 0.6, f"the framed teapot covers {coverage:.2%} of the image"


def test_connected_scalar_roughness_comes_from_each_spheres_primvar(render):
    """testPreviewSurfaceConnectedScalar: a UsdPrimvarReader_float drives roughness from a constant primvar per sphere
    (0, 0.2, ... 1). Each is folded into its own copy of the material: the sharper the highlight, the brighter."""
    from pxr import Usd

    opened = Usd.Stage.Open(str(shared_asset(f"{IMAGING}PreviewSurface/testPreviewSurfaceConnectedScalar.usda")))
    result = render(opened, camera=None, resolution=(640, 480), aovs=("color", "primId"))
    assert not [w for w in result.warnings if "roughness" in w], result.warnings
    colour = np.asarray(result["color"].pixels)[..., :3].max(axis=2)
    prims = np.asarray(result["primId"].ids())
    peaks = {}
    for prim in np.unique(prims[prims != 0xFFFFFFFF]):
        path = result.prim_path(int(prim))
        roughness = opened.GetPrimAtPath(path.rsplit("/", 1)[0] if "pSphere" not in path.rsplit("/", 1)[-1] else path)
        value = roughness.GetAttribute("primvars:roughness").Get() if roughness.GetAttribute("primvars:roughness") else None
        if value is not None:
            peaks[float(value)] = float(colour[prims == prim].max())
    assert len(peaks) == 6, peaks
    # Roughness 0 is a mirror whose highlight (the key light's small disk) may fall between pixels: from 0.2 on, the
    # rougher the dimmer.
    ordered = [peaks[r] for r in sorted(peaks)][1:]
    assert all(a >= b * 0.98 for a, b in zip(ordered, ordered[1:])) and ordered[0] > 2 * ordered[-1], peaks
