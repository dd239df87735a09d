"""Shared test set-up: every render runs with the Khronos validation layer and fails on any message."""

import os
from pathlib import Path

import pytest

import atexit
import shutil
import tempfile

os.environ.setdefault("TESSERA_VALIDATION", "1")
# Each test run gets its own mesh cache, removed afterwards: tests neither read nor write the user's.
os.environ["TESSERA_CACHE"] = tempfile.mkdtemp(prefix="tessera-test-cache-")
atexit.register(shutil.rmtree, os.environ["TESSERA_CACHE"], True)

TESTENV = Path(__file__).parent
SHARED_ASSETS = (TESTENV.parent.parent / "shared" / "assets").resolve()


def shared_asset(relative: str) -> Path:
    """A file under ../shared/assets, or a skip that says what is missing."""
    path = SHARED_ASSETS / relative
    if not path.exists():
        pytest.skip(f"shared asset {path} is not present (expected beside the project in ../shared/assets)")
    return path


def stage_with_camera():
    """An in-memory stage with /Camera at z = 10 looking down -z, apertures 40 x 20 mm (it sees x in [-8, 8] and y in
    [-4, 4] at z = 0)."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    camera.GetHorizontalApertureAttr().Set(40.0)
    camera.GetVerticalApertureAttr().Set(20.0)
    return stage


def preview_material(stage, path, color):
    """A UsdPreviewSurface material of one diffuse colour at `path`."""
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


@pytest.fixture
def render():
    """Renders a stage with validation on and asserts that no validation message and no error came out."""
    import tessera

    def _render(stage, *, resolution=(256, 256), camera="auto", aovs=("color",), expect_errors=False, **session_args):
        session = tessera.Session(stage, validation=True, **session_args)
        assert session.delegate.validation_enabled, "tests run with the Khronos validation layer"
        if camera == "auto":
            camera = session.camera_paths()[0] if session.camera_paths() else None
        result = session.render(camera=camera, resolution=resolution, aovs=aovs)
        validation = [e for e in result.errors if e.startswith("validation")]
        assert not validation, "\n".join(validation)
        if not expect_errors:
            assert not result.errors, "\n".join(result.errors)
        result.session = session
        return result

    return _render
