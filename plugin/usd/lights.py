"""UsdLux lights as the renderer's LightDesc: DistantLight, DomeLight (and DomeLight_1), RectLight and SphereLight.

Every light reads intensity, exposure, colour and normalize (radiance = colour * intensity * 2^exposure). Rect and
sphere lights are area lights: their size is in world space (width, height, radius through the light's transform,
scale included), and `normalize` divides their radiance by their world-space area (w * h; 4 pi r^2), so that resizing
them keeps their power. A dome's `inputs:texture:file` is a lat-long image in OpenEXR's orientation (the pole along
the dome's +Y, longitude 0 along +Z); the C++ side reads it when the light syncs (a file that cannot be read is a
warning there, and the dome lights by its colour). shaders/lights.h says how each type is shaded.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from tessera import _tessera

# UsdLux prim types -> render index sprim types.
SPRIM_TYPES = {"distantLight", "domeLight", "rectLight", "sphereLight"}


def sprim_type(prim: Usd.Prim) -> str | None:
    """The sprim type of a light prim's type, or None when it is not a light Tessera draws."""
    if prim.IsA(UsdLux.DistantLight):
        return "distantLight"
    if prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
        return "domeLight"
    if prim.IsA(UsdLux.RectLight):
        return "rectLight"
    if prim.IsA(UsdLux.SphereLight):
        return "sphereLight"
    return None


def _asset_file(attribute, time) -> str:
    """The absolute path of an asset attribute: resolved by USD's resolver, else (a file that does not exist) anchored
    to the layer that authored it, so that a warning names the real path; "" when none is authored."""
    asset = attribute.Get(time) if attribute else None
    if not isinstance(asset, Sdf.AssetPath) or not asset.path:
        return ""
    if asset.resolvedPath:
        return asset.resolvedPath
    specs = attribute.GetPropertyStack(time)
    return Sdf.ComputeAssetPathRelativeToLayer(specs[0].layer, asset.path) if specs else asset.path


def _unit(v) -> tuple[float, float, float]:
    length = math.sqrt(sum(c * c for c in v)) or 1.0
    return tuple(float(c) / length for c in v)


def light_desc(prim: Usd.Prim, time, world: Gf.Matrix4d, warnings: list[str]):
    """The LightDesc of a light prim at `time`; `world` is its local-to-world transform (Gf, row vectors)."""
    light = UsdLux.LightAPI(prim)
    intensity = light.GetIntensityAttr().Get(time) or 0.0
    exposure = light.GetExposureAttr().Get(time) or 0.0
    color = np.asarray(light.GetColorAttr().Get(time) or (1, 1, 1), dtype=np.float64)
    normalize = bool(light.GetNormalizeAttr().Get(time))
    radiance = color * intensity * 2.0 ** exposure
    desc = _tessera.LightDesc()
    kind = sprim_type(prim)
    if kind == "distantLight":
        # UsdLux: a distant light's intensity is the radiance of a disk `angle` degrees across; the irradiance it
        # delivers is that times the disk's solid angle, unless inputs:normalize says it already is one.
        if not normalize:
            half_angle = math.radians(UsdLux.DistantLight(prim).GetAngleAttr().Get(time) or 0.53) / 2.0
            radiance = radiance * 2.0 * math.pi * (1.0 - math.cos(half_angle))
        desc.type = _tessera.LightType.distant
        desc.direction = _unit(world.TransformDir(Gf.Vec3d(0, 0, -1)))  # lights emit along their -Z
    elif kind == "rectLight":
        rect = UsdLux.RectLight(prim)
        width, height = rect.GetWidthAttr().Get(time) or 0.0, rect.GetHeightAttr().Get(time) or 0.0
        if rect.GetTextureFileAttr().Get(time):
            warnings.append(f"{prim.GetPath()}: a RectLight's texture:file is not read; the light is uniform")
        axis_x = world.TransformDir(Gf.Vec3d(width / 2.0, 0, 0))
        axis_y = world.TransformDir(Gf.Vec3d(0, height / 2.0, 0))
        area = 4.0 * Gf.Cross(axis_x, axis_y).GetLength()
        if normalize:
            radiance = radiance / area if area > 0 else radiance * 0.0
        desc.type = _tessera.LightType.rect
        desc.position = tuple(world.ExtractTranslation())
        desc.axis_x, desc.axis_y = tuple(axis_x), tuple(axis_y)
        desc.direction = _unit(world.TransformDir(Gf.Vec3d(0, 0, -1)))  # its front faces -Z
    elif kind == "sphereLight":
        # The transform's scale, as one factor (the cube root of its volume change): a sphere stays a sphere.
        scale = abs(world.ExtractRotationMatrix().GetDeterminant()) ** (1.0 / 3.0)
        radius = (UsdLux.SphereLight(prim).GetRadiusAttr().Get(time) or 0.0) * scale
        if normalize:
            area = 4.0 * math.pi * radius * radius
            radiance = radiance / area if area > 0 else radiance * 0.0
        desc.type = _tessera.LightType.sphere
        desc.position = tuple(world.ExtractTranslation())
        desc.radius = float(radius)
    else:  # a dome
        desc.type = _tessera.LightType.dome
        dome = UsdLux.DomeLight(prim) if prim.IsA(UsdLux.DomeLight) else UsdLux.DomeLight_1(prim)
        file = _asset_file(dome.GetTextureFileAttr(), time)
        layout = dome.GetTextureFormatAttr().Get(time) or "automatic"
        if file and layout not in ("automatic", "latlong"):
            warnings.append(f"{prim.GetPath()}: texture:format '{layout}' is not read (only latlong); the dome lights by its colour")
            file = ""
        desc.texture_file = file
        # The texture's frame: the dome's axes in world (rotation only); DomeLight_1 may turn its pole to Z.
        pole_to_z = False
        if prim.IsA(UsdLux.DomeLight_1):
            pole = dome.GetPoleAxisAttr().Get(time) or "scene"
            pole_to_z = pole == "Z" or (pole == "scene" and UsdGeom.GetStageUpAxis(prim.GetStage()) == UsdGeom.Tokens.z)
        x_axis, y_axis = Gf.Vec3d(1, 0, 0), Gf.Vec3d(0, 0, 1) if pole_to_z else Gf.Vec3d(0, 1, 0)
        axis_x = Gf.Vec3d(_unit(world.TransformDir(x_axis)))
        axis_y = world.TransformDir(y_axis)
        axis_y = Gf.Vec3d(_unit(axis_y - axis_x * Gf.Dot(axis_y, axis_x)))  # orthonormal, whatever the transform
        desc.axis_x, desc.axis_y = tuple(axis_x), tuple(axis_y)
    desc.radiance = tuple(float(c) for c in radiance)
    return desc
