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
