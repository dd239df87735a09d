"""Image comparison for image tests, with the semantics of OpenImageIO's idiff as OpenUSD's testenv uses it.

A pixel *fails* when any channel differs from the baseline by more than `fail`; the test fails when more than
`fail_percent` of the pixels fail. `warn` / `warn_percent` report smaller drifts without failing. Set
TESSERA_UPDATE_BASELINES=1 to (re)write baselines from the current renders instead of comparing.
"""

from __future__ import annotations

import os
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import tessera


@dataclass
class Comparison:
    failing_percent: float
    warning_percent: float
    max_difference: float
    mean_difference: float

    def __str__(self) -> str:
        return (f"{self.failing_percent:.3f}% of pixels over the fail threshold, {self.warning_percent:.3f}% over the warn "
                f"threshold, max difference {self.max_difference:.4f}, mean {self.mean_difference:.5f}")


def compare_arrays(result: np.ndarray, baseline: np.ndarray, fail: float, warn: float) -> Comparison:
    if result.shape != baseline.shape:
        raise AssertionError(f"image size {result.shape[:2]} differs from the baseline's {baseline.shape[:2]}")
    difference = np.abs(result.astype(np.float64) - baseline.astype(np.float64)).max(axis=-1)
    return Comparison(100.0 * float((difference > fail).mean()), 100.0 * float((difference > warn).mean()),
                      float(difference.max()), float(difference.mean()))


def assert_matches_baseline(image_path: Path, baseline_path: Path, *, fail: float = 0.02, fail_percent: float = 0.5,
                            warn: float = 0.004, warn_percent: float = 1.0) -> Comparison:
    update = os.environ.get("TESSERA_UPDATE_BASELINES", "0")
    if update not in ("0", "1"):  # "true" would otherwise compare, silently
        raise ValueError(f"TESSERA_UPDATE_BASELINES='{update}': expected 1 (write the baselines) or 0 (compare)")
    if update == "1":
        baseline_path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(image_path, baseline_path)
    if not baseline_path.exists():
        raise AssertionError(f"no baseline {baseline_path}; render one with TESSERA_UPDATE_BASELINES=1 and review it")
    comparison = compare_arrays(tessera.read_image(str(image_path)), tessera.read_image(str(baseline_path)), fail, warn)
    if comparison.failing_percent > fail_percent:
        raise AssertionError(f"{image_path.name} does not match {baseline_path}: {comparison}")
    if comparison.warning_percent > warn_percent:
        warnings.warn(f"{image_path.name} drifts from its baseline: {comparison}")
    return comparison


def coverage_mask(rgba: np.ndarray, background_rgb=None, tolerance: float = 0.06) -> np.ndarray:
    """Pixels covered by geometry: by alpha when the image has it, else those far from a background colour."""
    if background_rgb is None:
        return rgba[..., 3] > 0.5
    return np.abs(rgba[..., :3] - np.asarray(background_rgb)).max(axis=-1) > tolerance


def intersection_over_union(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def colour_class(rgb: np.ndarray, *, dark: float = 0.04, grey: float = 0.2) -> tuple[str, float]:
    """What a region's colour is, in terms that survive a change of lights and of encoding (linear or sRGB):
    ("dark", 0) when its median pixel is near black, ("grey", 0) when unsaturated, else ("hue", degrees).
    The median keeps Storm's wireframe lines and specular highlights from swaying it."""
    r, g, b = np.median(rgb.reshape(-1, 3), axis=0)
    high, low = max(r, g, b), min(r, g, b)
    if high < dark:
        return "dark", 0.0
    if (high - low) / high < grey:
        return "grey", 0.0
    if high == r:
        hue = 60.0 * (((g - b) / (high - low)) % 6.0)
    elif high == g:
        hue = 60.0 * ((b - r) / (high - low) + 2.0)
    else:
        hue = 60.0 * ((r - g) / (high - low) + 4.0)
    return "hue", float(hue)


def same_colour(a: tuple[str, float], b: tuple[str, float], hue_tolerance: float = 45.0) -> bool:
    """Same class, and hues within `hue_tolerance` degrees: primaries and secondaries are 60 degrees apart, and
    Tessera's dome light tints a saturated colour by up to ~35 degrees."""
    if a[0] != b[0]:
        return False
    difference = abs(a[1] - b[1]) % 360.0
    return min(difference, 360.0 - difference) <= hue_tolerance
