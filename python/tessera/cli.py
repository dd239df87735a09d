"""The `tessera` command: `tessera render STAGE -o OUT ...` in the manner of usdrecord and husk."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

from .session import AOVS, MOST_PIXEL_SAMPLES, PIXEL_FILTERS, PURPOSES, RASTER_MODES, VISUALIZATIONS, valid_pixel_samples


def _purposes(text: str) -> tuple[str, ...]:
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    unknown = [p for p in names if p not in PURPOSES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"'{text}': purposes are a comma-separated list of {', '.join(PURPOSES)} "
                                         "(default is always drawn)")
    return names


def _complexity(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 1.0:
        raise argparse.ArgumentTypeError(f"'{text}': complexity is a number from 1.0 (the control cage) to 2.0 (usdview's "
                                         "levels: 1.0, 1.1, 1.2, 1.3)")
    return value


def _add_complexity(parser) -> None:
    """--complexity, and --refine-level N as its alias (complexity 1.N, Hydra's convention)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--complexity", type=_complexity, default=1.0, metavar="C",
                       help="refines subdivision surfaces as usdview's complexity does: 1.0 the control cage (default), "
                            "1.1, 1.2, 1.3 refine 1, 2, 3 times, ... 1.8 to 2.0 8 times; meshes with subdivisionScheme none never")
    group.add_argument("--refine-level", type=int, choices=range(0, 9), metavar="N",
                       help="the same as --complexity 1.N (0 to 8)")


def _complexity_of(args) -> float:
    return 1.0 + args.refine_level / 10 if args.refine_level is not None else args.complexity


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not WIDTHxHEIGHT (for example 1920x1080)") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"'{text}': width and height must be between 1 and 16384")
    return w, h


