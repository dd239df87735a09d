"""The `tessera` command: outputs, options, and one-line errors for bad input."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import tessera
from conftest import TESTENV
from tessera import raster_split

CUBE = TESTENV / "testCube" / "cube.usda"


def run(*args):
    return subprocess.run([sys.executable, "-m", "tessera.cli", *map(str, args)], capture_output=True, text=True, timeout=300)


def bench_render(tmp_path, *args):
    """`tessera bench render` at 96 x 54 with its stages in tmp_path: the finished run and the rows of its --json."""
    rows_file = tmp_path / "rows.json"
    done = run("bench", "render", "--resolution", "96x54", *args, "--stages-dir", tmp_path, "--json", rows_file)
    assert done.returncode == 0, done.stderr + done.stdout
    return done, json.loads(rows_file.read_text())


@pytest.mark.parametrize("extension", ["png", "exr", "tif", "jpg"])
def test_render_writes_each_format(tmp_path, extension):
    out = tmp_path / f"cube.{extension}"
    done = run("render", CUBE, "-o", out, "--resolution", "64x48")
    assert done.returncode == 0, done.stderr
    image = tessera.read_image(str(out))
    assert image.shape == (48, 64, 4)
    assert image[24, 32, :3].max() > 0.05, "the cube covers the centre"


def test_exr_holds_linear_colour_and_png_the_display_transform(tmp_path):
    assert run("render", CUBE, "-o", tmp_path / "c.exr", "--resolution", "64x64").returncode == 0
    assert run("render", CUBE, "-o", tmp_path / "c.png", "--resolution", "64x64").returncode == 0
    linear = tessera.read_image(str(tmp_path / "c.exr"))[32, 32, :3]
    display = tessera.read_image(str(tmp_path / "c.png"))[32, 32, :3]
    encoded = [1.055 * c ** (1 / 2.4) - 0.055 if c > 0.0031308 else 12.92 * c for c in linear]
    assert display == pytest.approx(encoded, abs=2.5 / 255)


def test_stats_and_camera_options(tmp_path):
    stats_file = tmp_path / "stats.json"
    done = run("render", CUBE, "-o", tmp_path / "a.png", "--camera", "/World/Camera", "--resolution", "80x60", "--aov", "primId",
               "--stats", stats_file)
    assert done.returncode == 0, done.stderr
    stats = json.loads(stats_file.read_text())
    assert stats["camera"] == "/World/Camera" and stats["resolution"] == [80, 60]
    assert stats["instances"] == 1 and stats["visible_clusters"] == 1 and stats["errors"] == []
    assert set(stats["gpu_ms"]) == {"cull", "sw_raster", "hw_raster", "tessellation", "hzb", "classify", "resolve", "readback"}
    # The CPU's spans: recording, then waiting for the GPU, both inside the whole render call.
    assert 0 < stats["cpu_record_ms"] and 0 < stats["cpu_wait_ms"], stats
    assert stats["cpu_record_ms"] + stats["cpu_wait_ms"] <= stats["cpu_frame_ms"], stats
    assert stats["micro_triangles"] == 0 and stats["tessellation_bytes"] == 0, "nothing displaces: no tessellation work or memory"
    assert stats["occlusion_tested"] is False, "a first frame has no previous HZB"
    assert {"occluded_instances", "occluded_clusters", "backface_clusters", "post_pass_clusters"} <= set(stats)
    assert stats["sw_triangles"] + stats["hw_triangles"] == stats["visible_triangles"]
    assert stats["pixel_error"] == 1.0 and stats["lod"] is True and stats["candidate_clusters"] >= stats["visible_clusters"]
    assert stats["texel_views"] is True, "a small stage's streams fit the device's texel views"
    assert stats["output_binding"] is True, "a small frame's AOV output fits the device's storage buffer binding"


def test_lod_options(tmp_path):
    stats_file = tmp_path / "stats.json"
    done = run("render", CUBE, "-o", tmp_path / "a.png", "--resolution", "80x60", "--no-lod", "--vis", "clusters", "--stats", stats_file)
    assert done.returncode == 0, done.stderr
    stats = json.loads(stats_file.read_text())
    assert stats["lod"] is False and stats["visible_triangles"] == 12 and stats["hw_triangles"] == 12, "--no-lod: hardware raster only"
    assert tessera.read_image(str(tmp_path / "a.png"))[30, 40, :3].max() > 0.05
    done = run("render", CUBE, "-o", tmp_path / "b.png", "--pixel-error", "-2")
    assert done.returncode == 1 and "pixel error must be a number >= 0" in done.stderr


@pytest.mark.parametrize("args,message", [
    (["render", "/no/such/stage.usda", "-o", "x.png"], "/no/such/stage.usda: no such file"),
    (["render", TESTENV / "testBadInput" / "malformed.usda", "-o", "x.png"], "malformed.usda: cannot be opened as a USD stage"),
    # the parse error's own message, where in the file, without USD's C++ function and namespace
    (["render", TESTENV / "testBadInput" / "malformed.usda", "-o", "x.png"], "malformed.usda:8:1: parse error matching Sdf_TextFileFormatParser::"),
    (["render", CUBE, "-o", "x.png", "--camera", "/World/Nope"], "/World/Nope: not a camera on this stage"),
    (["render", CUBE, "-o", "x.bmp"], "unsupported image format '.bmp'"),
])
def test_errors_are_one_line_naming_the_culprit(tmp_path, args, message):
    args = [str(tmp_path / a) if a in ("x.png", "x.bmp") else a for a in args]
    done = run(*args)
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tessera: error:"), done.stderr
    assert message in lines[0] and "pxrInternal" not in lines[0] and "Error in '" not in lines[0]


def test_bad_resolution_is_rejected(tmp_path):
    done = run("render", CUBE, "-o", tmp_path / "x.png", "--resolution", "big")
    assert done.returncode == 2 and "WIDTHxHEIGHT" in done.stderr


def test_forcing_a_device_that_does_not_exist_is_one_clear_line(tmp_path):
    done = run("render", CUBE, "-o", tmp_path / "x.png", "--device", "no-such-gpu")
    assert done.returncode == 1
    assert "no usable Vulkan device matches TESSERA_DEVICE=no-such-gpu" in done.stderr


def test_build_mesh_reports_the_dag():
    from tessera import _tessera
    from tessera.bench import displaced_sphere

    stats = _tessera.build_mesh(*displaced_sphere(60))  # a closed, lumpy latitude-longitude sphere
    levels = stats["levels"]
    assert levels[0]["triangles"] == stats["source_triangles"], "level 0 holds every source triangle"
    assert len(levels) >= 5
    for finer, coarser in zip(levels, levels[1:]):
        assert coarser["triangles"] < 0.7 * finer["triangles"], "each level about halves the one below"
        assert coarser["max_error"] >= finer["max_error"], "errors grow up the DAG"
    assert stats["root_triangles"] <= 2 * 128


def test_bench_build_prints_a_table_and_writes_json(tmp_path):
    n = 40  # a 40 x 40 quad grid as OBJ
    lines = [f"v {x / n} {y / n} {0.02 * ((x * 7 + y * 3) % 5)}" for y in range(n + 1) for x in range(n + 1)]
    lines += [f"f {y * (n + 1) + x + 1} {y * (n + 1) + x + 2} {(y + 1) * (n + 1) + x + 2} {(y + 1) * (n + 1) + x + 1}"
              for y in range(n) for x in range(n)]
    mesh = tmp_path / "grid.obj"
    mesh.write_text("\n".join(lines))
    rows_file = tmp_path / "rows.json"
    done = run("bench", "build", mesh, "--json", rows_file)
    assert done.returncode == 0, done.stderr
    assert "tris/s" in done.stdout and "grid.obj" in done.stdout
    (row,) = json.loads(rows_file.read_text())
    assert row["input_triangles"] == 2 * n * n
    assert row["dag_depth"] >= 3 and row["build_seconds"] > 0
    assert 0 < row["disk_bytes_per_input_triangle"] < 12 and row["decode_input_triangles_per_second"] > 0
    assert row["relative_error_per_level"][0] == 0 and row["relative_error_per_level"][-1] > 0
    assert row["first_build_mib"] > 0 and row["peak_memory_bytes_per_input_triangle"] >= 0  # one-time costs apart


def test_bench_render_prints_tables_and_writes_json(tmp_path):
    rows_file, plot = tmp_path / "rows.json", tmp_path / "error.png"
    # The 1e8 field is measured against its cut at 1/16 px (every source triangle would take lavapipe half a minute).
    done = run("bench", "render", "--resolution", "96x54", "--frames", "1", "--turns", "2", "--max-density", "2", "--no-lod-limit", "1e7",
               "--stages-dir", tmp_path, "--json", rows_file, "--plot", plot)
    assert done.returncode == 0, done.stderr + done.stdout
    assert "frame ms" in done.stdout and "PSNR dB" in done.stdout
    rows = json.loads(rows_file.read_text())
    assert {r["table"] for r in rows} == {"density scaling", "against brute force", "speed against error", "displacement"}
    field, every_frame, no_occlusion, dense, _, _ = [r for r in rows if r["table"] == "density scaling"]
    assert field["source_triangles"] == 32 * 32 * 4 * 16 * 16 and field["frame_ms"] > 0
    assert dense["source_triangles"] == 32 * 32 * 4 * 156 * 156
    assert every_frame["occlusion"] is True and no_occlusion["occlusion"] is False, "measured frames test against the frame before"
    assert not every_frame["occlusion_rested"] and not no_occlusion["occlusion_rested"]
    assert field["occlusion"] or field["occlusion_rested"], "the default: occlusion where it pays"
    # Both fields were also rendered in turns in one process, and the scaling line compares those frames.
    assert field["frame_in_turns_ms"] > 0 and dense["frame_in_turns_ms"] > 0
    assert "frame_in_turns_ms" not in no_occlusion and "frame_in_turns_ms" not in every_frame
    # Every density row reports its error bound and its image error, the 1e6 field's against every source triangle.
    assert field["error_bound_px"] == dense["error_bound_px"] == 1.0
    assert field["error_reference"] == no_occlusion["error_reference"] == "--no-lod" and dense["error_reference"] == "0.0625 px cut"
    assert all(20 < r["psnr_db"] <= r["psnr_4x4_db"] and 0 < r["same_prim_percent"] <= 100 for r in (field, every_frame, no_occlusion, dense))
    assert "PSNR 4x4 dB" in done.stdout and "error bound px" in done.stdout
    ratio = dense["frame_in_turns_ms"] / field["frame_in_turns_ms"]
    assert f"densest field costs {ratio:.2f}x the lightest (95x the source triangles), rendered in turns" in done.stdout
    brute = {r["case"]: r for r in rows if r["table"] == "against brute force"}
    assert brute["--no-lod"]["speedup_vs_no_lod"] == brute["--no-lod"]["gpu_speedup_vs_no_lod"] == 1.0
    assert brute["1 px"]["speedup_vs_no_lod"] > 0 and brute["1 px"]["gpu_speedup_vs_no_lod"] > 0, "in wall time and in GPU time"
    assert "GPU speedup" in done.stdout
    sweep = [r for r in rows if r["table"] == "speed against error"]
    assert [r["pixel_error"] for r in sweep] == [0.25, 0.5, 1.0, 2.0, 4.0, 8.0]
    assert all(0 < r["same_prim_percent"] <= 100 and r["psnr_db"] > 0 for r in sweep)
    assert tessera.read_image(str(plot)).shape == (270, 480, 4)
    displaced = {r["case"]: r for r in rows if r["table"] == "displacement"}
    assert displaced["pre-tessellated, --no-lod"]["psnr_db"] == 99.0, "the reference against itself"
    runtime = [r for case, r in displaced.items() if case.startswith("runtime")]
    assert len(runtime) == 5 and all(r["micro_triangles"] > 0 and r["psnr_db"] > 20 for r in runtime)
    assert runtime[0]["micro_triangles"] > runtime[-1]["micro_triangles"], "a finer dicing rate makes more micro-triangles"


def test_bench_render_seams_gives_a_field_with_a_colour_per_face_its_lod(tmp_path):
    _, rows = bench_render(tmp_path, "--cases", "seams", "--seams-n", "16", "--frames", "1")
    rows = {r["case"]: r for r in rows}
    assert set(rows) == {"colour per face, 1 px", "colour per face, --no-lod", "one colour, 1 px", "one colour, --no-lod"}
    assert all(r["table"] == "seams" and r["source_triangles"] == 32 * 32 * 4 * 16 * 16 for r in rows.values())
    # A seam at every edge no longer keeps the mesh at its source triangles (the DAG stalled at level 0 before).
    for kind in ("colour per face", "one colour"):
        assert rows[f"{kind}, 1 px"]["triangles_drawn"] < 0.5 * rows[f"{kind}, --no-lod"]["triangles_drawn"], kind
        assert rows[f"{kind}, --no-lod"]["psnr_db"] == 99.0 and rows[f"{kind}, 1 px"]["psnr_db"] > 20


def test_bench_render_antialiasing_measures_each_sample_count_against_its_reference(tmp_path):
    done, rows = bench_render(tmp_path, "--cases", "antialiasing", "--frames", "1")
    assert [(r["table"], r["case"], r["pixel_samples"], r["pixel_filter"]) for r in rows] == [
        ("anti-aliasing", "1 sample", 1, "box"), ("anti-aliasing", "4 samples", 4, "box"), ("anti-aliasing", "16 samples", 16, "box"),
        ("anti-aliasing", "16 samples, gaussian", 16, "gaussian")]
    assert [r["error_reference"] for r in rows] == ["--no-lod, " + r["case"] for r in rows]
    assert all(r["ms_per_sample"] > 0 and 20 < r["psnr_db"] and r["psnr_vs_finest_db"] > 20 for r in rows)
    # Against the 16-sample reference, more samples come closer: the single sample's error is mostly aliasing.
    assert rows[0]["psnr_vs_finest_db"] < rows[2]["psnr_vs_finest_db"] == rows[2]["psnr_db"]
    assert "ms per sample" in done.stdout


def test_bench_render_first_frame_loads_cached_meshes_and_draws_the_warm_frames_image(tmp_path):
    done, rows = bench_render(tmp_path, "--cases", "first-frame", "--max-density", "1", "--frames", "1")
    assert [(r["table"], r["case"]) for r in rows] == [("first frame", "1 M source triangles, a field"), ("first frame", "1 k source triangles, one mesh")]
    for row in rows:
        # The parent filled the mesh cache: the first frame loads the mesh from it and builds nothing.
        assert row["meshes_cached"] == 1 and row["meshes_built"] == 0, row
        assert row["first_frame_ms"] > row["upload_ms"] >= 0 and row["load_seconds"] > 0  # a 1 k-triangle mesh uploads in under 0.1 ms
        assert 0 < row["resident_mib"] <= row["peak_memory_mib"], row
        # Drawn without a frame before (no HZB to test against), its image is the warm frames' all the same.
        assert row["error_reference"] == "first frame" and row["psnr_db"] == 99.0 and row["same_prim_percent"] == 100.0
    assert "first frame ms" in done.stdout and "upload ms" in done.stdout and "resident MiB" in done.stdout


def test_bench_render_aovs_resolves_every_aov_in_one_pass(tmp_path):
    done, rows = bench_render(tmp_path, "--cases", "aovs", "--max-density", "1", "--frames", "1")
    assert [(r["table"], r["case"], r["aovs"]) for r in rows] == [("AOVs", "color", 1), ("AOVs", "color, depth, normal, primId", 4),
                                                                   ("AOVs", "all seven", 7)]
    # A slice of the output, 16 bytes a pixel, per AOV beside the frame's other per-pixel buffers.
    assert [r["pixel_bytes"] - rows[0]["pixel_bytes"] for r in rows] == [0, 3 * 96 * 54 * 16, 6 * 96 * 54 * 16]
    assert all(r["frame_ms"] > 0 and r["resolve_ms"] >= 0 for r in rows)
    assert "pixel MiB" in done.stdout


def test_bench_render_materials_shades_eight_materials_as_their_bins_do(tmp_path):
    done, rows = bench_render(tmp_path, "--cases", "materials", "--max-density", "1", "--frames", "1")
    assert [r["table"] for r in rows] == ["materials", "materials"]
    read, binned = rows
    assert binned["case"] == "8 materials, 8 bins" and binned["classify_ms"] >= 0
    if "llvmpipe" in read["device"]:  # a CPU device reads each pixel's material: no classify, no bin list
        assert read["case"] == "8 materials, each pixel's own material" and read["pixel_mib"] <= binned["pixel_mib"]
    # The same image as the bins' (the error reference), bit for bit.
    assert read["psnr_db"] == 99.0 and read["same_prim_percent"] == 100.0 and read["error_reference"] == "bins"
    assert read["source_triangles"] == binned["source_triangles"] > 1e6 * 0.9


def test_bench_render_edit_uploads_the_edited_quad_alone_and_the_host_keeps_no_mesh(tmp_path):
    done, [row, displaced] = bench_render(tmp_path, "--cases", "edit", "--max-density", "1", "--frames", "2")
    assert (row["table"], row["case"]) == ("live edit", "a quad's points beside the mesh")
    assert (displaced["table"], displaced["case"]) == ("live edit", "a quad's points beside a displaced sphere")
    # Beside a sphere drawn displaced, an edit writes the quad's streams alone too, and makes none of the sphere's
    # displacement data again (made at its first frame, kept).
    assert displaced["micro_triangles"] > 0 and displaced["displaced_meshes_prepared"] == 0, displaced
    assert 0 < displaced["geometry_upload_bytes"] < 1000, displaced
    # Each frame writes the quad's streams alone (a cluster, four vertices, two triangles), not the sphere's; the sphere,
    # held by the mesh cache, left the host once on the GPU (the quad is too small to be cached: its few bytes stay).
    assert 0 < row["geometry_upload_bytes"] < 1000, row
    assert row["source_triangles"] > 1000, "the sphere's 1024 and the quad's 2"
    assert 0 < row["host_mesh_bytes"] < 1000 and row["host_mesh_mib"] == 0.0, row
    assert "upload bytes" in done.stdout and "host mesh MiB" in done.stdout and "displaced prepared" in done.stdout


def test_bench_raster_measures_both_rasterizers_per_triangle_size(tmp_path):
    rows_file, cache = tmp_path / "rows.json", tmp_path / "cache"
    # --record writes into the cache it runs with: its own here, so that no other test's sessions find the record.
    done = subprocess.run([sys.executable, "-m", "tessera.cli", "bench", "raster", "--resolution", "96x54", "--frames", "1",
                           "--stages-dir", str(tmp_path), "--json", str(rows_file), "--record"],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "TESSERA_CACHE": str(cache)})
    assert done.returncode == 0, done.stderr + done.stdout
    assert "crossover:" in done.stdout and "SW GPU ms" in done.stdout
    rows = json.loads(rows_file.read_text())
    records = json.loads((cache / "raster_split.json").read_text())
    assert list(records) == [rows[0]["device_key"]] and f"recorded for {rows[0]['device_key']}" in done.stdout
    assert records[rows[0]["device_key"]]["area_px"] == raster_split.crossover(rows)
    assert [r["area_px"] for r in rows] == [1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048]
    assert all(r["software_ms"] > 0 and r["hardware_ms"] > 0 and r["faster"] in ("software", "hardware") for r in rows)
    # Triangles of one pixel fill the frame about once: twice as many triangles as pixels, all through software raster.
    assert 0.5 * 96 * 54 < rows[0]["triangles"] / 2 < 2 * 96 * 54 and rows[0]["software_share"] > 0.9
    assert rows[0]["triangles"] > 8 * rows[4]["triangles"], "16 times the area, a sixteenth of the triangles"


def test_bench_textures_measures_loads_and_shading(tmp_path):
    rows_file = tmp_path / "rows.json"
    done = run("bench", "textures", "--resolution", "96x54", "--frames", "1", "--sizes", "32,64", "--stages-dir", tmp_path,
               "--json", rows_file)
    assert done.returncode == 0, done.stderr + done.stdout
    assert "load + mips ms" in done.stdout and "resolve ms" in done.stdout
    rows = json.loads(rows_file.read_text())
    loads = [r for r in rows if r["table"] == "loads"]
    assert [(r["texture"], r["format"]) for r in loads[:3]] == [
        ("32x32 4ch 8-bit", "rgba8 srgb"), ("32x32 1ch 8-bit", "r8"), ("32x32 4ch 16-bit", "rgba16f")]
    # The mip chain adds a third: 4, 1 and 8 bytes per texel become 5.33, 1.33 and 10.67.
    assert [r["bytes_per_texel"] for r in loads[3:]] == [5.33, 1.33, 10.67]
    shading = {r["case"]: r for r in rows if r["table"] == "shading"}
    assert shading["untextured"]["texture_bytes"] == 0 and shading["untextured"]["textures"] == 0
    assert shading["four textures"]["textures"] == 4 and shading["opacity mask"]["textures"] == 1
    assert all(r["resolve_ms"] > 0 for r in shading.values())


def test_bench_usd_translates_and_resyncs_one_edit(tmp_path):
    rows_file = tmp_path / "rows.json"
    done = run("bench", "usd", "--prims", "50", "--instances", "40", "--point-instances", "3000", "--prototype-triangles", "400",
               "--edits", "2", "--stages-dir", tmp_path, "--json", rows_file)
    assert done.returncode == 0, done.stderr + done.stdout
    assert "edit re-sync ms" in done.stdout and "GPU B/inst" in done.stdout
    one_shape, distinct, instances, points = json.loads(rows_file.read_text())
    assert points["instances"] == 3000 and points["batches"] == 1, "one PointInstancer prototype: one batch"
    assert points["gpu_bytes_per_instance"] <= 64 and points["load_seconds"] >= points["upload_seconds"] >= 0
    assert points["visible_instances"][0] > 0, "the frame drew some of the field"
    assert one_shape["rprims"] == distinct["rprims"] == 50 and instances["rprims"] == 1
    assert one_shape["meshes_shared"] == 49, "one shape: built or loaded once, shared by the other 49"
    assert distinct["meshes_built"] + distinct["meshes_cached"] == 50 and distinct["meshes_shared"] == 0
    assert all(row["edit_resynced_prims"] == 1 and row["edit_resync_ms"] > 0 for row in (one_shape, distinct, instances))


def _big_and_tiny_meshes(path):
    """Two meshes above the size the cache keeps (a 24 x 24-quad grid each, one raised) and one tiny cube."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    i, j = np.meshgrid(np.arange(24), np.arange(24), indexing="ij")
    a = (i * 25 + j).ravel()
    quads = np.stack([a, a + 1, a + 26, a + 25], -1).ravel().tolist()
    x, z = np.meshgrid(np.linspace(-1, 1, 25), np.linspace(-1, 1, 25), indexing="ij")
    for name, height in (("GridA", 0.0), ("GridB", 0.5)):
        grid = UsdGeom.Mesh.Define(stage, f"/{name}")
        grid.CreatePointsAttr([(float(px), height + 0.1 * float(px * pz), float(pz)) for px, pz in zip(x.ravel(), z.ravel())])
        grid.CreateFaceVertexCountsAttr([4] * 576)
        grid.CreateFaceVertexIndicesAttr(quads)
        grid.CreateSubdivisionSchemeAttr("none")
    UsdGeom.Cube.Define(stage, "/Tiny")
    stage.GetRootLayer().Save()
    return path


