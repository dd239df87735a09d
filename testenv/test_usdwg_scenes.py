"""Scenes of the USD Working Group's assets and the Cornell box, checked for what each is about: the schemaTests
transforms against their reference cards, the Vehicles' variants switched live, the Cornell box's walls."""

import numpy as np
import pytest

import tessera
from conftest import shared_asset
from imagecompare import colour_class, intersection_over_union, same_colour

TRANSFORMS = "usd-wg/test_assets/schemaTests/usdGeom/transforms"
VEHICLES = "usd-wg/full_assets/Vehicles/USD_Mini_Car_Kit/assets/vehicles/vehicleVariants.usda"


def bounding_box_shape(mask: np.ndarray, size: int = 64) -> np.ndarray:
    """The mask cropped to its bounding box and resampled to size x size: its shape, wherever and however big."""
    ys, xs = np.nonzero(mask)
    assert len(ys), "nothing drawn"
    crop = mask[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
    rows = ((np.arange(size) + 0.5) * crop.shape[0] / size).astype(int)
    columns = ((np.arange(size) + 0.5) * crop.shape[1] / size).astype(int)
    return crop[rows][:, columns]


def look_down_z(stage) -> str:
    """An orthographic camera on +Z looking down -Z at the stage's bounds (the cards' ZPos view)."""
    from pxr import Gf, Usd, UsdGeom

    bounds = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default", "render"]).ComputeWorldBound(stage.GetPseudoRoot())
    box = bounds.ComputeAlignedRange()
    reach = max(box.GetSize())
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        camera = UsdGeom.Camera.Define(stage, "/CardCamera")
        camera.MakeMatrixXform().Set(Gf.Matrix4d().SetTranslate(box.GetMidpoint() + Gf.Vec3d(0, 0, 3 * reach)))
        camera.GetProjectionAttr().Set(UsdGeom.Tokens.orthographic)
        camera.GetHorizontalApertureAttr().Set(15 * reach)  # tenths of a unit: 1.5x the bounds
        camera.GetVerticalApertureAttr().Set(15 * reach)
        camera.GetClippingRangeAttr().Set(Gf.Vec2f(0.01 * reach, 10 * reach))
    return "/CardCamera"


@pytest.mark.parametrize("name", ["simple_transform", "complex_transform", "matrix_transform"])
def test_transform_matches_its_card(render, name):
    """The card (a reference render) seen down -Z shows the mesh's outline as its xform stack turns, scales and
    shears it. The cards' axis gizmo (../../../_common/axis.usda) is not among the shared assets: its reference is
    a warning, and the gizmo's coloured pixels are left out of the card's outline. The cards' side views (XPos,
    YPos, ...) follow a convention for their up vector that is not documented, so only ZPos is compared."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(shared_asset(f"{TRANSFORMS}/{name}.usda")))
    result = render(stage, camera=look_down_z(stage), resolution=(256, 256), aovs=("primId",), complexity=1.0)
    assert any("axis.usda" in w for w in result.warnings), "the missing gizmo is reported"
    ours = np.asarray(result["primId"].ids()) != 0xFFFFFFFF
    card = np.asarray(tessera.read_image(str(shared_asset(f"{TRANSFORMS}/cards/{name}_ZPos.png"))))
    rgb = card[..., :3]
    mesh = (card[..., 3] > 0.5) & (rgb.max(-1) - rgb.min(-1) < 0.1) & (rgb.max(-1) > 0.08)  # grey: not the gizmo
    iou = intersection_over_union(bounding_box_shape(ours), bounding_box_shape(mesh))
    assert iou >= 0.85, f"the outline seen down -Z differs from the card's: IoU {iou:.3f}"


def test_vehicle_variants_switch_live():
    """The vehicle variant set switched on a live session draws the new vehicle (as a fresh session of it does),
    then a wheel variant inside it switched again; nothing is reported along the way."""
    from pxr import Usd

    def drawn(result):
        assert not result.errors and not result.warnings, "\n".join(result.errors + result.warnings)
        return np.asarray(result["primId"].ids()) != 0xFFFFFFFF

    session = tessera.Session(shared_asset(VEHICLES), validation=True, complexity=1.0)
    tractor = drawn(session.render(camera=None, resolution=(160, 120), aovs=("primId",)))
    vehicle = session.stage.GetPrimAtPath("/vehicleVariant").GetVariantSet("wheels")
    assert "formula" in vehicle.GetVariantNames()
    vehicle.SetVariantSelection("formula")
    formula = drawn(session.render(camera=None, resolution=(160, 120), aovs=("primId",)))
    assert intersection_over_union(tractor, formula) < 0.8, "switching the vehicle changes what is drawn"

    fresh_stage = Usd.Stage.Open(str(shared_asset(VEHICLES)))
    fresh_stage.GetPrimAtPath("/vehicleVariant").GetVariantSet("wheels").SetVariantSelection("formula")
    fresh = drawn(tessera.Session(fresh_stage, validation=True, complexity=1.0).render(camera=None, resolution=(160, 120),
                                                                                        aovs=("primId",)))
    assert intersection_over_union(formula, fresh) > 0.99, "a live switch draws what a fresh stage does"

    wheel = next(p for p in session.stage.Traverse() if p.GetName() == "wheel1" and p.GetVariantSet("wheels").GetVariantNames())
    wheels = wheel.GetVariantSet("wheels")
    other = next(n for n in wheels.GetVariantNames() if n != wheels.GetVariantSelection() and "Wide" in n)
    wheels.SetVariantSelection(other)
    wide = drawn(session.render(camera=None, resolution=(160, 120), aovs=("primId",)))
    assert (wide != formula).sum() > 20, f"switching one wheel to {other} changes what is drawn"


def test_cornell_box_walls(render):
    """Framed from the open side (the framing camera leaves it about a tenth of the image), the red wall on the left, the green on
    the right, each drawn in its material's hue."""
    result = render(shared_asset("scenes/cornell-box/usdpreviewsurface/cornell-box.usda"), camera=None,
                    resolution=(160, 120), aovs=("color", "primId"))
    ids = np.asarray(result["primId"].ids())
    coverage = float((ids != 0xFFFFFFFF).mean())
    assert 0.05 < coverage < 0.6, f"the framed box covers {coverage:.0%} of the image"
    colour = np.asarray(result["color"].pixels)[..., :3]
    columns = {}
    for wall, hue in (("left_wall", 0.0), ("right_wall", 120.0)):
        prim_id = next(i for i in np.unique(ids) if i != 0xFFFFFFFF and result.prim_path(int(i)).endswith(f"/{wall}"))
        pixels = ids == prim_id
        assert pixels.sum() > 50, f"{wall} is seen"
        found = colour_class(colour[pixels])
        assert same_colour(found, ("hue", hue)), f"{wall} is drawn {found}, not hue {hue}"
        columns[wall] = np.nonzero(pixels)[1].mean()
    assert columns["left_wall"] < columns["right_wall"], "the red wall is on the left, the green on the right"