def _pixel_samples(text: str) -> int:
    try:
        samples = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number of samples") from None
    if not valid_pixel_samples(samples):
        raise argparse.ArgumentTypeError(f"'{text}': pixel samples must be between 1 and {MOST_PIXEL_SAMPLES}")
    return samples


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
    render.add_argument("-o", "--output", help="image file: .exr (linear float), .tif, .png, .jpg (default: the render settings' "
                                               "products, each to its productName); a product's other AOVs go beside it as NAME.AOV.EXT")
    render.add_argument("--camera", help="camera prim path (default: the stage's first camera, else one framing the stage)")
    render.add_argument("--resolution", type=_resolution, help="WIDTHxHEIGHT (default: the render settings', else 960x540)")
    when = render.add_mutually_exclusive_group()
    when.add_argument("--frame", type=float, help="time code to render (default: the stage's default time)")
    when.add_argument("--frames", type=_frames, metavar="FIRST-LAST[xSTEP]",
                      help="render a sequence through one session (only what varies in time re-syncs); the output "
                           "name's run of '#' becomes the zero-padded frame number, for example out.####.exr")
    render.add_argument("--aov", choices=AOVS, help="what to write (default: the render product's vars, else color)")
    render.add_argument("--settings", metavar="PRIM_PATH",
                        help="the UsdRenderSettings prim to use (default: the stage's renderSettingsPrimPath, else the only "
                             "one under /Render); its resolution, camera, purposes and products apply unless flags say otherwise")
    render.add_argument("--pixel-error", type=float, default=1.0, metavar="PX",
                        help="screen-space error bound of the level-of-detail cut, in pixels (default 1)")
    render.add_argument("--pixel-samples", type=_pixel_samples, metavar="N",
                        help="anti-aliasing: the colour is the filtered mean of N frames sampling each pixel at spread "
                             "offsets (--pixel-filter; depth, normal and ids are the pixel centres'); each sample costs a frame "
                             "(default: the render settings' tessera:pixelSamples, else 1)")
    render.add_argument("--pixel-filter", choices=PIXEL_FILTERS,
                        help="how pixel samples combine: box (the mean over the pixel's square; alpha the exact coverage) "
                             "or gaussian (samples over two pixels' width, weighted: softer edges, less moire) (default: "
                             "the render settings' tessera:pixelFilter, else box)")
    render.add_argument("--no-lod", action="store_true", help="draw every source triangle: the DAG off, the full-detail reference")
    render.add_argument("--dicing-rate", type=float, default=1.0, metavar="PX",
                        help="displaced surfaces are diced into micro-triangles whose edges project to about this many pixels (default 1)")
    render.add_argument("--vis", choices=VISUALIZATIONS, help="show a debug view in the color AOV instead of shading")
    render.add_argument("--raster", choices=RASTER_MODES, default="auto",
                        help="auto: small triangles through the compute rasterizer, large ones through hardware raster (default)")
    occlusion = render.add_mutually_exclusive_group()
    occlusion.add_argument("--no-occlusion", action="store_true",
                           help="no occlusion culling: neither normal cones nor the two-pass HZB test (by default both; the HZB test where "
                                "it pays: a first frame tests small instances against the large ones, later frames against the frame "
                                "before, and on a CPU device the 15 frames after one where it culled under a quarter of the work skip it)")
    occlusion.add_argument("--occlusion-every-frame", action="store_true",
                           help="the two-pass HZB test in every frame, even where it culls little")
    render.add_argument("--stats", help="write frame statistics to this JSON file (with --frames: {\"frames\": [one per frame]})")
    _add_complexity(render)
    render.add_argument("--purposes", type=_purposes, metavar="render,proxy,guide",
                        help="UsdGeom purposes drawn besides default (default: the render settings' includedPurposes, else "
                             "render); the others are not read")
    render.add_argument("--device", help="Vulkan device: gpu, cpu, an index or part of its name (default: $TESSERA_DEVICE, else the best)")
    render.add_argument("--strict", action="store_true",
                        help="exit with status 1 when the stage gave any error or warning (the image is still written)")
    build_cmd = commands.add_parser("build", help="build every mesh of a stage into the mesh cache ($TESSERA_CACHE)")
    build_cmd.add_argument("stage", help="USD stage")
    build_cmd.add_argument("--frame", type=float, help="time code (default: the stage's default time)")
    _add_complexity(build_cmd)
    build_cmd.add_argument("--purposes", type=_purposes, default=("render",), metavar="render,proxy,guide", help="as for render (default render)")
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
    bench_raster.add_argument("--record", action="store_true",
                              help="keep the measured split for this device in the Tessera cache, where every later session on it "
                                   "finds it (tessera.raster_split)")
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
    bench_render.add_argument("--turns", type=int, default=15,
                              help="turns of the density fields rendered in turns in one process (the scaling ratio's frames; default 15)")
    bench_render.add_argument("--max-density", type=int, default=3, choices=(1, 2, 3),
                              help="fields of 1e6, 1e8, 1e10 source triangles: how many of them (default all 3)")
    bench_render.add_argument("--no-lod-limit", type=float, default=2e8,
                              help="density fields of at most this many source triangles are measured against --no-lod, "
                                   "larger ones against the cut at 1/16 px (default 2e8: the 1e10 field against the cut)")
    bench_render.add_argument("--stages-dir", default="out/bench", help="where the generated stages are kept (default out/bench)")
    bench_render.add_argument("--device", help="Vulkan device, as for render")
    bench_render.add_argument("--plot", help="write the speed-against-error plot (PNG) here")
    bench_render.add_argument("--cases", type=lambda text: text.split(","), default=["density", "brute", "error", "displacement"],
                              help="which tables, comma-separated (default density,brute,error,displacement; also seams: a "
                                   "field with a colour per face and the same field with one colour, each against --no-lod; "
                                   "antialiasing: the 1e6 field at 1, 4 and 16 pixel samples of the box filter and 16 of the "
                                   "gaussian, each against --no-lod at as many samples and at 16 of the box; first-frame: "
                                   "each density field and the densest prototype alone rendered once in a fresh process with "
                                   "their meshes in the mesh cache, as a batch render is: load, first frame, upload; edit: "
                                   "the densest prototype alone with a 4-vertex quad beside it whose points move every frame: "
                                   "the upload's ms and bytes, and the mesh streams the host still holds; aovs: the sphere at 1 px "
                                   "with the colour alone, with depth, normal and primId, and with all seven AOVs: frame ms and the "
                                   "per-pixel buffers' MiB; materials: the 1e8 field's instances in eight materials, each pixel "
                                   "reading its own material and classified into bins, the error against the bins' image)")
    bench_render.add_argument("--seams-n", type=int, default=100,
                              help="the seams fields' sphere has 4 n^2 triangles (default 100: 40 k, 41 M in the field)")
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


