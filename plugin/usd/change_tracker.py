"""Stage edits as the render index's dirty bits (Hydra's UsdImaging change processing, reduced to what Tessera reads).

`ChangeTracker` listens to a stage's `Usd.Notice.ObjectsChanged` and keeps the paths it names until the scene
delegate applies them (`UsdSceneDelegate.apply_changes`, called before each sync). `classify` says what an edited
property dirties:

| what changed (on which prim)                                     | what is dirtied                                          |
| ---------------------------------------------------------------- | -------------------------------------------------------- |
| a prim added, removed or recomposed (a variant, a reference or   | RESYNC: its subtree walked again; prims gone are removed,|
| payload, `active`, `instanceable`, applied schemas)              | new ones inserted, those still there re-sync everything  |
| `purpose`                                                        | RESYNC (what is drawn there changes)                     |
| `visibility`                                                     | VISIBILITY: DirtyVisibility on every mesh at or under it;|
|                                                                  | its lights and instancing walked again                   |
| `xformOp:*`, `xformOpOrder`                                      | SUBTREE DirtyTransform: every mesh at or under it;       |
|                                                                  | cameras and lights there re-read (DirtyParams); copies   |
|                                                                  | it places re-made (DirtyInstancer)                        |
| `material:binding*`                                              | SUBTREE DirtyMaterialId, where the bound material changed|
| `collection:*` (collection-based bindings)                       | EVERY_MESH DirtyMaterialId, where it changed             |
| PointInstancer `positions`, `orientations(f)`, `scales`,         | INSTANCER: the instancer re-made (DirtyInstancer, meshes |
| `protoIndices`, `ids`, `invisibleIds`, `prototypes`              | of prototypes it no longer uses removed)                 |
| anything on or under a Material (shader inputs, connections)     | SPRIM DirtyParams on that material                       |
| anything on a camera or a light                                  | SPRIM DirtyParams on it                                  |
| gprim `points`, implicit shapes' `size`, `radius`                | GPRIM DirtyPoints on the meshes read from it             |
| `faceVertexCounts`, `faceVertexIndices`, `holeIndices`,          | GPRIM DirtyTopology                                      |
| `orientation`, `subdivisionScheme`, subdivision tags             |                                                          |
| (`interpolateBoundary`, `crease*`, `corner*`, ...)               |                                                          |
| `normals`, `primvars:*`                                          | GPRIM DirtyPrimvar                                       |
| `primvars:*` on another imageable prim (an Xform, a Scope)       | INHERITED_PRIMVAR DirtyPrimvar on the meshes under it    |
|                                                                  | that read that primvar (constant primvars are inherited) |
| `doubleSided`                                                    | GPRIM DirtyDoubleSided                                   |
| `tessera:*` (TesseraMeshAPI build settings)                      | GPRIM DirtyTopology (the mesh is built again)            |
| anything else (`extent`, custom attributes, prim metadata)       | nothing                                                  |

Only the points, topology, primvar and sidedness bits rebuild a mesh (through the mesh cache); a transform,
visibility, material or instancer change is read alone.
"""

from __future__ import annotations

import threading
import weakref
from typing import NamedTuple

from pxr import Tf, Usd, UsdGeom, UsdLux, UsdShade

from tessera import _tessera
from . import subdivision

_dirty = _tessera.dirty

# Scopes of an edit: which prims its bits go to (see the table above).
RESYNC = "resync"
VISIBILITY = "visibility"
SUBTREE = "subtree"
EVERY_MESH = "every mesh"
INSTANCER = "instancer"
SPRIM = "sprim"
GPRIM = "gprim"
INHERITED_PRIMVAR = "inherited primvar"


class Effect(NamedTuple):
    scope: str
    bits: int = 0


_INSTANCER_ATTRIBUTES = {"positions", "orientations", "orientationsf", "scales", "protoIndices", "ids", "invisibleIds",
                         "prototypes"}  # ids: invisibleIds name instances by id
