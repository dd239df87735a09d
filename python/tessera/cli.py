"""The `tessera` command: `tessera render STAGE -o OUT ...` in the manner of usdrecord and husk."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

from .session import AOVS, RASTER_MODES, VISUALIZATIONS


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not WIDTHxHEIGHT (for example 1920x1080)") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"'{text}': width and height must be between 1 and 16384")
    return w, h


_FRAME_RANGE = re.compile(r"^(-?\d+(?:\.\d+)?)(?:[-:](-?\d+(?:\.\d+)?)(?:x(\d+(?:\.\d+)?))?)?$")


def _frames(text: str) -> list[float]:
    """FIRST-LAST[xSTEP] (usdrecord's FIRST:LAST also), or a single frame; several separated by commas."""
    frames: list[float] = []
    for part in text.split(","):
        match = _FRAME_RANGE.match(part.strip())
        if not match:
            raise argparse.ArgumentTypeError(f"'{part}' is not FIRST-LAST[xSTEP] (for example 1-100 or 1-100x2) or a frame")
        first = float(match.group(1))
        last = float(match.group(2)) if match.group(2) is not None else first
        step = float(match.group(3)) if match.group(3) is not None else 1.0
        if last < first or step <= 0:
            raise argparse.ArgumentTypeError(f"'{part}': the last frame comes before the first, or the step is not positive")
        count = int((last - first) / step + 1e-9) + 1
        frames += [first + i * step for i in range(count)]
    return frames


_FRAME_FIELD = re.compile(r"(#+)(\.#+)?")


def frame_path(pattern: str, frame: float) -> str:
    """The output name for `frame`: the run of `#` replaced by the frame number zero-padded to its length (husk and
    usdrecord's convention: out.####.exr -> out.0012.exr); `.##` after it gives the decimals of fractional frames."""
    match = _FRAME_FIELD.search(os.path.basename(pattern))
    if match is None:
        raise ValueError(f"{pattern}: rendering several frames needs '#' in the output name for the frame number (for example out.####.exr)")
    digits, decimals = len(match.group(1)), len(match.group(2) or ".") - 1
    if decimals == 0 and frame != int(frame):
        raise ValueError(f"{pattern}: frame {frame:g} is not whole: give decimal places in the output name (for example out.####.##.exr)")
    number = f"{frame:0{digits + decimals + 1}.{decimals}f}" if decimals else f"{int(frame):0{digits}d}"
    head, tail = os.path.split(pattern)
    return os.path.join(head, tail[:match.start()] + number + tail[match.end():])


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tessera", description="Tessera: virtualized-geometry renderer for USD stages")
    parser.add_argument("--version", action="version", version="tessera 0.1.0")
    commands = parser.add_subparsers(dest="command", required=True)
    render = commands.add_parser("render", help="render a stage to an image")
    render.add_argument("stage", help="USD stage (.usd, .usda, .usdc, .usdz)")
    render.add_argument("-o", "--output", required=True, help="image file: .exr (linear float), .tif, .png, .jpg")
    render.add_argument("--camera", help="camera prim path (default: the stage's first camera, else one framing the stage)")
    render.add_argument("--resolution", type=_resolution, default=(960, 540), help="WIDTHxHEIGHT (default 960x540)")
    when = render.add_mutually_exclusive_group()
    when.add_argument("--frame", type=float, help="time code to render (default: the stage's default time)")
    when.add_argument("--frames", type=_frames, metavar="FIRST-LAST[xSTEP]",
                      help="render a sequence through one session (only what varies in time re-syncs); the output "
                           "name's run of '#' becomes the zero-padded frame number, for example out.####.exr")
    render.add_argument("--aov", choices=AOVS, default="color", help="what to write (default color)")
    render.add_argument("--pixel-error", type=float, default=1.0, metavar="PX",
                        help="screen-space error bound of the level-of-detail cut, in pixels (default 1)")
    render.add_argument("--no-lod", action="store_true", help="draw every source triangle: the DAG off, the full-detail reference")
    render.add_argument("--vis", choices=VISUALIZATIONS, help="show a debug view in the color AOV instead of shading")
    render.add_argument("--raster", choices=RASTER_MODES, default="auto",
                        help="auto: small triangles through the compute rasterizer, large ones through hardware raster (default)")
    render.add_argument("--no-occlusion", action="store_true",
                        help="no two-pass HZB occlusion culling (it only acts from a sequence's second frame on)")
    render.add_argument("--stats", help="write frame statistics to this JSON file (with --frames: {\"frames\": [one per frame]})")
    render.add_argument("--refine-level", type=int, default=2, choices=range(0, 9), metavar="N",
                        help="uniform refinements of subdivision surfaces before the DAG (default 2; 0 draws the cage)")
    render.add_argument("--device", help="Vulkan device: gpu, cpu, an index or part of its name (default: $TESSERA_DEVICE, else the best)")
    build_cmd = commands.add_parser("build", help="build every mesh of a stage into the mesh cache ($TESSERA_CACHE)")
    build_cmd.add_argument("stage", help="USD stage")
    build_cmd.add_argument("--frame", type=float, help="time code (default: the stage's default time)")
    build_cmd.add_argument("--refine-level", type=int, default=2, choices=range(0, 9), metavar="N", help="as for render (default 2)")
    bench = commands.add_parser("bench", help="benchmarks: tables of speed, memory and error")
    benches = bench.add_subparsers(dest="bench", required=True)
    build = benches.add_parser("build", help="cluster DAG build: speed, memory, depth, error per level")
    build.add_argument("stages", nargs="*", help="USD stages (every mesh) or .obj files (default: the bunny and generated 1M / 10M meshes)")
    build.add_argument("--json", help="also write the rows to this file (keys: the columns in snake_case)")
    bench_raster = benches.add_parser("raster", help="the triangle size where hardware raster overtakes the compute rasterizer")
    bench_raster.add_argument("--resolution", type=_resolution, default=(1920, 1080), help="WIDTHxHEIGHT (default 1920x1080)")
    bench_raster.add_argument("--frames", type=int, default=5, help="frames measured after one warm-up; the median is reported")
    bench_raster.add_argument("--stages-dir", default="out/bench", help="where the generated stages are kept (default out/bench)")
    bench_raster.add_argument("--device", help="Vulkan device, as for render")
    bench_raster.add_argument("--json", help="also write the rows to this file (keys: the columns in snake_case)")
    bench_textures = benches.add_parser("textures", help="texture loads (read, mips, bytes) and the shading cost of textured materials")
    bench_textures.add_argument("--resolution", type=_resolution, default=(1920, 1080), help="WIDTHxHEIGHT (default 1920x1080)")
    bench_textures.add_argument("--frames", type=int, default=5, help="frames measured after one warm-up; the median is reported")
    bench_textures.add_argument("--sizes", type=lambda text: [int(v) for v in text.split(",")], default=[1024, 2048, 4096],
                                help="texture sizes in pixels, comma-separated (default 1024,2048,4096; the largest is shaded)")
    bench_textures.add_argument("--stages-dir", default="out/bench", help="where the generated textures and stages are kept (default out/bench)")
    bench_textures.add_argument("--device", help="Vulkan device, as for render")
    bench_textures.add_argument("--json", help="also write the rows to this file (keys: the columns in snake_case)")
    bench_render = benches.add_parser("render", help="frame cost against source density, brute force and the error bound")
    bench_render.add_argument("--resolution", type=_resolution, default=(1920, 1080), help="WIDTHxHEIGHT (default 1920x1080)")
    bench_render.add_argument("--frames", type=int, default=5, help="frames measured after one warm-up; the median is reported")
    bench_render.add_argument("--max-density", type=int, default=3, choices=(1, 2, 3),
                              help="fields of 1e6, 1e8, 1e10 source triangles: how many of them (default all 3)")
    bench_render.add_argument("--stages-dir", default="out/bench", help="where the generated stages are kept (default out/bench)")
    bench_render.add_argument("--device", help="Vulkan device, as for render")
    bench_render.add_argument("--plot", help="write the speed-against-error plot (PNG) here")
    bench_render.add_argument("--json", help="also write the rows to this file (keys: the columns in snake_case)")
    bench_usd = benches.add_parser("usd", help="translating a stage into the render index: time, memory, one edit re-synced")
    bench_usd.add_argument("--prims", type=int, default=100_000,
                           help="mesh prims of the first two stages, one shape shared and every mesh distinct (default 100000)")
    bench_usd.add_argument("--instances", type=int, default=10_000, help="native instances of the second stage (default 10000)")
    bench_usd.add_argument("--point-instances", type=int, default=10_000_000,
                           help="instances of the PointInstancer stage; 0 skips it (default 10000000)")
    bench_usd.add_argument("--prototype-triangles", type=int, default=100_000, help="triangles of its prototype (default 100000)")
    bench_usd.add_argument("--edits", type=int, default=20, help="transform edits timed; the median is reported (default 20)")
    bench_usd.add_argument("--stages-dir", default="out/bench", help="where the generated stages are kept (default out/bench)")
    bench_usd.add_argument("--device", help="Vulkan device, as for render")
    bench_usd.add_argument("--json", help="also write the rows to this file (keys: the columns in snake_case)")
    return parser


def _render(args) -> int:
    from . import Session

    frames = args.frames
    if frames is not None:
        outputs = [frame_path(args.output, frame) for frame in frames]  # a name without '#' fails before any work
    else:
        outputs = [args.output]
    started = time.perf_counter()
    session = Session(args.stage, frame=frames[0] if frames else args.frame, device=args.device, refine_level=args.refine_level)
    loaded = time.perf_counter()
    camera = args.camera or (session.camera_paths()[0] if session.camera_paths() else None)
    all_stats, validation_errors = [], []
    for number, output in enumerate(outputs):
        frame_started = time.perf_counter()
        if frames is not None:
            session.set_time(frames[number])
        result = session.render(camera=camera, resolution=args.resolution, aovs=[args.aov], pixel_error=args.pixel_error,
                                lod=not args.no_lod, vis=args.vis, raster=args.raster, occlusion=not args.no_occlusion)
        rendered = time.perf_counter()
        where = f"frame {frames[number]:g}: " if frames is not None else ""
        for message in result.warnings:
            print(f"tessera: warning: {where}{message}", file=sys.stderr)
        for message in result.errors:
            print(f"tessera: error: {where}{message}", file=sys.stderr)
        os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
        result.write(output, args.aov)
        if frames is not None:
            synced = ", ".join(f"{count} {kind}" for kind, count in sorted(result.stats["synced"].items())) or "nothing"
            print(f"frame {frames[number]:g} -> {output}: {rendered - frame_started:.2f} s, synced {synced}, "
                  f"{result.stats['meshes_built']} mesh(es) built", file=sys.stderr)
        stats = dict(result.stats)
        stats.update(camera=camera or "(framing)", resolution=list(args.resolution), aov=args.aov, output=output,
                     warnings=result.warnings, errors=result.errors)
        if frames is not None:
            stats.update(frame=frames[number], seconds={"render": rendered - frame_started})
        else:
            stats.update(seconds={"load": loaded - started, "render": rendered - loaded, "total": time.perf_counter() - started})
        all_stats.append(stats)
        validation_errors += [e for e in result.errors if e.startswith("validation error")]
    if args.stats:
        with open(args.stats, "w") as f:
            json.dump(all_stats[0] if frames is None else
                      {"frames": all_stats, "seconds": {"load": loaded - started, "total": time.perf_counter() - started}}, f, indent=2)
    return 1 if validation_errors else 0


class _Collector:
    """Stands in for the render index while the scene delegate populates: records the mesh prims."""

    def __init__(self):
        self.meshes = []

    def insert_rprim(self, kind, prim_id, instancer_id=""):
        self.meshes.append(prim_id)

    def insert_sprim(self, kind, prim_id):
        pass


def _build(args) -> int:
    """Builds every mesh into the cache, several at a time, with a progress line; no GPU needed."""
    from concurrent.futures import ThreadPoolExecutor

    from pxr import Usd

    from . import _tessera
    from .session import _open_stage
    from .usd import UsdSceneDelegate

    stage = _open_stage(args.stage)
    collector = _Collector()
    scene = UsdSceneDelegate(stage, collector, Usd.TimeCode(args.frame) if args.frame is not None else Usd.TimeCode.Default(),
                             args.refine_level)
    scene.populate()
    total, done, cached, triangles, failed = len(collector.meshes), 0, 0, 0, 0
    started = time.perf_counter()

    def build_one(prim_id):
        try:
            return prim_id, _tessera.cache_mesh(scene.get_mesh(prim_id)), None
        except Exception as error:  # a bad prim is reported and the others still build
            return prim_id, None, f"{prim_id}: {error}"

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for prim_id, result, error in pool.map(build_one, collector.meshes):
            done += 1
            if error:
                failed += 1
                print(f"\ntessera: error: {error}", file=sys.stderr)
            else:
                cached += result["cached"]
                triangles += result["source_triangles"]
                for warning in result["warnings"]:
                    print(f"\ntessera: warning: {warning}", file=sys.stderr)
            bar = "#" * (30 * done // max(total, 1))
            print(f"\r[{bar:<30}] {done}/{total} meshes, {triangles / 1e6:.1f} M triangles, {cached} already cached",
                  end="", file=sys.stderr, flush=True)
    for warning in scene.warnings:  # per-mesh settings that could not be used, among others
        print(f"\ntessera: warning: {warning}", file=sys.stderr)
    print(f"\nbuilt {total - cached - failed} mesh(es), {cached} from the cache, {failed} failed, in "
          f"{time.perf_counter() - started:.1f} s (cache: {os.environ.get('TESSERA_CACHE') or 'default'})", file=sys.stderr)
    return 1 if failed else 0


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "render":
            return _render(args)
        if args.command == "build":
            return _build(args)
        if args.command == "bench":
            from . import bench, bench_textures

            return {"build": bench.build, "render": bench.render, "raster": bench.raster, "usd": bench.usd,
                    "textures": bench_textures.textures}[args.bench](args)
    except Exception as error:  # one line, never a traceback, for anything the user can fix
        print(f"tessera: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
