"""A PointInstancer's arrays as they reach C++: numpy views of USD's VtArrays (no copies, no per-instance Python).

Instance i of prototype k is drawn at T(positions[i]) R(orientations[i]) S(scales[i]) in the instancer's space, for
every i with protoIndices[i] == k that the mask (invisibleIds, inactiveIds) leaves visible. The renderer composes
those transforms itself (renderer.h InstanceArrays), relative to the instancer's world origin; Python only selects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom

from tessera import _tessera


def _view(value, dtype, width: int) -> np.ndarray | None:
    """A read-only (N, width) view of a VtArray (the buffer protocol: no copy), or None when there is none."""
    if value is None:
        return None
    array = np.asarray(value)
    if array.dtype != dtype or array.ndim != 2 or array.shape[1] != width:
        array = np.asarray(array, dtype=dtype).reshape(-1, width)
    return np.ascontiguousarray(array)


@dataclass
class PointArrays:
    """What one read of an instancer gives: its arrays and, per prototype, the instances drawn."""
    positions: np.ndarray              # (N, 3) float32
    orientations: np.ndarray | None    # (N, 4) float32 (orientationsf) or float16 (orientations), i j k r
    scales: np.ndarray | None          # (N, 3) float32
    selections: list                   # per prototype: uint32 indices drawn, None for all N, or an empty array

    def instance_arrays(self, prototype: int, local: np.ndarray):
        """The C++ InstanceArrays of one prototype, its mesh at `local` (row-major, column vectors) within it."""
        orientations = self.orientations
        return _tessera.instance_arrays(
            self.positions,
            orientations=orientations if orientations is not None and orientations.dtype == np.float32 else None,
            orientations_half=orientations.view(np.uint16) if orientations is not None and orientations.dtype == np.float16 else None,
            scales=self.scales, selection=self.selections[prototype], local=[float(v) for v in np.asarray(local, np.float64).reshape(16)])

    def matrices(self, prototype: int) -> np.ndarray:
        """The selected instances' transforms (K, 4, 4) in Gf's row-vector layout, as USD computes them (scale,
        rotate, translate; the quaternion normalized): for prototypes that nest further instancing, which composes
        with matrices."""
        selection = self.selections[prototype]
        take = (lambda a: a) if selection is None else (lambda a: a[selection])
        positions = take(self.positions).astype(np.float64)
        count = len(positions)
        if self.orientations is not None:
            q = take(self.orientations).astype(np.float64)
            length = np.linalg.norm(q, axis=1, keepdims=True)
            q = np.where(length > 0, q / np.where(length > 0, length, 1), [0.0, 0.0, 0.0, 1.0])
        else:
            q = np.tile([0.0, 0.0, 0.0, 1.0], (count, 1))
        x, y, z, w = q.T
        rotation = np.stack([  # column-vector rotation; transposed below into Gf's row vectors
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)
        scales = take(self.scales).astype(np.float64) if self.scales is not None else np.ones((count, 3))
        matrices = np.zeros((count, 4, 4))
        matrices[:, :3, :3] = np.swapaxes(rotation * scales[:, None, :], 1, 2)
        matrices[:, 3, :3] = positions
        matrices[:, 3, 3] = 1.0
        return matrices

    def same_as(self, other: "PointArrays | None", prototype: int) -> bool:
        """Whether prototype `prototype` is drawn at the same places in both (a cheap vectorised compare)."""
        if other is None:
            return False
        mine, theirs = self.selections[prototype], other.selections[prototype] if prototype < len(other.selections) else []
        if (mine is None) != (theirs is None) or (mine is not None and not np.array_equal(mine, theirs)):
            return False
        return all((a is None and b is None) or (a is not None and b is not None and a.dtype == b.dtype and np.array_equal(a, b))
                   for a, b in ((self.positions, other.positions), (self.orientations, other.orientations),
                                (self.scales, other.scales)))


def read(instancer: UsdGeom.PointInstancer, prototype_count: int, time: Usd.TimeCode, warnings: list[str]) -> PointArrays | None:
    """The instancer's arrays at `time`, or None (with a warning naming it) when they cannot be used."""
    path = instancer.GetPath()
    proto_indices = instancer.GetProtoIndicesAttr().Get(time)
    if proto_indices is None or len(proto_indices) == 0:
        return None
    proto_indices = np.asarray(proto_indices)
    count = len(proto_indices)
    positions = _view(instancer.GetPositionsAttr().Get(time), np.float32, 3)
    if positions is None or len(positions) != count:
        warnings.append(f"{path}: positions and protoIndices disagree in length; the instancer is skipped")
        return None
    # orientationsf, when authored and not empty, is the float version of orientations (quath) and wins over it
    # (an empty orientationsf leaves orientations in charge, as UsdGeomPointInstancer's own transforms do).
    orientations = None
    for attribute, dtype in ((instancer.GetOrientationsfAttr(), np.float32), (instancer.GetOrientationsAttr(), np.float16)):
        if attribute.HasAuthoredValue():
            orientations = _view(attribute.Get(time), dtype, 4)
            if orientations is not None and len(orientations) > 0:
                break
    scales = _view(instancer.GetScalesAttr().Get(time), np.float32, 3) if instancer.GetScalesAttr().HasAuthoredValue() else None
    for name, array in (("orientations", orientations), ("scales", scales)):
        if array is not None and len(array) == 0:  # authored empty: USD's default (no rotation, unit scale)
            array = None
            if name == "orientations":
                orientations = None
            else:
                scales = None
        if array is not None and len(array) != count:
            warnings.append(f"{path}: {len(array)} {name} for {count} instances; the instancer is skipped")
            return None
    bad = (proto_indices < 0) | (proto_indices >= prototype_count)
    if bad.any():
        warnings.append(f"{path}: {int(bad.sum())} protoIndices out of range (0..{prototype_count - 1}); those instances are skipped")
    # Instances whose position, orientation or scale is NaN or infinite have no place to be drawn (a GPU may draw them
    # anywhere): they are left out and named, the rest drawn. A zero scale or quaternion is no error (USD's matrix
    # for it is degenerate, or the identity rotation, and so is the instance drawn).
    broken = ~np.isfinite(positions).all(axis=1)
    for array in (orientations, scales):
        if array is not None:
            broken |= ~np.isfinite(array).all(axis=1)
    if broken.any():
        which = np.flatnonzero(broken)
        listed = ", ".join(str(i) for i in which[:5]) + (", ..." if len(which) > 5 else "")
        count_text = "1 instance has" if len(which) == 1 else f"{len(which)} instances have"
        warnings.append(f"{path}: {count_text} a NaN or infinite position, orientation or scale (instance {listed}); "
                        f"{'it is' if len(which) == 1 else 'they are'} skipped")
        bad = bad | broken
    # The mask: only read element by element when invisibleIds or inactiveIds are authored.
    masked = bad
    prim = instancer.GetPrim()
    if instancer.GetInvisibleIdsAttr().HasAuthoredValue() or prim.HasMetadata("inactiveIds"):
        mask = instancer.ComputeMaskAtTime(time)
        if mask:
            masked = masked | ~np.asarray(mask, dtype=bool)
    selections = []
    if prototype_count == 1 and not masked.any():
        selections.append(None)  # the common case: every instance, no index list at all
    else:
        for index in range(prototype_count):
            chosen = np.flatnonzero((proto_indices == index) & ~masked).astype(np.uint32)
            selections.append(None if len(chosen) == count else chosen)
    return PointArrays(positions, orientations, scales, selections)