def test_an_unchanged_stage_is_never_built_twice(tmp_path, monkeypatch):
    """Meshes are loaded from the cache the second time; tiny ones (the cube) are built again instead, which costs
    less than reading a page file, and never fill the cache."""
    monkeypatch.setenv("TESSERA_CACHE", str(tmp_path / "cache"))
    stage = _big_and_tiny_meshes(tmp_path / "meshes.usda")
    first = tessera.Session(stage, validation=True).render(resolution=(64, 48), aovs=("primId",))
    assert first.stats["meshes_built"] == 3 and first.stats["meshes_cached"] == 0
    second = tessera.Session(stage, validation=True).render(resolution=(64, 48), aovs=("primId",))
    assert second.stats["meshes_built"] == 1 and second.stats["meshes_cached"] == 2, "the two grids from the cache"
    assert (first["primId"].ids() == second["primId"].ids()).all()
    assert len(list((tmp_path / "cache").rglob("*.tsra"))) == 2, "the cube's build is not cached"


def test_tessera_build_fills_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TESSERA_CACHE", str(tmp_path / "cache"))
    stage = _big_and_tiny_meshes(tmp_path / "meshes.usda")
    done = run("build", stage)
    assert done.returncode == 0, done.stderr
    assert "3/3 meshes" in done.stderr and "built 3 mesh(es), 0 from the cache" in done.stderr
    assert run("build", stage).stderr.count("built 1 mesh(es), 2 from the cache") == 1
    stats_file = tmp_path / "stats.json"
    assert run("render", stage, "-o", tmp_path / "x.png", "--resolution", "32x24", "--stats", stats_file).returncode == 0
    stats = json.loads(stats_file.read_text())
    assert stats["meshes_built"] == 1 and stats["meshes_cached"] == 2


