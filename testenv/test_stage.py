"""Stage-level options and problems: purposes drawn, render settings, instancer cycles, missing payloads, --strict."""

import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender

import tessera
from tessera import cli

NO_HIT = 0xFFFFFFFF


def _quad(stage, path, x, purpose=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.GetPointsAttr().Set([(x - 0.4, -0.4, 0), (x + 0.4, -0.4, 0), (x + 0.4, 0.4, 0), (x - 0.4, 0.4, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if purpose:
        mesh.GetPurposeAttr().Set(purpose)
    return mesh


def _camera(stage, path="/Camera", aperture=(60.0, 10.0)):
    camera = UsdGeom.Camera.Define(stage, path)
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    camera.GetHorizontalApertureAttr().Set(aperture[0])
    camera.GetVerticalApertureAttr().Set(aperture[1])
    return camera


def _drawn(result):
    return {result.prim_path(int(i)) for i in np.unique(result["primId"].ids()) if i != NO_HIT}


def _purpose_stage():
    stage = Usd.Stage.CreateInMemory()
    _camera(stage)
    _quad(stage, "/Default", -2.5)
    _quad(stage, "/Render", -1.5, UsdGeom.Tokens.render)
    _quad(stage, "/Proxy", -0.5, UsdGeom.Tokens.proxy)
    _quad(stage, "/Guide", 2.5, UsdGeom.Tokens.guide)
    group = UsdGeom.Xform.Define(stage, "/ProxyGroup")
    group.GetPurposeAttr().Set(UsdGeom.Tokens.proxy)
    _quad(stage, "/ProxyGroup/RenderChild", 0.5, UsdGeom.Tokens.render)  # its own purpose wins over the inherited one
    _quad(stage, "/ProxyGroup/Inherits", 1.5)  # proxy, from its parent
    return stage


def test_render_purpose_by_default_and_proxy_on_request():
    stage = _purpose_stage()
    session = tessera.Session(stage, validation=True)
    result = session.render(camera="/Camera", resolution=(240, 40), aovs=["primId"])
    assert _drawn(result) == {"/Default", "/Render", "/ProxyGroup/RenderChild"}
    assert set(session.scene.rprims) == {"/Default", "/Render", "/ProxyGroup/RenderChild"}, "other purposes are not read"

    session = tessera.Session(stage, validation=True, purposes=("render", "proxy"))
    result = session.render(camera="/Camera", resolution=(240, 40), aovs=["primId"])
    assert _drawn(result) == {"/Default", "/Render", "/Proxy", "/ProxyGroup/RenderChild", "/ProxyGroup/Inherits"}

    session = tessera.Session(stage, validation=True, purposes=("proxy",))
    assert set(session.scene.rprims) == {"/Default", "/Proxy", "/ProxyGroup/Inherits"}
    with pytest.raises(tessera.StageError, match="unknown purpose 'bogus'"):
        tessera.Session(stage, purposes=("bogus",))


def test_purpose_edit_re_walks_the_prim():
    stage = _purpose_stage()
    session = tessera.Session(stage, validation=True)
    session.render(camera="/Camera", resolution=(240, 40), aovs=["primId"])
    stage.GetPrimAtPath("/Proxy").GetAttribute("purpose").Set(UsdGeom.Tokens.render)
    stage.GetPrimAtPath("/ProxyGroup").GetAttribute("purpose").Set(UsdGeom.Tokens.default_)
    result = session.render(camera="/Camera", resolution=(240, 40), aovs=["primId"])
    assert _drawn(result) == {"/Default", "/Render", "/Proxy", "/ProxyGroup/RenderChild", "/ProxyGroup/Inherits"}


def test_cli_purposes(tmp_path):
    stage_file = tmp_path / "purposes.usda"
    stage = _purpose_stage()  # held: the layer lives as long as its stage
    stage.GetRootLayer().Export(str(stage_file))
    counts = {}
    for purposes in (None, "render,proxy", "guide"):
        stats = tmp_path / "stats.json"
        argv = ["render", str(stage_file), "-o", str(tmp_path / "out.exr"), "--resolution", "120x20", "--stats", str(stats)]
        assert cli.main(argv + (["--purposes", purposes] if purposes else [])) == 0
        counts[purposes] = json.loads(stats.read_text())["rprims"]
    assert counts == {None: 3, "render,proxy": 5, "guide": 2}
    with pytest.raises(SystemExit):
        cli.main(["render", str(stage_file), "-o", str(tmp_path / "x.exr"), "--purposes", "render,bogus"])


# -- bad input -------------------------------------------------------------------------------------------------------

BAD = Path(__file__).parent / "testBadInput"


def test_instancer_cycle_is_an_error_naming_the_prims_and_the_rest_renders():
    session = tessera.Session(BAD / "instancer_cycle.usda", validation=True)
    result = session.render(resolution=(64, 64), aovs=["primId"])  # the framing camera's bounds leave the cycle out
    assert result.errors == ["/World/A: PointInstancer cycle (/World/A -> /World/A/Protos/B -> /World/A); "
                             "the copies inside the cycle are skipped"]
    assert _drawn(result) == {"/World/Good"}


def test_missing_payload_is_a_warning_naming_the_asset():
    result = tessera.Session(BAD / "missing_payload.usda", validation=True).render(resolution=(64, 64), aovs=["primId"])
    assert not result.errors
    [warning] = result.warnings
    assert warning.startswith("/World/Loaded: could not open asset @") and "missing_asset.usd@ for payload" in warning
    assert _drawn(result) == {"/World/Good"}


def test_a_variant_switched_to_a_missing_payload_is_reported_at_the_next_render():
    stage = Usd.Stage.CreateInMemory()
    _camera(stage)
    _quad(stage, "/Good", 0.0)
    holder = UsdGeom.Xform.Define(stage, "/Holder").GetPrim()
    variants = holder.GetVariantSets().AddVariantSet("load")
    for name in ("none", "missing"):
        variants.AddVariant(name)
    variants.SetVariantSelection("missing")
    with variants.GetVariantEditContext():
        holder.GetPayloads().AddPayload("./not_there.usd")
    variants.SetVariantSelection("none")
    session = tessera.Session(stage, validation=True)
    assert not session.render(camera="/Camera", resolution=(64, 16)).warnings
    variants.SetVariantSelection("missing")
    result = session.render(camera="/Camera", resolution=(64, 16), aovs=["primId"])
    assert len(result.warnings) == 1 and "not_there.usd" in result.warnings[0] and result.warnings[0].startswith("/Holder: ")
    assert _drawn(result) == {"/Good"}
    assert not session.render(camera="/Camera", resolution=(64, 16)).warnings, "reported once"


@pytest.mark.parametrize("stage_file, problems", [("missing_payload.usda", True), ("instancer_cycle.usda", True),
                                                   ("../testCube/cube.usda", False)])
def test_strict_exit_status(tmp_path, stage_file, problems):
    argv = ["render", str(BAD / stage_file), "-o", str(tmp_path / "out.exr"), "--resolution", "32x32"]
    assert cli.main(argv) == 0, "problems with the stage are reported, and the image written"
    assert cli.main(argv + ["--strict"]) == (1 if problems else 0)
    assert (tmp_path / "out.exr").exists()


# -- render settings -------------------------------------------------------------------------------------------------

SETTINGS = Path(__file__).parent / "testRenderSettings" / "render_settings.usda"


def test_render_settings_are_read_from_the_prim_the_stage_names():
    from tessera.usd import render_settings

    warnings = []
    settings = render_settings.read(Usd.Stage.Open(str(SETTINGS)), None, warnings)
    assert (settings.path, settings.camera, settings.resolution, settings.purposes) == ("/Render/Settings", "/World/Side", (200, 100), ("proxy",))
    beauty, depth = settings.products
    assert (beauty.name, beauty.camera, beauty.resolution, beauty.aovs) == ("beauty.exr", "/World/Side", (200, 100), ["color", "primId"])
    assert (depth.name, depth.camera, depth.resolution, depth.aovs) == ("passes/depth.exr", "/World/Top", (64, 48), ["depth"])
    assert warnings == ["/Render/Vars/Diffuse: lpe 'diffuse' is not an AOV Tessera writes (color, depth, normal, primId, "
                        "instanceId, clusterId, triangleId); it is skipped"]
    preview = render_settings.read(Usd.Stage.Open(str(SETTINGS)), "/Render/Preview", [])
    assert (preview.camera, preview.resolution, preview.purposes) == ("/World/Top", (40, 30), ("render",)), "includedPurposes' fallback"
    with pytest.raises(ValueError, match="/World/Box: not a RenderSettings prim"):
        render_settings.read(Usd.Stage.Open(str(SETTINGS)), "/World/Box", [])


def test_several_settings_without_a_choice_are_a_warning_and_the_only_one_is_used():
    from tessera.usd import render_settings

    stage = Usd.Stage.CreateInMemory()
    first = UsdRender.Settings.Define(stage, "/Render/First")
    first.GetResolutionAttr().Set(Gf.Vec2i(10, 20))
    warnings = []
    settings = render_settings.read(stage, None, warnings)
    assert settings.path == "/Render/First" and settings.resolution == (10, 20) and not warnings
    UsdRender.Settings.Define(stage, "/Render/Second")
    assert render_settings.read(stage, None, warnings) is None
    assert warnings == ["several RenderSettings prims (/Render/First, /Render/Second) and no renderSettingsPrimPath to "
                        "choose one; none is used"]
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Second")
    assert render_settings.read(stage, None, []).resolution == (2048, 1080), "the schema's fallback resolution"


def test_cli_writes_every_render_product(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # product names are relative to the working directory, as for husk
    stats = tmp_path / "stats.json"
    assert cli.main(["render", str(SETTINGS), "--stats", str(stats)]) == 0
    color, ids, depth = (tessera.read_image(str(tmp_path / name)) for name in ("beauty.exr", "beauty.primId.exr", "passes/depth.exr"))
    assert color.shape[:2] == ids.shape[:2] == (100, 200) and depth.shape[:2] == (48, 64)
    products = json.loads(stats.read_text())["products"]
    assert [(p["product"], p["camera"], p["aovs"], p["rprims"]) for p in products] == [
        ("/Render/Products/Beauty", "/World/Side", ["color", "primId"], 2), ("/Render/Products/Depth", "/World/Top", ["depth"], 2)]
    assert np.isfinite(depth[24, 32, 0]) and not np.isfinite(depth[0, 0, 0]), "the box seen from the top, background around it"
    assert cli.main(["render", str(SETTINGS), "--strict"]) == 1, "the unusable RenderVar is a warning"


def test_cli_flags_win_over_render_settings(tmp_path):
    stats = tmp_path / "stats.json"
    out = tmp_path / "out.exr"
    assert cli.main(["render", str(SETTINGS), "-o", str(out), "--resolution", "32x16", "--camera", "/World/Top",
                     "--purposes", "render", "--stats", str(stats)]) == 0
    saved = json.loads(stats.read_text())
    assert (saved["camera"], saved["resolution"], saved["aovs"], saved["rprims"]) == ("/World/Top", [32, 16], ["color", "primId"], 1)
    assert tessera.read_image(str(tmp_path / "out.primId.exr")).shape[:2] == (16, 32)
    assert cli.main(["render", str(SETTINGS), "-o", str(out), "--aov", "depth", "--settings", "/Render/Preview", "--stats", str(stats)]) == 0
    saved = json.loads(stats.read_text())
    assert (saved["camera"], saved["resolution"], saved["aovs"], saved["render_settings"]) == ("/World/Top", [40, 30], ["depth"], "/Render/Preview")


def test_session_reads_render_settings():
    session = tessera.Session(SETTINGS, validation=True)
    settings = session.render_settings()
    product = settings.products[1]
    result = session.render(camera=product.camera, resolution=product.resolution, aovs=product.aovs)
    assert result["depth"].pixels.shape[:2] == (48, 64)
    assert tessera.Session(Usd.Stage.CreateInMemory()).render_settings() is None


def test_pixel_samples_come_from_the_flag_else_the_render_settings(tmp_path):
    from tessera.usd import render_settings

    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    _quad(stage, "/Quad", 0.0)
    _camera(stage, aperture=(20.0, 15.0))
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.GetResolutionAttr().Set(Gf.Vec2i(32, 24))
    samples = settings.GetPrim().CreateAttribute("tessera:pixelSamples", Sdf.ValueTypeNames.Int)
    for bad in (0, 5000):
        samples.Set(bad)
        warnings = []
        assert render_settings.read(stage, None, warnings).pixel_samples is None
        assert warnings == [f"/Render/Settings: tessera:pixelSamples = {bad} is not a whole number from 1 to 4096; 1 sample is used"]
    samples.Set(4)
    assert render_settings.read(stage, None, []).pixel_samples == 4
    stage.GetRootLayer().Save()
    stats = tmp_path / "stats.json"
    out = str(tmp_path / "out.exr")
    assert cli.main(["render", str(tmp_path / "shot.usda"), "-o", out, "--stats", str(stats)]) == 0
    saved = json.loads(stats.read_text())
    assert saved["pixel_samples"] == 4 and saved["resolution"] == [32, 24]
    alpha = tessera.read_image(out)[..., 3]
    assert ((alpha > 0) & (alpha < 1)).any(), "the quad's edges are partly covered"
    assert cli.main(["render", str(tmp_path / "shot.usda"), "-o", out, "--pixel-samples", "2", "--stats", str(stats)]) == 0
    assert json.loads(stats.read_text())["pixel_samples"] == 2, "the flag wins"
    # The filter: the settings' token, else box; an unknown one is a warning naming the prim.
    pixel_filter = settings.GetPrim().CreateAttribute("tessera:pixelFilter", Sdf.ValueTypeNames.Token)
    pixel_filter.Set("gaussian")
    assert render_settings.read(stage, None, []).pixel_filter == "gaussian"
    pixel_filter.Set("sinc")
    warnings = []
    assert render_settings.read(stage, None, warnings).pixel_filter is None
    assert warnings == ["/Render/Settings: tessera:pixelFilter = 'sinc' is not one of box, gaussian; box is used"]
    pixel_filter.Set("gaussian")
    stage.GetRootLayer().Save()
    assert cli.main(["render", str(tmp_path / "shot.usda"), "-o", out, "--pixel-samples", "16", "--stats", str(stats)]) == 0
    soft = tessera.read_image(out)[..., 3]
    assert ((soft > 0) & (soft < 1)).sum() > ((alpha > 0) & (alpha < 1)).sum(), "the Gaussian's band is wider than the box's"
    with pytest.raises(SystemExit):
        cli.main(["render", str(tmp_path / "shot.usda"), "--pixel-samples", "0"])
