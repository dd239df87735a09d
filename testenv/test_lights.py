"""UsdLux area lights (RectLight, SphereLight) and DomeLight textures: exact values where the shading is exact (the
diffuse irradiance of a sphere and of a rectangle), orientation conventions, edits, bad files, and image baselines."""

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

import tessera
from conftest import TESTENV
from imagecompare import assert_matches_baseline

LIGHTS = TESTENV / "testLights"
SIZE = 101  # the image centre is pixel 50


def _x(column):
    """The floor's x (or z, for a row) that a pixel's centre sees."""
    return ((column + 0.5) / SIZE - 0.5) * 20.0


def _floor_stage():
    """A white, diffuse-only floor (y = 0, facing +Y) seen from straight above by an orthographic camera 20 units
    across: pixel (row, column) looks at x = _x(column), z = _x(row)."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    floor = UsdGeom.Mesh.Define(stage, "/Floor")
    floor.GetPointsAttr().Set([(-10, 0, -10), (10, 0, -10), (10, 0, 10), (-10, 0, 10)])
    floor.GetFaceVertexCountsAttr().Set([4])
    floor.GetFaceVertexIndicesAttr().Set([0, 3, 2, 1])
    floor.GetSubdivisionSchemeAttr().Set("none")
    floor.CreateDisplayColorAttr([(1, 1, 1)])  # no material: diffuse only, albedo 1
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 10, 0))
    camera.AddRotateXOp().Set(-90)
    camera.GetProjectionAttr().Set(UsdGeom.Tokens.orthographic)
    camera.GetHorizontalApertureAttr().Set(200.0)  # tenths of a unit: 20 units across
    camera.GetVerticalApertureAttr().Set(200.0)
    camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.1, 100))
    return stage


def _render(stage, session=None):
    session = session or tessera.Session(stage, validation=True)
    result = session.render(camera="/Camera", resolution=(SIZE, SIZE), aovs=["color"])
    assert not result.errors, result.errors
    result.session = session
    return result


def _corner_form_factor(a, b, d):
    """Form factor from a point to a rectangle a x b parallel to it at distance d, the point under one corner."""
    x, y = a / d, b / d
    return (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x)) +
            y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)


def test_sphere_light_delivers_the_exact_irradiance_of_a_sphere():
    stage = _floor_stage()
    light = UsdLux.SphereLight.Define(stage, "/Bulb")
    light.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
    light.GetRadiusAttr().Set(0.5)
    light.GetIntensityAttr().Set(3.0)
    pixels = _render(stage)["color"].pixels
    # Wholly above the horizon, a sphere of radiance L delivers pi L (r / d)^2 cos(theta): a white Lambert floor
    # returns L (r / d)^2 cos(theta).
    for column in (50, 60, 75):
        x = _x(column)
        d2 = x * x + 4.0
        expected = 3.0 * 0.25 / d2 * (2.0 / math.sqrt(d2))
        assert pixels[50, column, :3] == pytest.approx([expected] * 3, rel=2e-3), column


def test_lights_beyond_the_frame_budget_are_named_in_a_warning():
    """A frame is lit by at most 8 lights: a stage with more keeps its distant light and the first bulbs in path order,
    and the warning names every bulb left out (never dropped silently)."""
    stage = _floor_stage()
    sun = UsdLux.DistantLight.Define(stage, "/Z/Sun")  # last in path order, kept first
    sun.GetIntensityAttr().Set(0.5)
    for i in range(10):
        bulb = UsdLux.SphereLight.Define(stage, f"/Bulb{i}")
        bulb.AddTranslateOp().Set(Gf.Vec3d(-9 + 2 * i, 1, 0))
        bulb.GetRadiusAttr().Set(0.2)
    result = _render(stage)
    dropped = [w for w in result.warnings if "at most 8" in w]
    assert len(dropped) == 1 and dropped[0].endswith("left out /Bulb7, /Bulb8, /Bulb9"), result.warnings
    pixels = result["color"].pixels
    lit_by_bulb = lambda i: pixels[50, int((-9 + 2 * i + 10) / 20 * SIZE), 0]
    assert lit_by_bulb(6) > 2 * lit_by_bulb(8), "the floor under a kept bulb is brighter than under one left out"


def _cone_irradiance(cos_theta, sin_sigma, steps=600):
    """The integral of max(cos, 0) to the normal over a cone of half-angle sigma whose axis makes angle theta with the
    normal, by quadrature: what a sphere light straddling the horizon delivers per unit radiance."""
    sigma, theta = math.asin(sin_sigma), math.acos(cos_theta)
    t = (np.arange(steps) + 0.5) / steps * sigma
    p = (np.arange(2 * steps) + 0.5) / (2 * steps) * 2 * math.pi
    t, p = np.meshgrid(t, p, indexing="ij")
    # Direction within the cone (axis tilted by theta from the normal, in the normal's x-y plane): its normal component.
    cosine = np.cos(t) * math.cos(theta) - np.sin(t) * np.cos(p) * math.sin(theta)
    return float((np.maximum(cosine, 0) * np.sin(t)).sum() * (sigma / steps) * (math.pi / steps))


def test_sphere_light_across_the_horizon():
    stage = _floor_stage()
    light = UsdLux.SphereLight.Define(stage, "/Bulb")
    light.AddTranslateOp().Set(Gf.Vec3d(0, 0.3, 0))  # low: part of it lies below the horizon of nearby points
    light.GetRadiusAttr().Set(0.5)
    pixels = _render(stage)["color"].pixels
    for column in (54, 56):
        x = _x(column)
        distance = math.hypot(x, 0.3)
        expected = _cone_irradiance(0.3 / distance, 0.5 / distance) / math.pi  # a white Lambert floor: E / pi
        assert 0.3 / distance < 0.5 / distance, "the sphere straddles this point's horizon"
        assert pixels[50, column, 0] == pytest.approx(expected, rel=3e-3), column


def test_sphere_light_normalize_exposure_colour_and_scale():
    def centre(normalize):
        stage = _floor_stage()
        light = UsdLux.SphereLight.Define(stage, "/Bulb")
        light.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
        light.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))  # radius 0.25 scaled to 0.5 in the world
        light.GetRadiusAttr().Set(0.25)
        light.GetIntensityAttr().Set(1.5)
        light.GetExposureAttr().Set(1.0)  # 3
        light.GetColorAttr().Set(Gf.Vec3f(1.0, 0.5, 0.0))
        light.GetNormalizeAttr().Set(normalize)  # radiance / (4 pi r^2), r the world radius
        return _render(stage)["color"].pixels[50, 50, :3]

    # Under it: L (r / d)^2 with r = 0.5, d = 2.
    assert centre(False) == pytest.approx([3.0 / 16, 1.5 / 16, 0.0], rel=2e-3, abs=1e-6)
    radiance = 3.0 / (4 * math.pi * 0.25)
    assert centre(True) == pytest.approx([radiance / 16, 0.5 * radiance / 16, 0.0], rel=2e-3, abs=1e-6)


def test_rect_light_delivers_the_irradiance_of_a_rectangle_from_its_front_only():
    stage = _floor_stage()
    light = UsdLux.RectLight.Define(stage, "/Panel")
    light.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
    rotate = light.AddRotateXOp()
    rotate.Set(-90.0)  # its -Z (the side it emits from) turned down to the floor
    light.GetWidthAttr().Set(2.0)
    light.GetHeightAttr().Set(1.0)
    light.GetIntensityAttr().Set(3.0)
    session = tessera.Session(stage, validation=True)
    pixels = _render(stage, session)["color"].pixels
    # Under the centre: four rectangles of 1 x 0.5 meeting there, 2 units up. A white Lambert floor returns L * F.
    expected = 3.0 * 4 * _corner_form_factor(1.0, 0.5, 2.0)
    assert pixels[50, 50, :3] == pytest.approx([expected] * 3, rel=2e-3)
    # Off centre along x (the light's width): rectangles of (1 - x) and (1 + x) by 0.5 on either side of the point.
    x = _x(58)
    expected = 3.0 * 2 * (_corner_form_factor(1 + x, 0.5, 2.0) - _corner_form_factor(x - 1, 0.5, 2.0))
    assert pixels[50, 58, :3] == pytest.approx([expected] * 3, rel=5e-3)
    # Turned to face up, its back faces the floor: nothing arrives.
    rotate.Set(90.0)
    result = _render(stage, session)
    assert np.abs(result["color"].pixels[..., :3]).max() == 0.0
    assert result.stats["synced"] == {"rectLight": 1}, "a light edit re-syncs that light alone"


def test_rect_light_normalize_divides_by_its_world_area():
    def centre(width, height, scale):
        stage = _floor_stage()
        light = UsdLux.RectLight.Define(stage, "/Panel")
        light.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
        light.AddRotateXOp().Set(-90.0)
        light.AddScaleOp().Set(Gf.Vec3f(scale, scale, 1))
        light.GetWidthAttr().Set(width)
        light.GetHeightAttr().Set(height)
        light.GetIntensityAttr().Set(6.0)
        light.GetNormalizeAttr().Set(True)
        return _render(stage)["color"].pixels[50, 50, 0]

    expected = 6.0 / 2.0 * 4 * _corner_form_factor(1.0, 0.5, 2.0)
    assert centre(2.0, 1.0, 1.0) == pytest.approx(expected, rel=2e-3)
    assert centre(1.0, 0.5, 2.0) == pytest.approx(expected, rel=2e-3), "the transform's scale sizes the light"


def test_a_light_edit_re_syncs_only_that_light():
    stage = _floor_stage()
    bulb = UsdLux.SphereLight.Define(stage, "/Bulb")
    bulb.AddTranslateOp().Set(Gf.Vec3d(0, 2, 0))
    bulb.GetRadiusAttr().Set(0.5)
    panel = UsdLux.RectLight.Define(stage, "/Panel")
    panel.AddTranslateOp().Set(Gf.Vec3d(5, 2, 0))
    panel.AddRotateXOp().Set(-90.0)
    first = _render(stage)
    session = first.session
    before = first["color"].pixels[50, 50, 0]
    bulb.GetRadiusAttr().Set(1.0)  # four times the irradiance right under it (plus the panel's, unchanged)
    second = _render(stage, session)
    assert second.stats["synced"] == {"sphereLight": 1}
    assert list(session.index.last_synced) == ["/Bulb"]
    panel_share = before - 1.0 * 0.25 / 4.0
    assert second["color"].pixels[50, 50, 0] == pytest.approx(1.0 * 1.0 / 4.0 + panel_share, rel=3e-3)


def test_area_lights_image(tmp_path):
    session = tessera.Session(LIGHTS / "area_lights.usda", validation=True)
    result = session.render(camera="/World/Camera", resolution=(320, 200))
    assert not result.errors and not result.warnings, result.errors + result.warnings
    out = tmp_path / "area_lights.png"
    result.write(out)
    assert_matches_baseline(out, LIGHTS / "baseline" / out.name)


# -- dome textures ---------------------------------------------------------------------------------------------------

def _marker_image(path):
    """A lat-long image of four vertical bands centred on the axes as OpenEXR's convention places them: red at +X
    (u = 0.25), green at +Z (0.5), blue at -X (0.75), white at -Z (the seam)."""
    import sys

    sys.path.insert(0, str(TESTENV / "testTextures"))
    from make_textures import write_png

    image = np.full((32, 64, 3), 255, np.uint8)
    u = (np.arange(64) + 0.5) / 64
    image[:, (u >= 0.125) & (u < 0.375)] = (255, 0, 0)
    image[:, (u >= 0.375) & (u < 0.625)] = (0, 255, 0)
    image[:, (u >= 0.625) & (u < 0.875)] = (0, 0, 255)
    write_png(path, image)
    return path


def _dome_stage(texture):
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    ball = UsdGeom.Sphere.Define(stage, "/Ball")
    ball.CreateDisplayColorAttr([(1, 1, 1)])
    dome = UsdLux.DomeLight.Define(stage, "/Sky")
    dome.GetTextureFileAttr().Set(Sdf.AssetPath(str(texture)))
    # Cameras far away (the ball covers the image's middle only) looking along -Z, +X, +Z and -X.
    for name, turn in (("ToNegZ", 0), ("ToPosX", -90), ("ToPosZ", 180), ("ToNegX", 90)):
        camera = UsdGeom.Camera.Define(stage, f"/{name}")
        camera.AddRotateYOp().Set(turn)
        camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 20))
    return stage, dome


def test_dome_texture_is_seen_in_the_lat_long_orientation_of_usdlux(tmp_path):
    stage, dome = _dome_stage(_marker_image(tmp_path / "markers.png"))
    dome.GetIntensityAttr().Set(2.0)
    session = tessera.Session(stage, validation=True)
    # Straight along each axis on the horizon, the background is the marker there (OpenEXR's convention: +X at
    # u = 0.25, +Z at 0.5, -X at 0.75, -Z at the seam), times the light's radiance.
    expected = {"ToNegZ": (2, 2, 2), "ToPosX": (2, 0, 0), "ToPosZ": (0, 2, 0), "ToNegX": (0, 0, 2)}
    for camera, color in expected.items():
        result = session.render(camera=f"/{camera}", resolution=(64, 48))
        assert not result.errors and not result.warnings, result.errors + result.warnings
        pixels = result["color"].pixels
        assert pixels[24, 4, :3] == pytest.approx(color, abs=1e-3), camera  # the horizon, beside the ball
        assert pixels[24, 4, 3] == 1.0
        # The ball's middle faces the camera, i.e. the opposite marker; its irradiance leans that way.
        ball = pixels[24, 32, :3]
        facing = {"ToNegZ": 1, "ToPosZ": None, "ToPosX": 2, "ToNegX": 0}[camera]  # channel of the marker behind the camera
        if facing is not None:
            others = [c for c in range(3) if c != facing]
            assert ball[facing] > ball[others[0]] + 0.1 and ball[facing] > ball[others[1]] + 0.1, (camera, ball)
    assert result.stats["textures"] == 1 and result.stats["texture_bytes"] > 0


def test_dome_irradiance_coefficients(tmp_path):
    """The marker image's first band (y, z, x) points at its colours: red towards +X, blue towards -X, white (red and
    blue, green being everywhere but at +-X) towards -Z; nothing up or down."""
    coefficients = np.asarray(tessera._tessera.latlong_irradiance(str(_marker_image(tmp_path / "m.png")))).reshape(9, 3)
    assert coefficients[3, 0] > 0.1 and coefficients[3, 2] < -0.1, "+X red, -X blue"
    assert coefficients[2, 0] < -0.1 and coefficients[2, 2] < -0.1 and abs(coefficients[2, 1]) < 1e-3, "-Z white, +Z green"
    assert np.abs(coefficients[1]).max() < 1e-3, "no colour leans up or down"


def test_uniform_dome_image_lights_like_its_colour(tmp_path):
    """A uniform image's irradiance is pi times its radiance everywhere: only the constant coefficient remains."""
    import sys

    sys.path.insert(0, str(TESTENV / "testTextures"))
    from make_textures import write_png

    write_png(tmp_path / "grey.png", np.full((64, 128, 3), 255, np.uint8))
    coefficients = np.asarray(tessera._tessera.latlong_irradiance(str(tmp_path / "grey.png"))).reshape(9, 3)
    assert coefficients[0] * 0.282095 == pytest.approx([1.0] * 3, abs=2e-3)
    assert np.abs(coefficients[1:]).max() < 2e-3
    # Rendered: a white diffuse ball under a white image of radiance 1 returns 1, like a uniform white dome.
    stage, dome = _dome_stage(tmp_path / "grey.png")
    result = tessera.Session(stage, validation=True).render(camera="/ToNegZ", resolution=(64, 48))
    assert result["color"].pixels[24, 32, :3] == pytest.approx([1.0] * 3, abs=5e-3)


