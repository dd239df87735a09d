"""A render session: one stage, one render index, renders on demand."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _tessera, raster_split

AOVS = ("color", "depth", "normal", "primId", "instanceId", "clusterId", "triangleId")
# Debug views the color AOV can show instead of shading (renderer.h: Visualize).
VISUALIZATIONS = ("triangles", "clusters", "groups", "lod", "instances", "primitives", "shading-bins", "raster-bins", "overdraw", "uv", "tessellation")
RASTER_MODES = ("auto", "hardware", "software")
PIXEL_FILTERS = ("box", "gaussian")  # how pixel samples combine (Session.render)
OCCLUSION_MODES = (True, "always", False)  # Session.render's occlusion: where it pays, every frame, none
MOST_PIXEL_SAMPLES = _tessera.MOST_PIXEL_SAMPLES
RASTER_VERTICES = ("auto", "shared", "per-triangle")
# UsdGeom purposes a render may draw besides `default` (which is always drawn).
PURPOSES = ("render", "proxy", "guide")


def valid_pixel_samples(value) -> bool:
    """A pixel sample count Session.render takes: a whole number from 1 to MOST_PIXEL_SAMPLES (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MOST_PIXEL_SAMPLES


class StageError(RuntimeError):
    """The stage cannot be opened or rendered as asked (names the file or prim)."""


def ocio_config_path() -> str:
    """The colour configuration shipped with Tessera ($OCIO, when set, takes precedence at write time)."""
    return str(Path(__file__).parent / "ocio" / "config.ocio")


@dataclass
class RenderResult:
    images: dict[str, _tessera.Image]
    stats: dict
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    index: object = None

    def __getitem__(self, aov: str) -> _tessera.Image:
        return self.images[aov]

    def write(self, path: str | os.PathLike, aov: str = "color") -> None:
        self.images[aov].write(str(path), ocio_config_path())

    def prim_path(self, prim_id: int) -> str:
        return self.index.prim_path(prim_id)


def _usd_error_text(error) -> str:
    """What a USD error exception says, for a person: each of its errors' own message (a parse error's file, line and
    column first), without the C++ function and source file that raised it and USD's internal namespace."""
    messages = re.findall(r"Error in '[^']*' at line \d+ in file [^\n]* : '(.*?)'\s*(?=\n\s*Error in |\Z)", str(error), re.DOTALL)
    cleaned = [re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", m).strip() for m in messages]
    return "; ".join(m for m in cleaned if m) or str(error).strip()


def _open_stage(stage):
    from pxr import Tf, Usd

    if isinstance(stage, Usd.Stage):
        return stage
    path = os.fspath(stage)
    if not os.path.exists(path):
        raise StageError(f"{path}: no such file")
    try:
        opened = Usd.Stage.Open(path)
    except Tf.ErrorException as error:
        raise StageError(f"{path}: cannot be opened as a USD stage: {_usd_error_text(error)}") from None
    if opened is None:
        raise StageError(f"{path}: cannot be opened as a USD stage")
    return opened


def _checked_complexity(complexity) -> float:
    from .usd import subdivision

    try:
        subdivision.refine_level(complexity)
    except (TypeError, ValueError) as error:
        raise StageError(str(error)) from None
    return float(complexity)


class Session:
    """Opens a stage and renders it; the render delegate and the GPU scene live as long as the session.

    Live edits: edit `session.stage` through the USD API (transforms, shader inputs, points, prims added or
    removed, variants, visibility) and render again; the change notices since the last render say what re-syncs,
    and nothing else does. `set_time` moves to another frame the same way: only time-varying attributes re-sync.
    """

    def __init__(self, stage, *, frame: float | None = None, device: str | None = None, validation: bool | None = None,
                 complexity: float = 1.0, build_settings: _tessera.BuildSettings | dict | None = None,
                 purposes=("render",)):
        """`complexity`: the render setting that refines subdivision surfaces, Hydra's convention (1.0 the control
        cage, as usdview's default; 1.1, 1.2, 1.3 refine 1, 2, 3 times; up to 2.0, 8 times): the session's default,
        which render() may override. `build_settings` (a BuildSettings or a dict of tessera.build_mesh's keywords)
        applies to every mesh. `purposes`: the UsdGeom purposes drawn besides `default` (PURPOSES; `render` by
        default, as usdview's render mode and husk); geometry of the others is not read."""
        from pxr import Usd

        from .usd import ChangeTracker, UsdSceneDelegate

        self.stage = _open_stage(stage)
        self.time = Usd.TimeCode(frame) if frame is not None else Usd.TimeCode.Default()
        self.delegate = _tessera.RenderDelegate(device=device, validation=validation)
        # The raster split recorded for this device (`tessera bench raster --record`), else the default.
        self.software_raster_area, self.software_raster_area_source = raster_split.for_device(
            self.delegate.cache_directory, raster_split.device_key(self.delegate.device_name, self.delegate.software_device))
        self.index = _tessera.RenderIndex(self.delegate)
        if isinstance(build_settings, dict):
            build_settings = _tessera.BuildSettings(**build_settings)
        self.purposes = tuple(purposes)
        unknown = [p for p in self.purposes if p not in PURPOSES]
        if unknown:
            raise StageError(f"unknown purpose {', '.join(map(repr, unknown))} (choose from {', '.join(PURPOSES)}; default is always drawn)")
        self.complexity = _checked_complexity(complexity)
        self.scene = UsdSceneDelegate(self.stage, self.index, self.time, self.complexity, build_settings, self.purposes)
        self.scene.populate()
        self._changes = ChangeTracker(self.stage)  # edits from here on re-sync what they touch

    def close(self) -> None:
        """Stops listening to the stage's edits (the session still renders what it has)."""
        self._changes.close()

    def set_time(self, frame: float | None) -> None:
        """Renders from now on at `frame` (None: the default time). Dirties only what varies in time: animated
        transforms, points, visibility, instancers, shader inputs, lights and cameras."""
        from pxr import Usd

        self._apply_edits()
        self.time = Usd.TimeCode(frame) if frame is not None else Usd.TimeCode.Default()
        self.scene.set_time(self.time)

    def _apply_edits(self) -> None:
        self.scene.apply_changes(*self._changes.take())

    def render_settings(self, path: str | None = None):
        """The stage's UsdRenderSettings as `tessera.usd.render_settings.RenderSettings` (resolution, camera, purposes,
        products with their AOVs), or None without any: `path`, else the stage's renderSettingsPrimPath, else the only
        RenderSettings prim under /Render. What cannot be used is a warning of the next render. The session does not
        apply them by itself: pass them to render() (the `tessera render` command does)."""
        from .usd import render_settings

        return render_settings.read(self.stage, path, self.scene.warnings)

    @property
    def device_name(self) -> str:
        return self.delegate.device_name

    def camera_paths(self) -> list[str]:
        return list(self.scene.cameras)

    def render(self, *, camera: str | None = None, resolution: tuple[int, int] = (960, 540),
               aovs=("color",), background=(0.0, 0.0, 0.0, 0.0), pixel_error: float = 1.0, lod: bool = True,
               vis: str | None = None, raster: str = "auto", occlusion: bool | str = True, dicing_rate: float = 1.0,
               complexity: float | None = None, raster_vertices: str = "auto", software_raster_area: float | None = None,
               pixel_samples: int = 1, pixel_filter: str = "box", last: bool = False) -> RenderResult:
        """Renders the stage at the session's time. `pixel_error` is the DAG cut's screen-space error bound in
        pixels; `lod=False` draws every source triangle (the full-detail reference); `vis` replaces shading in
        the color AOV by a debug view (VISUALIZATIONS); `raster` forces one rasterizer (RASTER_MODES); `occlusion`
        culls what the previous render of this session hid (two-pass HZB occlusion: counts change, the image does
        not; a session's first render, or one after instances moved, has nothing to test against) where it pays: on
        a CPU device, the 15 renders after one where it culled under a quarter of the work skip it (stats
        `occlusion_rested`); "always" tests every render, False none; `dicing_rate`:
        displaced surfaces are diced into micro-triangles whose edges project to about this many pixels;
        `complexity` (None: the session's) refines subdivision surfaces (see Session): a render at another refine
        level than the last rebuilds the meshes that have a subdivision scheme, and no others; `raster_vertices`
        picks the compute rasterizer's variant (RASTER_VERTICES; the same pixels either way, a matter of speed: auto
        is shared, or $TESSERA_RASTER_VERTICES); `software_raster_area` (None:
        the session's, recorded for its device or the default; see tessera.raster_split) sends clusters of triangles
        smaller than that many pixels to the compute rasterizer (the same pixels either way, a matter of speed);
        `pixel_samples` anti-aliases: the colour is the filtered mean of that many frames, each sampling the pixels at
        another offset (tessera.pixel_sample_offset), while depth, normal and ids are the pixel centres' (the first
        sample). Each sample costs a frame; stats add the frames' times. `pixel_filter` (PIXEL_FILTERS): "box", the
        mean over the pixel's square (alpha the exact coverage), or "gaussian", samples over two pixels' width, denser
        towards the centre as a Gaussian weighs (softer edges, less moire). `last`: no render of this session follows
        (a batch render's last frame): it builds no depth pyramid for the next render's occlusion to test against (the
        same image; stats `hzb_builds`), and a render after it tests nothing, as a first render."""
        from .usd import framing_camera

        width, height = resolution
        aovs = list(aovs)
        for aov in aovs:
            if aov not in AOVS:
                raise StageError(f"unknown AOV '{aov}' (choose from {', '.join(AOVS)})")
        if vis is not None and vis not in VISUALIZATIONS:
            raise StageError(f"unknown visualization '{vis}' (choose from {', '.join(VISUALIZATIONS)})")
        if raster not in RASTER_MODES:
            raise StageError(f"unknown raster mode '{raster}' (choose from {', '.join(RASTER_MODES)})")
        if raster_vertices not in RASTER_VERTICES:
            raise StageError(f"unknown raster vertices '{raster_vertices}' (choose from {', '.join(RASTER_VERTICES)})")
        if not (pixel_error >= 0.0):
            raise StageError(f"pixel error must be a number >= 0, not {pixel_error}")
        if not valid_pixel_samples(pixel_samples):
            raise StageError(f"pixel samples must be a whole number from 1 to {MOST_PIXEL_SAMPLES}, not {pixel_samples!r}")
        if pixel_filter not in PIXEL_FILTERS:
            raise StageError(f"unknown pixel filter '{pixel_filter}' (choose from {', '.join(PIXEL_FILTERS)})")
        if not (dicing_rate > 0.0):
            raise StageError(f"dicing rate must be a number of pixels > 0, not {dicing_rate}")
        if occlusion not in OCCLUSION_MODES:
            raise StageError(f"occlusion must be one of True (where it pays), 'always' or False, not {occlusion!r}")
        complexity = self.complexity if complexity is None else _checked_complexity(complexity)
        self._apply_edits()
        self.scene.set_complexity(complexity)
        if vis == "uv":  # the UV view shows every mesh's st, where shading reads only what a texture reads
            self.scene.read_all_uvs()
        camera_id = ""
        if camera:
            if camera not in self.scene.cameras:
                raise StageError(f"{camera}: not a camera on this stage (cameras: {', '.join(self.scene.cameras) or 'none'})")
            camera_id = camera
        syncs_before = dict(self.index.sync_counts)
        # With a stage camera, meshes whose extent it does not see are not built until a render sees them.
        self.index.sync_all(self.scene, camera_id, width, height)
        syncs = {kind: count - syncs_before.get(kind, 0) for kind, count in self.index.sync_counts.items()}
        # Without a stage camera, frame the stage's bounds (computed only when needed: bounds touch every prim).
        fallback = (framing_camera(self.stage, self.time, width, height, self.purposes, self.scene.instancer_cycles)
                    if not camera_id else _tessera.CameraDesc())
        area = self.software_raster_area if software_raster_area is None else float(software_raster_area)
        if not (area > 0.0) or area == float("inf"):
            raise StageError(f"software raster area must be a number of pixels > 0, not {software_raster_area}")
        images, stats = self.index.execute(camera_id, fallback, width, height, aovs, tuple(background), float(pixel_error), lod,
                                           vis or "none", raster, bool(occlusion), float(dicing_rate), raster_vertices, area,
                                           pixel_samples, pixel_filter, 0.0 if occlusion == "always" else -1.0, bool(last))
        diagnostics = self.index.take_diagnostics()
        warnings, errors = diagnostics["warnings"], diagnostics["errors"]
        warnings = list(self.scene.warnings) + list(warnings)
        errors = list(self.scene.errors) + list(errors)
        self.scene.warnings.clear()
        self.scene.errors.clear()
        messages = self.delegate.take_validation_messages()
        if messages:
            errors = list(errors) + messages
        stats["device"] = self.delegate.device_name
        stats["sw_raster_area"] = area  # the raster split, and whether it was recorded for this device, the default or given
        stats["sw_raster_area_source"] = self.software_raster_area_source if software_raster_area is None else "given"
        stats["pixel_error"] = float(pixel_error) if lod else 0.0
        stats["lod"] = lod
        stats["complexity"] = complexity
        stats["refine_level"] = self.scene.refine_level  # of subdivision surfaces
        stats["rprims"] = self.index.rprim_count
        stats["meshes_built"] = diagnostics["meshes_built"]
        stats["meshes_cached"] = diagnostics["meshes_cached"]
        stats["meshes_shared"] = diagnostics["meshes_shared"]  # identical to a mesh already in the scene: that one is used
        stats["meshes_out_of_view"] = self.index.meshes_out_of_view  # not built: no rendered view has seen their extent
        stats["synced"] = {kind: count for kind, count in syncs.items() if count}  # prims synced for this render, per type
        return RenderResult(dict(zip(aovs, images)), stats, warnings, list(errors), self.index)
