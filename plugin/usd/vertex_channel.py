"""The mesh's vertex channel: the primvars its materials' UsdPrimvarReaders read (or the fallback surface's
displayColor), packed into the one per-vertex stream the builder carries (4 components, rgba16f on the GPU), whose
components the material maps to inputs (MaterialDesc.vertex_inputs).

A mesh pays for it only when a reader finds a primvar that varies over it: when every primvar read is constant, or
missing (the reader's fallback), the channel is one constant and the render index folds it into a copy of the material.
"""

from __future__ import annotations

import numpy as np

_EXPECTED = {"vertex": 0, "varying": 0, "uniform": 1, "faceVarying": 2}  # which count an interpolation needs (below)


def pack(reads, found, topology, name: str, warnings: list[str]):
    """(values, interpolation, indices, components) for MeshSource's display_color from `reads` (materials.ChannelRead)
    and what was `found` for each ((values, interpolation, indices) or None). One primvar as authored keeps its
    interpolation and indices; several of one interpolation and indexing are put side by side; several of different
    ones are expanded to face-varying. `topology`: (point count, faceVertexCounts, faceVertexIndices), or None to take
    each primvar's first element (an implicit shape). (None, "constant", None, 3) when there is nothing to read."""
    width = max(r.offset + r.components for r in reads)
    components = 3 if width <= 3 else 4
    columns = []  # per read: (values, interpolation, indices), or a constant row
    for read, got in zip(reads, found):
        if got is not None and topology is not None and got[1] != "constant":
            got = _checked(got, read, topology, name, warnings)
        if got is None:
            if read.fallback is None:  # the fallback surface without displayColor: no channel, Hydra's grey
                return None, "constant", None, 3
            columns.append((np.asarray(read.fallback, np.float32)[None, :], "constant", None))
        elif got[1] == "constant" or topology is None:
            values, _, indices = got
            first = values[indices[0]] if indices is not None and len(indices) and 0 <= indices[0] < len(values) else values[0]
            columns.append((first[None, :], "constant", None))
        else:
            columns.append(got)
    varying = [c for c in columns if c[1] != "constant"]
    if not varying:
        return _side_by_side(reads, [c[0] for c in columns], 1, components), "constant", None, components
    first = varying[0]
    if len(varying) == 1 or all(c[1] == first[1] and _same_indices(c[2], first[2]) and len(c[0]) == len(first[0]) for c in varying):
        count = len(first[0])
        values = [c[0] if c[1] != "constant" else np.broadcast_to(c[0], (count, c[0].shape[1])) for c in columns]
        return _side_by_side(reads, values, count, components), first[1], first[2], components
    # Different interpolations or indexings: one value per face corner each.
    _, counts, face_vertex_indices = topology
    corners = len(face_vertex_indices)
    values = [_face_varying(c, counts, face_vertex_indices) if c[1] != "constant" else np.broadcast_to(c[0], (corners, c[0].shape[1]))
              for c in columns]
    return _side_by_side(reads, values, corners, components), "faceVarying", None, components


def _side_by_side(reads, values, count: int, components: int):
    out = np.zeros((count, components), np.float32)
    if components == 4:
        out[:, 3] = 1.0  # unused components as a displayColor's alpha
    for read, v in zip(reads, values):
        out[:, read.offset:read.offset + read.components] = v
    return np.ascontiguousarray(out.reshape(-1))


def _same_indices(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def _checked(got, read, topology, name: str, warnings: list[str]):
    """The primvar if its elements fit its interpolation over the mesh, else None with a warning naming it."""
    values, interpolation, indices = got
    point_count, counts, face_vertex_indices = topology
    if interpolation not in _EXPECTED:
        warnings.append(f"{name}: primvars:{read.primvar} has interpolation '{interpolation}'; ignored")
        return None
    needed = (point_count, len(counts), len(face_vertex_indices))[_EXPECTED[interpolation]]
    available = len(indices) if indices is not None else len(values)
    if available < needed:
        warnings.append(f"{name}: primvars:{read.primvar} has {available} elements but its interpolation ({interpolation}) needs "
                        f"{needed}; the reader's fallback is used")
        return None
    if indices is not None and len(indices) and (indices.min() < 0 or indices.max() >= len(values)):
        warnings.append(f"{name}: primvars:{read.primvar} has an index outside its {len(values)} values; the reader's fallback is used")
        return None
    if indices is not None:  # the builder reads only as many slots as the interpolation needs
        indices = np.ascontiguousarray(indices[:needed])
    else:
        values = values[:needed]
    return values, interpolation, indices


def _face_varying(column, counts, face_vertex_indices):
    values, interpolation, indices = column
    if indices is not None:
        values = values[indices]
    if interpolation == "faceVarying":
        return values
    if interpolation == "uniform":
        return np.repeat(values, np.asarray(counts, np.int64), axis=0)
    points = np.clip(np.asarray(face_vertex_indices, np.int64), 0, len(values) - 1)  # bad faces are the builder's to drop
    return values[points]