_POINTS = {"points", "size", "radius"}  # implicit gprims' shape attributes are their points
_TOPOLOGY = {"faceVertexCounts", "faceVertexIndices", "holeIndices", "orientation", "subdivisionScheme",
             *subdivision.TAG_ATTRIBUTES}  # interpolateBoundary, creases, corners, ...


def classify(prim: Usd.Prim, name: str) -> Effect | None:
    """What an edit of property `name` on `prim` dirties; None when the render reads nothing of it."""
    if name == "visibility":
        return Effect(VISIBILITY, _dirty.VISIBILITY)
    if name == "purpose":
        return Effect(RESYNC, _dirty.ALL)
    if name.startswith("xformOp:") or name == "xformOpOrder":
        return Effect(SUBTREE, _dirty.TRANSFORM)
    if name.startswith("material:binding"):
        return Effect(SUBTREE, _dirty.MATERIAL_ID)
    if name.startswith("collection:"):
        return Effect(EVERY_MESH, _dirty.MATERIAL_ID)
    if prim.IsA(UsdGeom.PointInstancer):
        return Effect(INSTANCER, _dirty.INSTANCER) if name in _INSTANCER_ATTRIBUTES else None
    if prim.IsA(UsdShade.Material) or prim.IsA(UsdShade.Shader) or prim.IsA(UsdShade.NodeGraph):
        return Effect(SPRIM, _dirty.PARAMS)
    if prim.IsA(UsdGeom.Camera) or prim.HasAPI(UsdLux.LightAPI):
        return Effect(SPRIM, _dirty.PARAMS)
    if prim.IsA(UsdGeom.Gprim):
        if name in _POINTS:
            return Effect(GPRIM, _dirty.POINTS)
        if name in _TOPOLOGY or name.startswith("tessera:"):
            return Effect(GPRIM, _dirty.TOPOLOGY)
        if name == "normals" or name.startswith("primvars:"):
            return Effect(GPRIM, _dirty.PRIMVAR)
        if name == "doubleSided":
            return Effect(GPRIM, _dirty.DOUBLE_SIDED)
    elif name.startswith("primvars:") and prim.IsA(UsdGeom.Imageable):
        return Effect(INHERITED_PRIMVAR, _dirty.PRIMVAR)  # a constant primvar the meshes below may inherit
    return None


class ChangeTracker:
    """Collects the paths a stage's change notices name, until `take()` hands them over. Notices arrive on the thread
    that edits the stage, which may not be the one that renders: recording and taking hold a lock."""

    def __init__(self, stage: Usd.Stage):
        self.resynced: set[str] = set()  # prim paths whose subtree was recomposed
        self.changed: dict[str, set[str]] = {}  # prim path -> names of properties whose value changed
        self._lock = threading.Lock()
        me = weakref.ref(self)  # the listener must not keep the tracker alive

        def on_change(notice, sender):
            tracker = me()
            if tracker is not None:
                with tracker._lock:
                    tracker._record(notice)

        self._on_change = on_change  # Tf holds its callbacks weakly
        self._listener = Tf.Notice.Register(Usd.Notice.ObjectsChanged, on_change, stage)

    def _record(self, notice) -> None:
        for path in notice.GetResyncedPaths():
            if path.IsPropertyPath():  # a property created or removed: its value changed
                self.changed.setdefault(str(path.GetPrimPath()), set()).add(path.name)
            else:
                self.resynced.add(str(path))
        for path in notice.GetChangedInfoOnlyPaths():
            # Prim metadata that matters (active, instanceable, composition arcs, applied schemas) arrives as a resync.
            if path.IsPropertyPath():
                self.changed.setdefault(str(path.GetPrimPath()), set()).add(path.name)

    def take(self) -> tuple[set[str], dict[str, set[str]]]:
        """The edits since the last take: (resynced prim paths, {prim path: changed property names})."""
        with self._lock:
            resynced, changed = self.resynced, self.changed
            self.resynced, self.changed = set(), {}
        return resynced, changed

    def close(self) -> None:
        self._listener.Revoke()
