"""The raster split (tessera.raster_split): measured per device by `tessera bench raster --record`, recorded in the
cache, used by every session on that device; it changes which rasterizer draws a cluster, never the image."""

import json

import numpy as np
import pytest

import tessera
from conftest import TESTENV
from tessera import raster_split


def rows(*measured):
    return [{"area_px": a, "software_share": share, "software_ms": sw, "hardware_ms": hw} for a, share, sw, hw in measured]


def test_crossover_lies_between_the_last_software_win_and_the_first_hardware_win():
    # An earlier host's shape: compute wins up to 32 px, hardware from 64: 45 px between them.
    assert raster_split.crossover(rows((1, 1.0, 10, 30), (16, 0.99, 10, 12), (32, 0.97, 10, 11), (64, 0.95, 12, 11))) == 45.3
    # Compute wins everywhere it really drew (256 px: mostly hardware even when compute is asked): its largest win.
    assert raster_split.crossover(rows((1, 1.0, 1, 3), (64, 0.95, 5, 6), (128, 0.81, 5, 6), (256, 0.15, 7, 6))) == 128.0
    # A hardware win below a compute win does not end the compute range; the first hardware win after it does.
    assert raster_split.crossover(rows((1, 1.0, 5, 4), (2, 1.0, 3, 4), (4, 1.0, 3, 4), (8, 1.0, 5, 4))) == pytest.approx(5.7)
    # Hardware wins even the smallest size: nearly everything goes to hardware raster.
    assert raster_split.crossover(rows((1, 1.0, 5, 4), (2, 1.0, 5, 4))) == 1.0
    assert raster_split.crossover(rows((64, 0.3, 1, 2))) is None, "nothing the compute rasterizer really drew"


def test_records_are_per_device_and_a_broken_file_means_the_default(tmp_path):
    measured = rows((32, 0.97, 10, 11), (64, 0.95, 12, 11))
    assert raster_split.for_device(tmp_path, "gpu A") == (raster_split.DEFAULT_AREA, "default")
    raster_split.record(tmp_path, "gpu A", 45.3, measured)
    raster_split.record(tmp_path, "cpu B | some CPU", 128.0, measured)
    assert raster_split.for_device(tmp_path, "gpu A") == (45.3, "recorded")
    assert raster_split.for_device(tmp_path, "cpu B | some CPU") == (128.0, "recorded")
    assert raster_split.for_device(tmp_path, "cpu B | another CPU")[1] == "default", "a CPU device's split is its CPU's"
    assert json.loads(raster_split.record_path(tmp_path).read_text())["gpu A"]["measured"][1]["hardware_ms"] == 11
    raster_split.record_path(tmp_path).write_text("{ not json")
    assert raster_split.for_device(tmp_path, "gpu A") == (raster_split.DEFAULT_AREA, "default")


def test_a_session_uses_its_devices_record_and_the_split_never_changes_the_image(tmp_path, monkeypatch):
    monkeypatch.setenv("TESSERA_CACHE", str(tmp_path / "cache"))
    stage = TESTENV / "testPointInstancer" / "point_instancer.usda"
    plain = tessera.Session(stage, validation=True)
    assert (plain.software_raster_area, plain.software_raster_area_source) == (raster_split.DEFAULT_AREA, "default")
    key = raster_split.device_key(plain.delegate.device_name, plain.delegate.software_device)
    raster_split.record(plain.delegate.cache_directory, key, 7.5, [])
    session = tessera.Session(stage, validation=True)
    aovs = ("primId", "triangleId", "depth")

    def frame(**kwargs):
        result = session.render(camera=session.camera_paths()[0], resolution=(200, 150), aovs=aovs, occlusion=False, **kwargs)
        assert not result.errors, result.errors
        return result

    recorded = frame()
    assert (recorded.stats["sw_raster_area"], recorded.stats["sw_raster_area_source"]) == (7.5, "recorded")
    hardware = frame(software_raster_area=1e-6)  # every cluster through hardware raster
    software = frame(software_raster_area=1e6)   # every cluster the compute rasterizer can take
    assert hardware.stats["sw_raster_area_source"] == "given"
    assert hardware.stats["sw_triangles"] == 0 < software.stats["sw_triangles"]
    assert hardware.stats["sw_triangles"] <= recorded.stats["sw_triangles"] <= software.stats["sw_triangles"]
    for aov in aovs:
        assert np.array_equal(hardware[aov].pixels.view(np.uint32), software[aov].pixels.view(np.uint32)), aov
        assert np.array_equal(hardware[aov].pixels.view(np.uint32), recorded[aov].pixels.view(np.uint32)), aov
    with pytest.raises(tessera.StageError, match="software raster area"):
        frame(software_raster_area=0)


