"""UsdRenderSettings and its RenderProducts as what a render needs: resolution, camera, purposes and, per product,
its output name and the AOVs its RenderVars ask for, where Tessera has them.

Which settings: a path given by the caller, else the stage's `renderSettingsPrimPath` metadata, else the only
RenderSettings prim under /Render (UsdRender keeps its prims there; the rest of the stage is not searched). A product's
own resolution and camera, when authored, win over the settings'. A RenderVar maps to an AOV by its sourceName
(`color`, `Ci`, `rgba` or an `C.*` light path expression: color; `depth`, `z`: depth; `normal`, `N`, `Neye`: normal;
`primId`, `instanceId`, `clusterId`, `triangleId`, `elementId` as the last); any other is a warning naming the var.
Tessera's own settings on the settings prim, namespaced as renderers' are: `int tessera:pixelSamples` (anti-aliasing
samples per pixel, 1 to 4096) and `token tessera:pixelFilter` (`box` or `gaussian`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pxr import Sdf, Usd, UsdGeom, UsdRender

_AOV_NAMES = {
    "color": "color", "ci": "color", "rgba": "color", "rgb": "color",
    "depth": "depth", "z": "depth",
    "normal": "normal", "n": "normal", "neye": "normal",
    "primid": "primId", "instanceid": "instanceId", "clusterid": "clusterId",
    "triangleid": "triangleId", "elementid": "triangleId",
}


@dataclass
class RenderProduct:
    path: str
    name: str  # productName: the file to write ("" when not authored)
    camera: str | None
    resolution: tuple[int, int]
    aovs: list[str]  # Tessera's AOV names, in orderedVars order, without repeats


@dataclass
class RenderSettings:
    path: str
    camera: str | None  # a camera prim path, or None for the render's default
    resolution: tuple[int, int]
    purposes: tuple[str, ...]  # includedPurposes other than default
    products: list[RenderProduct] = field(default_factory=list)
    pixel_samples: int | None = None  # tessera:pixelSamples when authored and valid
    pixel_filter: str | None = None  # tessera:pixelFilter when authored and valid


def _tessera_setting(prim: Usd.Prim, where: str, warnings: list[str], name: str, valid, expected: str, fallback: str):
    """The value of Tessera's setting `name` on the settings prim: None when not authored, or when not `valid` (a
    warning naming the prim says what it should be and what is used instead)."""
    attribute = prim.GetAttribute(name)
    if not attribute or not attribute.HasAuthoredValue():
        return None
    value = attribute.Get()
    if not valid(value):
        warnings.append(f"{where}: {name} = {value!r} is not {expected}; {fallback} is used")
        return None
    return value


def _pixel_samples(prim: Usd.Prim, where: str, warnings: list[str]) -> int | None:
    from tessera.session import MOST_PIXEL_SAMPLES, valid_pixel_samples

    samples = _tessera_setting(prim, where, warnings, "tessera:pixelSamples", valid_pixel_samples,
                               f"a whole number from 1 to {MOST_PIXEL_SAMPLES}", "1 sample")
    return None if samples is None else int(samples)


def _pixel_filter(prim: Usd.Prim, where: str, warnings: list[str]) -> str | None:
    from tessera.session import PIXEL_FILTERS

    valid = lambda v: str(v) in PIXEL_FILTERS
    pixel_filter = _tessera_setting(prim, where, warnings, "tessera:pixelFilter", valid, f"one of {', '.join(PIXEL_FILTERS)}", "box")
    return None if pixel_filter is None else str(pixel_filter)


def find(stage: Usd.Stage, path: str | None, warnings: list[str]) -> Usd.Prim | None:
    """The RenderSettings prim to use (see the module's docstring); None when there is none."""
    if path:
        prim = stage.GetPrimAtPath(path)
        if not (prim and prim.IsA(UsdRender.Settings)):
            raise ValueError(f"{path}: not a RenderSettings prim on this stage")
        return prim
    chosen = UsdRender.Settings.GetStageRenderSettings(stage)
    if chosen:
        return chosen.GetPrim()
    named = stage.GetMetadata("renderSettingsPrimPath")
    if named:
        warnings.append(f"renderSettingsPrimPath {named} is not a RenderSettings prim; render settings are not used")
        return None
    render = stage.GetPrimAtPath("/Render")
    found = [p for p in Usd.PrimRange(render) if p.IsA(UsdRender.Settings)] if render else []
    if len(found) > 1:
        warnings.append(f"several RenderSettings prims ({', '.join(str(p.GetPath()) for p in found)}) and no renderSettingsPrimPath "
                        "to choose one; none is used")
        return None
    return found[0] if found else None


def _camera(stage: Usd.Stage, base, where: str, warnings: list[str]) -> str | None:
    targets = base.GetCameraRel().GetForwardedTargets()
    if not targets:
        return None
    prim = stage.GetPrimAtPath(targets[0])
    if not (prim and prim.IsA(UsdGeom.Camera)):
        warnings.append(f"{where}: camera {targets[0]} is not a camera prim; the default camera is used")
        return None
    return str(targets[0])


def _resolution(base, where: str, warnings: list[str], inherited: tuple[int, int] | None) -> tuple[int, int]:
    """A settings prim's resolution (the schema's fallback, 2048x1080, when unauthored), or a product's own when
    authored, else the `inherited` settings'."""
    attribute = base.GetResolutionAttr()
    if inherited is not None and not attribute.HasAuthoredValue():
        return inherited
    default = inherited or (2048, 1080)
    w, h = attribute.Get()
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        warnings.append(f"{where}: resolution {w}x{h} is outside 1-16384; {default[0]}x{default[1]} is used")
        return default
    return int(w), int(h)


def read(stage: Usd.Stage, path: str | None, warnings: list[str]) -> RenderSettings | None:
    """The stage's render settings (None without any); what cannot be used is a warning naming the prim."""
    prim = find(stage, path, warnings)
    if prim is None:
        return None
    settings = UsdRender.Settings(prim)
    where = str(prim.GetPath())
    purposes = tuple(str(p) for p in (settings.GetIncludedPurposesAttr().Get() or []) if p != UsdGeom.Tokens.default_)
    known = tuple(p for p in purposes if p in ("render", "proxy", "guide"))
    if known != purposes:
        warnings.append(f"{where}: includedPurposes {list(purposes)}: only render, proxy and guide are purposes")
    result = RenderSettings(where, _camera(stage, settings, where, warnings),
                            _resolution(settings, where, warnings, None), known, pixel_samples=_pixel_samples(prim, where, warnings),
                            pixel_filter=_pixel_filter(prim, where, warnings))
    for target in settings.GetProductsRel().GetForwardedTargets():
        product_prim = stage.GetPrimAtPath(target)
        if not (product_prim and product_prim.IsA(UsdRender.Product)):
            warnings.append(f"{where}: product {target} is not a RenderProduct prim; it is skipped")
            continue
        product = UsdRender.Product(product_prim)
        name = product.GetProductNameAttr().Get() or ""
        aovs: list[str] = []
        for var_path in product.GetOrderedVarsRel().GetForwardedTargets():
            var_prim = stage.GetPrimAtPath(var_path)
            if not (var_prim and var_prim.IsA(UsdRender.Var)):
                warnings.append(f"{target}: orderedVars {var_path} is not a RenderVar prim; it is skipped")
                continue
            var = UsdRender.Var(var_prim)
            source = str(var.GetSourceNameAttr().Get() or "")
            kind = str(var.GetSourceTypeAttr().Get() or "raw")
            aov = "color" if kind == "lpe" and source.startswith("C") else _AOV_NAMES.get(source.lower()) if kind == "raw" else None
            if aov is None:
                warnings.append(f"{var_path}: {kind} '{source}' is not an AOV Tessera writes (color, depth, normal, primId, "
                                "instanceId, clusterId, triangleId); it is skipped")
            elif aov not in aovs:
                aovs.append(aov)
        result.products.append(RenderProduct(str(target), str(name), _camera(stage, product, str(target), warnings) or result.camera,
                                             _resolution(product, str(target), warnings, result.resolution), aovs))
    return result