def test_tessera_build_reads_stages_with_materials(tmp_path, monkeypatch):
    """The stand-in index `tessera build` populates answers every call the scene delegate makes: materials are dirtied
    while a stage populates (it failed there with an AttributeError, building nothing)."""
    from pxr import Sdf, Usd, UsdShade

    monkeypatch.setenv("TESSERA_CACHE", str(tmp_path / "cache"))
    stage_path = _big_and_tiny_meshes(tmp_path / "meshes.usda")
    stage = Usd.Stage.Open(str(stage_path))
    material = UsdShade.Material.Define(stage, "/Looks/Red")
    surface = UsdShade.Shader.Define(stage, "/Looks/Red/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set((0.8, 0.1, 0.1))
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    for name in ("/GridA", "/GridB"):
        UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(name)).Bind(material)
    stage.GetRootLayer().Save()
    done = run("build", stage_path)
    assert done.returncode == 0, done.stderr
    assert "built 3 mesh(es), 0 from the cache, 0 failed" in done.stderr
    stats_file = tmp_path / "stats.json"
    assert run("render", stage_path, "-o", tmp_path / "x.png", "--resolution", "32x24", "--stats", stats_file).returncode == 0
    stats = json.loads(stats_file.read_text())
    assert stats["meshes_built"] == 1 and stats["meshes_cached"] == 2, "the grids were built by tessera build"


