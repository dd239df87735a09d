"""`tessera bench textures`: what textures cost. Two tables:

- loads: reading an image file and building its mip chain (OpenImageIO, box filter on the CPU), and the bytes the
  texture pool keeps, per size and bit depth;
- shading: a frame filled by one card, untextured, with one texture, with four (diffuse, roughness, normal,
  occlusion), and with a textured opacity mask (cut per pixel by the rasterizer): GPU ms of the resolve and raster
  passes, median of the measured frames after one warm-up.
"""

from __future__ import annotations

import json
import struct
import time
import zlib
from pathlib import Path

import numpy as np

LOAD_COLUMNS = [("texture", "texture"), ("format", "stored as"), ("levels", "levels"), ("bytes", "bytes"),
                ("bytes_per_texel", "B/texel"), ("load_ms", "load + mips ms")]
SHADING_COLUMNS = [("case", "case"), ("textures", "textures"), ("texture_bytes", "texture bytes"), ("resolve_ms", "resolve ms"),
                   ("hw_raster_ms", "HW raster ms"), ("gpu_ms", "GPU ms")]


def write_png(path: Path, pixels: np.ndarray, bits: int = 8) -> None:
    """A PNG of 1, 3 or 4 channels (rows top first), 8 or 16 bits, written with zlib alone."""
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    height, width, channels = pixels.shape
    data = pixels.astype(">u2" if bits == 16 else np.uint8)
    raw = b"".join(b"\0" + data[y].tobytes() for y in range(height))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, bits, {1: 0, 3: 2, 4: 6}[channels], 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 1)) + chunk(b"IEND", b""))


def _pattern(size: int, channels: int, top: int) -> np.ndarray:
    """Gradients with a little noise: compresses like a painted texture, not like pure noise."""
    rng = np.random.default_rng(size)
    y, x = np.mgrid[0:size, 0:size] / size
    ramps = [x, y, (x + y) / 2, 1 - x]
    base = np.stack([ramps[c % 4] for c in range(channels)], axis=-1) * 0.9 * top
    return np.clip(base + rng.integers(0, max(top // 32, 1) + 1, size=base.shape), 0, top).astype(np.int64)


def _texture_file(directory: Path, size: int, channels: int, bits: int, variant: int = 0) -> Path:
    path = directory / f"texture_{size}_{channels}ch_{bits}bit{f'_{variant}' if variant else ''}.png"
    if not path.exists():
        write_png(path, _pattern(size + variant, channels, 2 ** bits - 1)[:size, :size], bits)
    return path


def _card_stage(path: Path, case: str, textures: dict[str, Path], width: int, height: int) -> None:
    """A camera and one card filling its view, with the material of `case`."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    camera = UsdGeom.Camera.Define(stage, "/Camera")
    camera.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    camera.GetFocalLengthAttr().Set(50.0)
    camera.GetVerticalApertureAttr().Set(24.0)
    camera.GetHorizontalApertureAttr().Set(24.0 * width / height)
    half_h = 24.0 / 50.0 * 10 / 2 * 1.05
    half_w = half_h * width / height
    mesh = UsdGeom.Mesh.Define(stage, "/Card")
    mesh.GetPointsAttr().Set([(-half_w, -half_h, 0), (half_w, -half_h, 0), (half_w, half_h, 0), (-half_w, half_h, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (1, 1), (0, 1)])
    material = UsdShade.Material.Define(stage, "/Look")
    surface = UsdShade.Shader.Define(stage, "/Look/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, "/Look/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    inputs = {"untextured": {}, "diffuse texture": {"diffuseColor": "rgb"},
              "four textures": {"diffuseColor": "rgb", "roughness": "r", "normal": "rgb", "occlusion": "r"},
              "opacity mask": {"diffuseColor": "rgb", "opacity": "a"}}[case]
    for name, output in inputs.items():
        texture = UsdShade.Shader.Define(stage, f"/Look/{name}")
        texture.CreateIdAttr("UsdUVTexture")
        texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(textures[name]))
        texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        if name == "normal":
            texture.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
            texture.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
        kind = Sdf.ValueTypeNames.Color3f if output == "rgb" else Sdf.ValueTypeNames.Float
        surface.CreateInput(name, kind).ConnectToSource(texture.ConnectableAPI(), output)
    if "opacity" in inputs:
        surface.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


def textures(args) -> int:
    from . import Session, _tessera

    directory = Path(args.stages_dir)
    directory.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in args.sizes:
        for channels, bits in ((4, 8), (1, 8), (4, 16)):
            path = _texture_file(directory, size, channels, bits)
            start = time.perf_counter()
            info = _tessera.read_texture(str(path))
            load_ms = (time.perf_counter() - start) * 1000
            rows.append({"table": "loads", "texture": f"{size}x{size} {channels}ch {bits}-bit", "format": info["format"],
                         "levels": info["levels"], "bytes": info["bytes"],
                         "bytes_per_texel": round(info["bytes"] / (size * size), 2), "load_ms": round(load_ms, 1)})

    width, height = args.resolution
    size = max(args.sizes)
    maps = {"diffuseColor": _texture_file(directory, size, 4, 8), "roughness": _texture_file(directory, size, 1, 8),
            "normal": _texture_file(directory, size, 3, 8), "occlusion": _texture_file(directory, size, 1, 8, variant=1),
            "opacity": _texture_file(directory, size, 4, 8)}
    device = None
    for case in ("untextured", "diffuse texture", "four textures", "opacity mask"):
        stage = directory / f"texture_card_{case.replace(' ', '_')}_{width}x{height}_{size}.usda"
        _card_stage(stage, case, maps, width, height)
        session = Session(str(stage), device=args.device)
        device = session.device_name
        settings = {"camera": "/Camera", "resolution": (width, height), "lod": False}
        session.render(**settings)
        passes = []
        for _ in range(args.frames):
            result = session.render(**settings)
            if result.errors:
                raise RuntimeError("; ".join(result.errors))
            passes.append(result.stats["gpu_ms"])
        median = {name: float(np.median([p[name] for p in passes])) for name in passes[0]}
        rows.append({"table": "shading", "case": case, "textures": result.stats["textures"],
                     "texture_bytes": result.stats["texture_bytes"], "resolve_ms": round(median["resolve"], 1),
                     "hw_raster_ms": round(median["hw_raster"], 1),
                     "gpu_ms": round(float(np.median([sum(p.values()) for p in passes])), 1),
                     "resolution": f"{width}x{height}", "texture_size": size, "device": device})

    for table, columns in (("loads", LOAD_COLUMNS), ("shading", SHADING_COLUMNS)):
        print(" | ".join(title for _, title in columns))
        for row in rows:
            if row["table"] == table:
                print(" | ".join(str(row[key]) for key, _ in columns))
        print()
    print(f"device: {device}, {width}x{height}, textures of {size}x{size} for shading, median of {args.frames} frames after one warm-up")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return 0
