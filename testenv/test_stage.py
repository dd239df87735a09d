"""Stage-level options and problems: purposes drawn, render settings, instancer cycles, missing payloads, --strict."""

import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

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