def _strip(stage, path, y, length, triangles, sliver=None):
    """A row of `triangles` thin triangles along x (`length` units long, 0.02 high) at height y; with `sliver`, the last
    is replaced by one of that length instead. Few enough triangles for one cluster."""
    from pxr import UsdGeom

    xs = np.linspace(-length / 2, length / 2, triangles // 2 + 1)
    points = [(x, y + dy, 0.0) for x in xs for dy in (0.0, 0.02)]
    quads = [(2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1) for i in range(triangles // 2)]
    faces = [(a, b, c) for a, b, c, d in quads for a, b, c in ((a, b, c), (a, c, d))]
    if sliver:
        base = len(points)
        points += [(-sliver / 2, y - 0.3, 0.0), (sliver / 2, y - 0.3, 0.0), (sliver / 2, y - 0.29, 0.0)]
        faces[-1] = (base, base + 1, base + 2)
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([i for face in faces for i in face])
    mesh.CreateDoubleSidedAttr(True)


def test_the_longest_edge_not_the_spread_keeps_a_cluster_out_of_the_compute_rasterizer():
    """A cluster goes to the compute rasterizer when its triangles are small, however far it spreads on screen (a
    silhouette's slivers), unless one of its edges is longer than TS_SW_MAX_EDGE_PIXELS (128 px): that triangle's box
    would hold one lane while the others wait. Either way the image is the one hardware raster draws."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    # At 10 units the default camera shows about 4.2 units across 400 pixels: about 95 pixels a unit.
    UsdGeom.Camera.Define(stage, "/Camera").AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    _strip(stage, "/Spread", 0.5, 4.0, 128)  # 380 px wide (radius beyond 128 px), edges of 3-6 px
    _strip(stage, "/Long", -0.5, 0.5, 128, sliver=2.0)  # 48 px wide but one edge of 190 px
    session = tessera.Session(stage, validation=True)

    def frame(**kwargs):
        result = session.render(camera="/Camera", resolution=(400, 300), aovs=("primId", "triangleId", "depth"), occlusion=False, **kwargs)
        assert not result.errors, result.errors
        return result

    split, hardware = frame(), frame(software_raster_area=1e-6)
    assert split.stats["visible_clusters"] == 2 and split.stats["sw_triangles"] == split.stats["hw_triangles"] == 128
    assert hardware.stats["hw_triangles"] == 256
    for aov in ("primId", "triangleId", "depth"):
        assert np.array_equal(split[aov].pixels.view(np.uint32), hardware[aov].pixels.view(np.uint32)), aov
    # Which rasterizer drew each strip (the raster-bins view: compute blue, hardware orange): /Spread lies in the upper
    # half of the image, /Long in the lower.
    bins = session.render(camera="/Camera", resolution=(400, 300), aovs=("color", "primId"), vis="raster-bins", occlusion=False)
    colour, covered = np.asarray(bins["color"].pixels)[..., :3], bins["primId"].ids() != 0xFFFFFFFF
    upper, lower = colour[:150][covered[:150]], colour[150:][covered[150:]]
    assert len(upper) > 300 and len(lower) > 50
    assert np.all(upper[:, 2] > upper[:, 0]), "the spread-out strip of small triangles: compute raster"
    assert np.all(lower[:, 0] > lower[:, 2]), "the strip with a long edge: hardware raster"