def test_tessera_build_names_each_bad_mesh_once_and_builds_the_rest(tmp_path, monkeypatch):
    monkeypatch.setenv("TESSERA_CACHE", str(tmp_path / "cache"))
    done = run("build", TESTENV / "testBadInput" / "bad_meshes.usda")
    assert done.returncode == 1, "a mesh failed"
    errors = [line for line in done.stderr.replace("\r", "\n").splitlines() if line.startswith("tessera: error:")]
    assert errors == ["tessera: error: /CountsDisagree: faceVertexCounts sum to 8 but faceVertexIndices has 4 entries",
                      "tessera: error: /NegativeIndex: no drawable faces (every face is invalid: a vertex index out of range)"]
    assert "built 2 mesh(es), 0 from the cache, 2 failed" in done.stderr


def test_occlusion_every_frame_keeps_the_hzb_passes_that_rest_by_default_on_a_cpu_device(tmp_path):
    """A cube hides nothing: on a CPU device the frames after the first rest from occlusion's HZB passes, unless
    --occlusion-every-frame; --no-occlusion and it exclude each other."""
    rested = {}
    for flag in ("", "--occlusion-every-frame"):
        stats_file = tmp_path / f"stats{len(rested)}.json"
        done = run("render", CUBE, "-o", tmp_path / "c.####.png", "--frames", "1-3", "--resolution", "64x48", "--stats", stats_file,
                   *([flag] if flag else []))
        assert done.returncode == 0, done.stderr
        frames = json.loads(stats_file.read_text())["frames"]
        rested[flag] = [(f["occlusion_rested"], f["hzb_builds"]) for f in frames]
    if tessera.Session(CUBE).delegate.software_device:
        assert rested[""] == [(False, 1), (True, 0), (True, 0)]
    # The last frame builds no HZB for a frame after it (its post pass drew nothing: the one HZB would be that one).
    assert rested["--occlusion-every-frame"] == [(False, 1)] * 2 + [(False, 0)]
    done = run("render", CUBE, "-o", tmp_path / "x.png", "--no-occlusion", "--occlusion-every-frame")
    assert done.returncode == 2 and "not allowed with argument --no-occlusion" in done.stderr
