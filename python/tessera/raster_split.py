"""Where small triangles stop going to the compute rasterizer: measured per device, recorded, used by every session.

Clusters whose triangles are estimated below `area` pixels each are drawn by the compute rasterizer, the rest by
hardware raster (RenderSettings::softwareRasterArea). Both draw the same pixels, so the split only changes speed, and
the best split depends on the device: on lavapipe, on the CPU it runs on as well (hardware raster was three times
dearer on one 2-core host than on another, docs/benchmarks.md). `tessera bench raster --record` measures it and
records it in the Tessera cache folder (`raster_split.json`, by device); a session on a device with a record uses it,
any other the default. The record is the measurement's, so deleting it (or a fresh cache) goes back to the default.
"""

from __future__ import annotations

import json
import math
import os
import platform
from pathlib import Path

from . import _tessera

# RenderSettings::softwareRasterArea (renderer.h says why it is what it is).
DEFAULT_AREA = float(_tessera.DEFAULT_SOFTWARE_RASTER_AREA)
RECORD_FILE = "raster_split.json"
# A measured size counts only where the compute rasterizer really drew most of the triangles when asked to (larger
# clusters go to hardware raster whatever is asked).
MIN_SOFTWARE_SHARE = 0.5


def cpu_model() -> str:
    """The CPU's model name (what a CPU device's speed depends on besides its driver)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def device_key(device_name: str, software: bool) -> str:
    """What a record is kept under: the Vulkan device's name, and for a CPU device (lavapipe) the CPU's model too."""
    return f"{device_name} | {cpu_model()}" if software else device_name


def crossover(rows) -> float | None:
    """The split from `tessera bench raster`'s rows (area_px, software_share, software_ms, hardware_ms): between the
    largest size the compute rasterizer won and the smallest hardware raster won after it (their geometric mean, as
    45 px lies between 32 and 64), or the largest size it won when hardware raster won none. None: nothing measured."""
    measured = sorted((row for row in rows if row["software_share"] >= MIN_SOFTWARE_SHARE), key=lambda row: row["area_px"])
    software_wins = [row["area_px"] for row in measured if row["software_ms"] < row["hardware_ms"]]
    if not measured:
        return None
    if not software_wins:
        return float(measured[0]["area_px"])  # hardware raster wins even the smallest: send it nearly everything
    largest = max(software_wins)
    after = [row["area_px"] for row in measured if row["area_px"] > largest and row["software_ms"] >= row["hardware_ms"]]
    return round(math.sqrt(largest * min(after)), 1) if after else float(largest)


def record_path(cache_directory: str | os.PathLike) -> Path:
    return Path(cache_directory) / RECORD_FILE


def _read(path: Path) -> dict:
    try:
        records = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}  # none yet, or unreadable: the default applies (a broken record is rewritten by the next --record)
    return records if isinstance(records, dict) else {}


def record(cache_directory, key: str, area: float, rows) -> Path:
    """Keeps `area` for the device `key`, with the measurement it came from; other devices' records stay."""
    path = record_path(cache_directory)
    records = _read(path)
    records[key] = {"area_px": float(area), "measured": [
        {k: row[k] for k in ("area_px", "software_share", "software_ms", "hardware_ms")} for row in rows]}
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(".tmp")
    temporary.write_text(json.dumps(records, indent=2))
    temporary.replace(path)  # whole or not at all: sessions may read it meanwhile
    return path


def for_device(cache_directory, key: str) -> tuple[float, str]:
    """The split for the device `key` and where it comes from: ("recorded", from the cache) or ("default")."""
    entry = _read(record_path(cache_directory)).get(key)
    if isinstance(entry, dict):
        area = entry.get("area_px")
        if isinstance(area, (int, float)) and math.isfinite(area) and area > 0:
            return float(area), "recorded"
    return DEFAULT_AREA, "default"