def test_missing_dome_texture_is_a_warning_and_the_dome_lights_by_its_colour():
    stage, dome = _dome_stage("no_such_sky.exr")
    dome.GetColorAttr().Set(Gf.Vec3f(0.5, 0.25, 1.0))
    result = tessera.Session(stage, validation=True).render(camera="/ToNegZ", resolution=(64, 48))
    assert not result.errors
    assert any(w.startswith("/Sky: dome texture '") and "no_such_sky.exr" in w and "no such file" in w for w in result.warnings), result.warnings
    pixels = result["color"].pixels
    assert pixels[24, 4] == pytest.approx([0.5, 0.25, 1.0, 1.0], abs=1e-6), "the background is the dome's colour"
    assert pixels[24, 32, :3] == pytest.approx([0.5, 0.25, 1.0], abs=2e-3), "a white diffuse ball returns the uniform dome"
    assert result.stats["texture_bytes"] == 0


def test_editing_the_dome_texture_re_syncs_the_dome_alone(tmp_path):
    stage, dome = _dome_stage("no_such_sky.exr")
    session = tessera.Session(stage, validation=True)
    session.render(camera="/ToNegZ", resolution=(64, 48))
    dome.GetTextureFileAttr().Set(Sdf.AssetPath(str(_marker_image(tmp_path / "markers.png"))))
    result = session.render(camera="/ToPosX", resolution=(64, 48))
    assert result.stats["synced"] == {"domeLight": 1} and not result.warnings
    assert result["color"].pixels[24, 4, :3] == pytest.approx([1, 0, 0], abs=1e-3), "the red band at +X"


def test_dome_texture_image(tmp_path):
    session = tessera.Session(LIGHTS / "dome_texture.usda", validation=True)
    result = session.render(camera="/World/Camera", resolution=(320, 200))
    assert not result.errors and not result.warnings, result.errors + result.warnings
    out = tmp_path / "dome_texture.png"
    result.write(out)
    assert_matches_baseline(out, LIGHTS / "baseline" / out.name)