def aov_path(output: str, aov: str) -> str:
    """Where a product's AOV other than its first goes: beside the output, its name before the extension."""
    stem, extension = os.path.splitext(output)
    return f"{stem}.{aov}{extension}"


def _jobs(args, settings) -> list[dict]:
    """What to render: one job per output image set, each with its camera (None: the stage's first), resolution and
    [(aov, output name)]. Flags win over the render settings; without -o every product goes to its productName."""
    def job(product, output):
        base = product or settings
        aovs = [args.aov] if args.aov else (product.aovs if product and product.aovs else ["color"])
        return {"camera": args.camera or (base.camera if base else None), "product": product.path if product else None,
                "resolution": args.resolution or (base.resolution if base else (960, 540)),
                "outputs": [(aov, output if i == 0 else aov_path(output, aov)) for i, aov in enumerate(aovs)]}

    products = settings.products if settings else []
    if args.output:
        return [job(products[0] if products else None, args.output)]
    if not products:
        raise ValueError("no output: give -o OUT (the stage has no render settings with RenderProducts)")
    unnamed = [p.path for p in products if not p.name]
    if unnamed:
        raise ValueError(f"{', '.join(unnamed)}: no productName to write to; give -o OUT")
    return [job(product, product.name) for product in products]


def _render(args) -> int:
    from . import Session
    from .session import _open_stage
    from .usd import render_settings

    started = time.perf_counter()
    stage = _open_stage(args.stage)
    settings_warnings: list[str] = []
    settings = render_settings.read(stage, args.settings, settings_warnings)
    jobs = _jobs(args, settings)
    frames = args.frames
    for job in jobs:  # a name without '#' fails before any work
        for _, output in job["outputs"]:
            if frames is not None:
                frame_path(output, frames[0])
    purposes = args.purposes or (settings.purposes if settings else ("render",))
    pixel_samples = args.pixel_samples or (settings.pixel_samples if settings and settings.pixel_samples else 1)
    pixel_filter = args.pixel_filter or (settings.pixel_filter if settings and settings.pixel_filter else "box")
    session = Session(stage, frame=frames[0] if frames else args.frame, device=args.device, complexity=_complexity_of(args),
                      purposes=purposes)
    loaded = time.perf_counter()
    first_camera = session.camera_paths()[0] if session.camera_paths() else None
    all_stats, validation_errors, stage_problems = [], [], len(settings_warnings)
    for message in settings_warnings:
        print(f"tessera: warning: {message}", file=sys.stderr)
    for number, frame in enumerate(frames if frames is not None else [None]):
        if frame is not None:
            session.set_time(frame)
        last_frame = frames is None or number == len(frames) - 1
        for job in jobs:
            render_started = time.perf_counter()
            camera = job["camera"] or first_camera
            aovs = [aov for aov, _ in job["outputs"]]
            occlusion = False if args.no_occlusion else "always" if args.occlusion_every_frame else True
            result = session.render(camera=camera, resolution=job["resolution"], aovs=aovs, pixel_error=args.pixel_error,
                                    lod=not args.no_lod, vis=args.vis, raster=args.raster, occlusion=occlusion,
                                    dicing_rate=args.dicing_rate, pixel_samples=pixel_samples, pixel_filter=pixel_filter,
                                    last=last_frame and job is jobs[-1])
            rendered = time.perf_counter()
            where = f"frame {frame:g}: " if frame is not None else ""
            for message in result.warnings:
                print(f"tessera: warning: {where}{message}", file=sys.stderr)
            for message in result.errors:
                print(f"tessera: error: {where}{message}", file=sys.stderr)
            outputs = []
            for aov, pattern in job["outputs"]:
                output = frame_path(pattern, frame) if frame is not None else pattern
                os.makedirs(os.path.dirname(os.path.abspath(output)), exist_ok=True)
                result.write(output, aov)
                outputs.append(output)
            if frame is not None:
                synced = ", ".join(f"{count} {kind}" for kind, count in sorted(result.stats["synced"].items())) or "nothing"
                print(f"frame {frame:g} -> {', '.join(outputs)}: {rendered - render_started:.2f} s, synced {synced}, "
                      f"{result.stats['meshes_built']} mesh(es) built", file=sys.stderr)
            stats = dict(result.stats)
            stats.update(camera=camera or "(framing)", resolution=list(job["resolution"]), aov=aovs[0], output=outputs[0],
                         aovs=aovs, outputs=outputs, render_settings=settings.path if settings else None, product=job["product"],
                         warnings=result.warnings, errors=result.errors)
            if frame is not None:
                stats.update(frame=frame, seconds={"render": rendered - render_started})
            else:
                stats.update(seconds={"load": loaded - started, "render": rendered - render_started, "total": time.perf_counter() - started})
            all_stats.append(stats)
            validation_errors += [e for e in result.errors if e.startswith("validation error")]
            stage_problems += len(result.warnings) + len(result.errors)
    if args.stats:
        with open(args.stats, "w") as f:
            if frames is not None:
                json.dump({"frames": all_stats, "seconds": {"load": loaded - started, "total": time.perf_counter() - started}}, f, indent=2)
            else:
                json.dump(all_stats[0] if len(all_stats) == 1 else {"products": all_stats}, f, indent=2)
    if args.strict and stage_problems:
        print(f"tessera: --strict: {stage_problems} error(s) and warning(s) about the stage", file=sys.stderr)
        return 1
    return 1 if validation_errors else 0


