"""Subdivision surfaces as Hydra draws them: the refine level from the render's `complexity`, and a mesh's
subdivision tags (UsdGeomMesh) as the builder takes them (`_tessera.mesh_source` keywords)."""

from __future__ import annotations

import numpy as np
from pxr import Usd

# usdview's complexity menu (Low, Medium, High, Very High; usdviewq's RefinementComplexities) and its default, Low.
USDVIEW_COMPLEXITIES = (1.0, 1.1, 1.2, 1.3)
DEFAULT_COMPLEXITY = 1.0

# Hydra's thresholds as float literals (1.0f, 1.1f, ... 1.8f): level k from 1.k up.
_THRESHOLDS = [np.float32(f"1.{k}") for k in range(9)]


def refine_level(complexity: float) -> int:
    """The uniform refine level of a complexity, Hydra's convention: UsdImagingGLEngine's `_GetRefineLevel`
    (OpenUSD, pxr/usdImaging/usdImagingGL/engine.cpp) adds 0.01 against float error (1.3 as a float is below 1.3),
    caps the sum at 2.0, and maps [1.0, 1.1) to level 0, [1.1, 1.2) to 1, ... [1.8, 2.0] to 8, in float. So 1.0, 1.1,
    1.2, 1.3 are levels 0 to 3, and anything from 1.8 up is 8. Hydra calls a complexity below 1.0 a coding error (and
    uses level 0); here it is a ValueError, as is NaN."""
    c = float(complexity)
    if not c >= 1.0:
        raise ValueError(f"complexity must be a number from 1.0 (the control cage) to 2.0, not {complexity}")
    c = min(np.float32(c) + np.float32(0.01), np.float32(2.0))
    return max(k for k, threshold in enumerate(_THRESHOLDS) if c >= threshold)


_TOKENS = {
    "interpolateBoundary": ("none", "edgeOnly", "edgeAndCorner"),
    "faceVaryingLinearInterpolation": ("none", "cornersOnly", "cornersPlus1", "cornersPlus2", "boundaries", "all"),
    "triangleSubdivisionRule": ("catmullClark", "smooth"),
}
_FALLBACKS = {"interpolateBoundary": "edgeAndCorner", "faceVaryingLinearInterpolation": "cornersPlus1",
              "triangleSubdivisionRule": "catmullClark"}
_ARRAYS = {"creaseIndices": np.int32, "creaseLengths": np.int32, "creaseSharpnesses": np.float32,
           "cornerIndices": np.int32, "cornerSharpnesses": np.float32}
# Every attribute read here: an edit of one rebuilds the mesh (change_tracker's topology attributes).
TAG_ATTRIBUTES = frozenset(_TOKENS) | frozenset(_ARRAYS)


def _keyword(attribute: str) -> str:
    return "".join("_" + ch.lower() if ch.isupper() else ch for ch in attribute)


def tags(prim: Usd.Prim, authored, time, name: str, warnings: list[str]) -> dict:
    """The mesh's authored subdivision tags as `_tessera.mesh_source` keywords (USD's fallbacks where unauthored:
    edgeAndCorner, cornersPlus1, catmullClark, no creases or corners). An unknown token is a warning naming the prim
    and the fallback is used; crease and corner arrays that do not fit together are checked, and reported, by the
    builder."""
    kwargs = {}
    for attribute, choices in _TOKENS.items():
        if attribute in authored:
            value = prim.GetAttribute(attribute).Get(time)
            if value is None:
                continue
            if value not in choices:
                warnings.append(f"{name}: {attribute} '{value}' is not one of {', '.join(choices)}; USD's fallback "
                                f"{_FALLBACKS[attribute]} is used")
                continue
            kwargs[_keyword(attribute)] = str(value)
    for attribute, dtype in _ARRAYS.items():
        if attribute in authored:
            value = prim.GetAttribute(attribute).Get(time)
            if value is not None and len(value):
                kwargs[_keyword(attribute)] = np.ascontiguousarray(np.asarray(value, dtype))
    return kwargs