class _Collector:
    """Stands in for the render index while the scene delegate populates: records the mesh prims. It answers every call
    the delegate makes on an index (a stage with materials dirties them while it populates)."""

    def __init__(self):
        self.meshes = []

    def insert_rprim(self, kind, prim_id, instancer_id="", defaults=0):
        self.meshes.append(prim_id)

    def insert_rprims(self, kind, prim_ids, defaults=None, transforms=None):
        self.meshes.extend(prim_ids)

    def insert_sprim(self, kind, prim_id):
        pass

    def mark_dirty(self, prim_id, bits):
        pass  # nothing is drawn: a mesh is read once, when it is built

    def remove_prim(self, prim_id):
        if prim_id in self.meshes:
            self.meshes.remove(prim_id)


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
                             _complexity_of(args), purposes=args.purposes)
    scene.populate()
    total, done, cached, triangles, failed = len(collector.meshes), 0, 0, 0, 0
    started = time.perf_counter()

    def build_one(prim_id):
        try:
            return prim_id, _tessera.cache_mesh(scene.get_mesh(prim_id)), None
        except Exception as error:  # a bad prim is reported and the others still build
            message = str(error)  # the builder's errors name the prim already
            return prim_id, None, message if message.startswith(prim_id) else f"{prim_id}: {message}"

    with ThreadPoolExecutor(max_workers=_tessera.core_count()) as pool:  # the cores this process may use (its affinity)
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
