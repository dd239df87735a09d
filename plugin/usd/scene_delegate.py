"""The USD scene delegate: reads a stage through usd-core and answers the render index's questions.

Populate walks the stage and inserts prims into the render index: every drawable gprim becomes a "mesh" rprim
(hidden ones too: they sync only their visibility until they show); native instances and PointInstancers become
*one* rprim per prototype mesh whose instance transforms are composed here (nesting included), so a prototype is
built once however many copies it has. Sync later pulls data through the get_* methods; arrays come out of USD as
numpy views, without copies.

Edits: `apply_changes` takes what the stage's change notices named (change_tracker.py) and dirties only that: a
property edit becomes dirty bits on the prims that read it; a recomposed subtree is walked again and the index made
to match it. Instancing is kept in *groups* (one per native prototype, one per top-level PointInstancer) whose
rprims are re-made together when anything they read changes. `set_time` does the same for every time-varying
attribute.

Matrices handed to C++ are row-major and act on column vectors: the transpose of Gf's row-vector layout.
"""

from __future__ import annotations

import gc
from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Tf, Usd, UsdGeom, UsdLux, UsdShade

from tessera import _tessera
from . import change_tracker, implicit, lights, materials, mesh_settings, point_instancer, subdivision, vertex_channel
from .path_index import PathIndex, ancestors, is_at_or_under

_dirty = _tessera.dirty
_LIGHT_TYPES = lights.SPRIM_TYPES
_PROTOTYPE_PREDICATE = Usd.PrimIsActive & Usd.PrimIsLoaded & ~Usd.PrimIsAbstract  # PointInstancer prototypes: `over` too
# Bindings are resolved for the preview purpose, as Storm resolves them: a `preview` binding wins, else the
# all-purpose one (UsdShade's fallback); `full` bindings are for final-quality renderers.
_MATERIAL_PURPOSE = UsdShade.Tokens.preview


def to_column_major(gf_matrix: Gf.Matrix4d) -> list[float]:
    """Gf (row vectors) -> the C++ convention (row-major, column vectors). Once per mesh on a first sync: Gf's transpose
    read through its buffer by numpy (0.5 us; a memoryview cast to doubles unpacks each item alone, 0.9 us, and
    numpy's view, transpose and copy cost more still)."""
    return np.frombuffer(gf_matrix.GetTranspose()).tolist()


@dataclass(slots=True)  # one per rprim: 100 k of them on big stages
class _Rprim:
    prim: Usd.Prim
    # For instanced rprims: the frames of its copies (C, 4, 4), in the C++ convention: each copy's world transform,
    # or, with `points`, the world transform of a PointInstancer whose instances of prototype `prototype` are drawn
    # in it (the arrays stay USD's; `local` places the mesh within the prototype, C++ convention).
    frames: np.ndarray | None = None
    points: point_instancer.PointArrays | None = None
    prototype: int = 0
    local: np.ndarray | None = None
    group: str | None = None  # key of the instancing group that made it; None for a gprim drawn once (id = path)
    instancer_id: str = ""
    material: str = ""  # the bound material's path, "" for none
    subdivided: bool = False  # read with a subdivision scheme other than none: a new refine level rebuilds it
    # Inside a native prototype: the instance proxy path whose binding it draws with (one instance of those it draws,
    # all of which resolve alike: _instance_binding_key), so bindings on or above the instance reach it; None: its own.
    binding: str | None = None
    subset_materials: tuple = ()  # the materials of its materialBind GeomSubsets (slots 1, 2, ...), "" for the mesh's own
    # What the last walk found (None once read): the first sync after a walk need not ask USD again.
    walked_visible: bool | None = None
    walked_authored: _AuthoredNames | None = None


@dataclass
class _Group:
    """One top-level instancing context: a native prototype and its instances, or a PointInstancer."""
    kind: str  # "native" (key: the prototype's path) or "pointInstancer" (key: the instancer's path)
    anchors: dict[str, None] = field(default_factory=dict)  # the instance prims (stage order), or the instancer
    rprims: set[str] = field(default_factory=set)
    watched: set[str] = field(default_factory=set)  # prims whose subtrees it read
    # Native: the instances' world transforms (N, 4, 4, row vectors) in `order`, kept so that an edit re-reads only
    # the instances it moved.
    copies: np.ndarray | None = None
    order: list[str] = field(default_factory=list)
    # Native: each instance's binding key (_instance_binding_key), kept until an edit at or above the instance.
    binding_keys: dict[str, tuple] = field(default_factory=dict)
    # Native: each instance's purpose (what its prototype's prims inherit), as the walk that found it computed it.
    purposes: dict[str, str] = field(default_factory=dict)


class _AuthoredNames(frozenset):
    """A mesh's authored property names, one shared object per distinct set (100 k meshes that author the same
    names hold one), with what the mesh reader asks of them worked out once."""

    __slots__ = ("tessera", "plain")

    # Read by name when authored; anything else a mesh reader reads (normals, primvars, holes) makes it not plain.
    _PLAIN = frozenset({"points", "faceVertexCounts", "faceVertexIndices", "subdivisionScheme", "orientation",
                        "doubleSided"})
    _OTHER_READS = ("normals", "primvars:", "holeIndices", *sorted(subdivision.TAG_ATTRIBUTES))

    def __new__(cls, names):
        self = super().__new__(cls, names)
        self.tessera = any(name.startswith("tessera:") for name in names)  # TesseraMeshAPI settings authored
        self.plain = not any(name.startswith(cls._OTHER_READS) for name in names)
        return self


class _Purposes:
    """Computed purposes along a depth-first walk, by UsdGeom's rule: a prim's authored purpose, else its nearest
    ancestor's (`inherited` above the walk's root)."""

    def __init__(self, inherited: str = UsdGeom.Tokens.default_):
        self.inherited = inherited
        # (path, purpose) of the ancestors that author one, outermost first; while empty, a prim that authors no
        # purpose has `inherited` (the walk then need not call `of`).
        self.authored: list[tuple] = []

    def of(self, prim: Usd.Prim, path, authored=None) -> str:
        """`authored`: the prim's authored property names, when known (purpose is then read only where authored)."""
        while self.authored and not path.HasPrefix(self.authored[-1][0]):
            self.authored.pop()
        if authored is None or "purpose" in authored:
            attribute = UsdGeom.Imageable(prim).GetPurposeAttr()
            if attribute.HasAuthoredValue():
                self.authored.append((path, attribute.Get()))
                return self.authored[-1][1]
        return self.authored[-1][1] if self.authored else self.inherited


_UNKNOWN = object()  # a world transform the walk could not compute (USD rejected an ancestor's ops)
_NO_TRANSFORM = Gf.Matrix4d(1.0)  # a place holder where no transform is handed over


class _WorldTransforms:
    """World transforms along a depth-first walk, by UsdGeom's rule (a prim's local transform times its parent's
    world, unless its xformOpOrder resets the stack). Only prims that author xformOpOrder have a local transform
    other than the identity, so only those are read, each once: a mesh's world transform then costs no USD call of
    its own, where an XformCache look-up per mesh cost ~10 us and kept ~450 bytes per prim it passed."""

    # Local transforms are read through an XformCache, emptied now and then: its entries are never asked for again.
    _CLEAR_EVERY = 1024

    _IDENTITY = Gf.Matrix4d(1.0)

    def __init__(self, parent_world, time: Usd.TimeCode):
        # (path, world) of the ancestors that author ops, outermost first, above the walk's parent world (None when
        # the identity: a product with it is skipped).
        identity = parent_world is not _UNKNOWN and parent_world == self._IDENTITY
        self._stack: list[tuple] = [(None, None if identity else parent_world)]
        self._cache = UsdGeom.XformCache(time)
        self._reads = 0

    def _parent(self, path) -> Gf.Matrix4d | None:
        stack = self._stack
        while len(stack) > 1 and not path.HasPrefix(stack[-1][0]):
            stack.pop()
        return stack[-1][1]

    def enter(self, prim: Usd.Prim, path) -> Gf.Matrix4d | None:
        """A prim that authors xformOpOrder (and is Xformable): its world transform, noted for its subtree. None when
        USD rejects its ops (a scale op of one double, say): below it, nothing is known, and the meshes' syncs read
        their transforms through USD, which names the prim and skips it as before."""
        parent = self._parent(path)
        try:
            local, resets = self._cache.GetLocalTransformation(prim)
        except Tf.ErrorException:
            self._stack.append((path, _UNKNOWN))
            return None
        self._reads += 1
        if self._reads % self._CLEAR_EVERY == 0:
            self._cache.Clear()
        if parent is _UNKNOWN and not resets:
            world = _UNKNOWN
        else:
            world = local if resets or parent is None else local * parent
        self._stack.append((path, world))
        return None if world is _UNKNOWN else world

    def world(self, path) -> Gf.Matrix4d | None:
        """The world transform of a prim that authors no ops (its nearest ancestor's that does), None if unknown."""
        world = self._parent(path)
        return self._IDENTITY if world is None else None if world is _UNKNOWN else world


def inherited_purpose(prim: Usd.Prim) -> str:
    """The purpose a prim's children inherit from it and its ancestors."""
    while prim and not prim.IsPseudoRoot():
        imageable = UsdGeom.Imageable(prim)
        if imageable:
            return imageable.ComputePurpose()
        prim = prim.GetParent()
    return UsdGeom.Tokens.default_


@dataclass
class _Found:
    """What a walk of part of the stage found outside instancing contexts."""
    rprims: dict[str, Usd.Prim] = field(default_factory=dict)
    hidden: set[str] = field(default_factory=set)  # rprims found under (or at) an invisible prim
    authored: dict[str, _AuthoredNames] = field(default_factory=dict)  # rprim -> its authored property names
    worlds: dict[str, Gf.Matrix4d] = field(default_factory=dict)  # rprim -> its world transform
    sprims: dict[str, str] = field(default_factory=dict)  # cameras and lights: path -> type
    natives: dict[str, list[str]] = field(default_factory=dict)  # prototype path -> instance prim paths
    # Instance prim path -> its purpose, which its prototype's prims inherit unless they author their own.
    instance_purposes: dict[str, str] = field(default_factory=dict)
    instancers: list[str] = field(default_factory=list)


class UsdSceneDelegate(_tessera.SceneDelegate):
    def __init__(self, stage: Usd.Stage, render_index, time: Usd.TimeCode = Usd.TimeCode.Default(),
                 complexity: float = subdivision.DEFAULT_COMPLEXITY, build_settings: _tessera.BuildSettings | None = None,
                 purposes=(UsdGeom.Tokens.render,)):
        super().__init__()
        # Geometry of these purposes is drawn, besides `default` (Hydra's render tags); the others' is not read.
        self.purposes = {UsdGeom.Tokens.default_, *purposes}
        # Uniform refinements of subdivision surfaces (catmullClark, loop, bilinear), from the render's complexity.
        self.complexity = float(complexity)
        self.refine_level = subdivision.refine_level(complexity)
        # The render-wide build settings; a mesh's authored TesseraMeshAPI attributes override them (mesh_settings.py).
        self.build_settings = build_settings or _tessera.BuildSettings()
        self._mesh_settings = mesh_settings.SettingsReader()
        self.stage = stage
        self.index = render_index
        self.time = time
        self.xform_cache = UsdGeom.XformCache(time)
        self.rprims: dict[str, _Rprim] = {}
        self.sprims: dict[str, str] = {}  # id (the prim's path) -> type: cameras, lights and bound materials
        self.groups: dict[str, _Group] = {}
        self.cameras: list[str] = []  # in stage order; the first is the default camera
        self.lights: list[str] = []
        self.warnings: list[str] = []
        self.errors: list[str] = []  # prims left out for what is wrong with the stage (an instancer cycle)
        self._instancer_chain: list[str] = []  # the PointInstancers being visited, outermost first (cycles)
        self.instancer_cycles: set[str] = set()  # PointInstancers found in a cycle (bounds must not follow them)
        self._composition_errors: set[str] = set()  # reported already
        self._paths = PathIndex()  # prim path -> ids of the rprims and sprims read from that prim
        self._watch = PathIndex()  # prim path -> keys of the instancing groups that read its subtree
        self._material_users: dict[str, set[str]] = {}  # material path -> ids of the rprims bound to it
        self._time_varying: dict[str, set[str]] | None = None  # prim path -> time-varying attributes (on first need)
        self._kinds: dict[str, tuple[bool, str | None, bool]] = {}  # prim type name -> (imageable, role, xformable)
        self._authored_sets: dict[tuple, _AuthoredNames] = {}  # one shared set per distinct list of names
        # World transforms (row vectors) of gprims drawn once that a walk computed and no sync has used yet.
        self._walked_worlds: dict[str, Gf.Matrix4d] = {}
        # What each material needs its meshes to read (materials.PrimvarNeeds): 100 k meshes bound to one material read
        # its network once. An edit of the material that changes it dirties the meshes' primvars (_renew_needs).
        self._needs: dict[str, materials.PrimvarNeeds] = {}
        # Some prim that is not a mesh authors primvars:displayColor: the fallback surface's meshes look for an inherited
        # one (UsdImaging's constant primvar inheritance). Until then, no ancestor walk per mesh.
        self._inherited_display_color = False
        self._all_uvs = False  # read_all_uvs(): every mesh reads its st, textured or not (the `uv` debug view)

    @property
    def materials(self) -> set[str]:
        return set(self._material_users)

    # -- populate ---------------------------------------------------------------------------------

    def populate(self) -> None:
        self._report_composition_errors()
        # The walk makes a few objects per prim, all kept: the cyclic garbage collector would scan them again and again
        # as they accumulate (a measured 6 % of translating 100 k prims). It runs again afterwards.
        collecting = gc.isenabled()
        gc.disable()
        try:
            self._repopulate("/", _dirty.ALL)
        finally:
            if collecting:
                gc.enable()

    def _report_composition_errors(self) -> None:
        """USD's composition errors (a payload, reference or sublayer whose asset cannot be opened, ...) as warnings
        naming the asset and the prim that introduced it, each once; the prim composes without it."""
        for error in self.stage.GetCompositionErrors():
            text = str(error).strip()
            if text in self._composition_errors:
                continue
            self._composition_errors.add(text)
            site = getattr(error, "rootSite", None)
            where = str(site.path) if site is not None and hasattr(site, "path") else "stage"
            self.warnings.append(f"{where}: {text[:1].lower()}{text[1:].rstrip('.')}; the prim is read without it")

    def _relative(self, prim: Usd.Prim, frame: Usd.Prim | None) -> np.ndarray:
        if frame is None:
            return np.asarray(self.xform_cache.GetLocalToWorldTransform(prim))
        matrix, _ = self.xform_cache.ComputeRelativeTransform(prim, frame)
        return np.asarray(matrix)

    def _walk(self, root: Usd.Prim, hidden: bool, found: _Found) -> None:
        """Walks `root`'s subtree outside instancing. `hidden`: an ancestor of `root` is invisible. Gprims under an
        invisible prim are still found (they sync their visibility alone); lights and instancing there are not.
        Geometry and instancing of a purpose not rendered is not read (its descendants may author another purpose);
        cameras and lights are used whatever their purpose, as Hydra's render tags apply to geometry."""
        hidden_under = root.GetPath() if hidden else None
        at_top = root.IsPseudoRoot()
        purposes = _Purposes(inherited_purpose(root.GetParent()) if not at_top else UsdGeom.Tokens.default_)
        parent_world = Gf.Matrix4d(1.0)
        if not at_top:
            try:
                parent_world = self.xform_cache.GetLocalToWorldTransform(root.GetParent())
            except Tf.ErrorException:  # ops USD rejects above: the meshes' syncs read (and report) their transforms
                parent_world = _UNKNOWN
        worlds = _WorldTransforms(parent_world, self.time)
        # Without prototypes there are no instances: the per-prim instance test is skipped.
        may_instance = bool(self.stage.GetPrototypes())
        kinds, drawn_purposes, authored_sets = self._kinds, self.purposes, self._authored_sets
        it = iter(Usd.PrimRange(root))
        if at_top:
            next(it)
        for prim in it:
            path = prim.GetPath()
            if hidden_under is not None and not path.HasPrefix(hidden_under):
                hidden_under = None
            imageable, role, xformable = kinds.get(prim.GetTypeName()) or self._kind(prim)
            authored = world = None
            entered = False
            instance = may_instance and prim.IsInstance()
            drawn = True
            purpose = None
            if imageable:
                # One call lists what the prim authors; purpose and visibility are read only where authored (their
                # fallbacks are inherited): three times faster than reading both on every prim.
                authored = prim.GetAuthoredPropertyNames()
                purpose = purposes.of(prim, path, authored) if "purpose" in authored or purposes.authored else purposes.inherited
                drawn = purpose in drawn_purposes
                if hidden_under is None and "visibility" in authored and \
                        prim.GetAttribute("visibility").Get(self.time) == UsdGeom.Tokens.invisible:
                    hidden_under = path
                # Instances and PointInstancers place their copies themselves (_visit): the walk stops there.
                entered = xformable and "xformOpOrder" in authored and not instance and role != "pointInstancer"
                if entered:
                    world = worlds.enter(prim, path)
                if role != "mesh" and "primvars:displayColor" in authored:
                    self._inherited_display_color = True
            if instance:  # also a PointInstancer prototype root that is itself instanceable
                # An instance of a purpose not drawn is kept, as UsdImaging keeps it: its prototype's prims inherit that
                # purpose (and are not drawn) unless they author one that is drawn. Visibility has no such exception.
                if hidden_under is None:
                    found.natives.setdefault(str(prim.GetPrototype().GetPath()), []).append(str(path))
                    found.instance_purposes[str(path)] = purpose if purpose is not None else \
                        purposes.of(prim, path, ()) if purposes.authored else purposes.inherited
                it.PruneChildren()
                continue
            if role is None:
                continue
            if role == "mesh" and drawn:
                key = str(path)
                found.rprims[key] = prim
                names = authored_sets.get(tuple(authored))
                found.authored[key] = names if names is not None else self._authored_names(authored)
                if world is None and not entered:
                    world = worlds.world(path)
                if world is not None:
                    found.worlds[key] = world
                if hidden_under is not None:
                    found.hidden.add(key)
            elif role == "pointInstancer":
                if hidden_under is None and drawn:
                    found.instancers.append(str(path))
                it.PruneChildren()
            elif role == "camera":  # visibility does not apply to looking through a camera
                found.sprims[str(path)] = "camera"
            elif role in _LIGHT_TYPES:
                if hidden_under is None:
                    found.sprims[str(path)] = role
            elif not drawn:
                continue  # geometry of a purpose not rendered: not read
            elif role != "mesh":
                self.warnings.append(f"{path}: {prim.GetTypeName()} is not drawn (not supported yet)")

    def _kind(self, prim: Usd.Prim) -> tuple[bool, str | None, bool]:
        """(imageable, role, xformable) of a prim's type, found once per type name (IsA depends on the type alone).
        Roles: pointInstancer, camera, the light sprim types, mesh (drawn), unsupported (a gprim or light not drawn),
        None."""
        type_name = prim.GetTypeName()
        kind = self._kinds.get(type_name)
        if kind is None:
            role = None
            if prim.IsA(UsdGeom.PointInstancer):
                role = "pointInstancer"
            elif prim.IsA(UsdGeom.Camera):
                role = "camera"
            elif lights.sprim_type(prim):
                role = lights.sprim_type(prim)
            elif prim.HasAPI(UsdLux.LightAPI):
                role = "unsupported"  # disk, cylinder, portal and geometry lights
            elif prim.IsA(UsdGeom.Gprim):
                role = "mesh" if prim.IsA(UsdGeom.Mesh) or implicit.supported(prim) else "unsupported"
            kind = self._kinds[type_name] = (prim.IsA(UsdGeom.Imageable), role, prim.IsA(UsdGeom.Xformable))
        return kind

    def _visit(self, root: Usd.Prim, copies: np.ndarray, frame: Usd.Prim | None, context: str,
               records: dict[str, _Rprim], watched: set[str], points: tuple | None = None,
               proxy: tuple[str, str] | None = None, purpose: str | None = None) -> None:
        """Walks an instanced subtree. `copies` (N, 4, 4) are the world transforms of `frame` (row vectors);
        transforms inside are taken relative to `frame` (`root` itself when None). `context` names this copy set
        uniquely (it becomes the instancer id); the rprims made go into `records`, the prims read into `watched`.
        `points`: (PointArrays, prototype index) when `root` is a PointInstancer prototype: `copies` are then the
        instancer's world transforms and its arrays place the prototype's instances in them, kept as arrays.
        `proxy`: (prototype path, instance path) when `root` is in a native prototype: prims under the prototype path
        resolve their material bindings as the instance proxies under the instance path (that instance's bindings on
        and above it count, as UsdShade resolves them through instance proxies). `purpose`: what prims inside inherit
        where they author none (a native instance's purpose); None: what `root`'s parent passes down."""
        if frame is None:
            frame = root

        def proxy_path(prim: Usd.Prim) -> str | None:
            if proxy is None:
                return None
            path, (prefix, instance) = str(prim.GetPath()), proxy
            return instance + path[len(prefix):] if is_at_or_under(path, prefix) else None
        # A PointInstancer's prototypes are drawn even when defined under an `over` (a common way to keep them out of
        # ordinary traversals), as UsdImaging does: its prototype walk does not ask for defined prims.
        it = iter(Usd.PrimRange(root, _PROTOTYPE_PREDICATE) if points is not None else Usd.PrimRange(root))
        purposes = _Purposes(purpose if purpose is not None else
                             inherited_purpose(root.GetParent()) if root.GetParent() else UsdGeom.Tokens.default_)
        for prim in it:
            self._kind(prim)  # notes its type (_stage_has)
            imageable = UsdGeom.Imageable(prim)
            if imageable:
                if imageable.GetVisibilityAttr().Get(self.time) == UsdGeom.Tokens.invisible:
                    it.PruneChildren()
                    continue
                # A nested native instance of a purpose not drawn goes on: its prototype's prims may author one.
                if purposes.of(prim, prim.GetPath()) not in self.purposes and not prim.IsInstance():
                    if prim.IsA(UsdGeom.PointInstancer):
                        it.PruneChildren()
                    continue  # not read; its descendants may author a purpose that is drawn
            if points is not None and (prim.IsInstance() or prim.IsA(UsdGeom.PointInstancer)):
                # Nesting under a PointInstancer's instances composes as matrices: expand its arrays here.
                arrays, index = points
                copies = (arrays.matrices(index)[:, None] @ copies[None]).reshape(-1, 4, 4)
                points = None
            if prim.IsInstance():  # a nested native instance: its own context, one per encounter
                prototype = prim.GetPrototype()
                watched.add(str(prototype.GetPath()))
                world = self._relative(prim, frame)
                inner = (str(prototype.GetPath()), proxy_path(prim) or str(prim.GetPath()))
                self._visit(prototype, world[None] @ copies, None, f"{context};{prim.GetPath()}", records, watched,
                            proxy=inner, purpose=purposes.of(prim, prim.GetPath(), ()))
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.PointInstancer):
                self._visit_point_instancer(UsdGeom.PointInstancer(prim), copies, frame, f"{context};{prim.GetPath()}",
                                            records, watched, proxy)
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.Gprim):
                if not (prim.IsA(UsdGeom.Mesh) or implicit.supported(prim)):
                    self.warnings.append(f"{prim.GetPath()}: {prim.GetTypeName()} is not drawn (not supported yet)")
                    continue
                local = self._relative(prim, frame)
                id = f"{prim.GetPath()}{{{context}}}"
                if points is None:
                    records[id] = _Rprim(prim, np.ascontiguousarray(np.swapaxes(local[None] @ copies, 1, 2)), instancer_id=context)
                else:
                    records[id] = _Rprim(prim, np.ascontiguousarray(np.swapaxes(copies, 1, 2)), points=points[0], prototype=points[1],
                                         local=np.ascontiguousarray(local.T), instancer_id=context)
                records[id].binding = proxy_path(prim)

    def _visit_point_instancer(self, instancer: UsdGeom.PointInstancer, copies: np.ndarray | None, frame: Usd.Prim | None,
                               context: str, records: dict[str, _Rprim], watched: set[str],
                               proxy: tuple[str, str] | None = None) -> None:
        prim = instancer.GetPrim()
        path = prim.GetPath()
        if str(path) in self._instancer_chain:  # a prototype instances an instancer that instances it: no end
            chain = self._instancer_chain[self._instancer_chain.index(str(path)):] + [str(path)]
            self.instancer_cycles.update(chain)
            message = f"{path}: PointInstancer cycle ({' -> '.join(chain)}); the copies inside the cycle are skipped"
            if message not in self.errors:
                self.errors.append(message)
            return
        self._instancer_chain.append(str(path))
        try:
            self._visit_point_instancer_body(instancer, copies, frame, context, records, watched, proxy)
        finally:
            self._instancer_chain.pop()

    def _visit_point_instancer_body(self, instancer: UsdGeom.PointInstancer, copies: np.ndarray | None, frame: Usd.Prim | None,
                                    context: str, records: dict[str, _Rprim], watched: set[str],
                                    proxy: tuple[str, str] | None) -> None:
        prim = instancer.GetPrim()
        path = prim.GetPath()
        watched.add(str(path))
        prototypes = instancer.GetPrototypesRel().GetTargets()
        watched.update(str(target) for target in prototypes)
        arrays = point_instancer.read(instancer, len(prototypes), self.time, self.warnings)
        if arrays is None:
            return
        instancer_world = self._relative(prim, frame)
        world = instancer_world[None] if copies is None else instancer_world[None] @ copies  # (C, 4, 4)
        for index, target in enumerate(prototypes):
            selection = arrays.selections[index]
            if selection is not None and len(selection) == 0:
                continue
            proto = self.stage.GetPrimAtPath(target)
            if not proto:
                self.warnings.append(f"{path}: prototype {target} does not exist")
                continue
            # The prototype's root transform counts (ExcludeProtoXform with the prototype visited from its parent).
            self._visit(proto, world, proto.GetParent(), f"{context}[{index}]", records, watched, points=(arrays, index),
                        proxy=proxy)

    # -- the index made to match the stage ----------------------------------------------------------

    def _repopulate(self, path: str, survivor_bits: int) -> None:
        """Walks `path`'s subtree again and makes the index match it: prims gone are removed, new ones inserted,
        and those still there dirtied with `survivor_bits`. Instancing groups that read anything there are re-made."""
        found = _Found()
        had_materials = self._stage_has("Material")
        prim = self.stage.GetPrimAtPath(path)
        hidden = self._outside_state(prim) if prim else None
        if hidden is not None:
            self._walk(prim, hidden, found)
        resync = survivor_bits == _dirty.ALL

        # Gprims drawn once, cameras and lights: ids are prim paths.
        for id in self._paths.under(path):
            record = self.rprims.get(id)
            if record is not None and record.group is None and id not in found.rprims:
                self._remove_rprim(id)
            elif self.sprims.get(id, "material") != "material" and id not in found.sprims:
                self._remove_sprim(id)
        new = []
        for id, found_prim in found.rprims.items():
            record = self.rprims.get(id)
            if record is None:
                new.append(id)
                continue
            record.walked_visible, record.walked_authored = id not in found.hidden, found.authored[id]
            if resync:
                record.prim = found_prim  # the old handle may have expired
                self._rebind(id, record)
                self.index.mark_dirty(id, survivor_bits)
            elif survivor_bits:
                self.index.mark_dirty(id, survivor_bits)
        self._insert_walked(new, found)  # takes the world transforms it hands over out of found.worlds
        self._walked_worlds.update(found.worlds)
        for id, kind in found.sprims.items():
            if self.sprims.get(id) not in (None, kind):
                self._remove_sprim(id)
            if id not in self.sprims:
                self._insert_sprim(kind, id)
            elif resync:
                self.index.mark_dirty(id, _dirty.ALL)
        if resync:  # materials defined there: re-read, and the meshes bound to them re-bound
            for id in self._paths.under(path):
                if self.sprims.get(id) == "material":
                    self.index.mark_dirty(id, _dirty.ALL)
                    self._renew_needs(id)
                    for user in list(self._material_users.get(id, ())):
                        self._rebind(user, self.rprims[user], mark=True)

        # Instancing: anchors under `path` are forgotten, then those found there added back.
        touched = self._groups_touching(path)
        for key in touched:
            group = self.groups[key]
            group.anchors = {a: None for a in group.anchors if not is_at_or_under(a, path)}
        for prototype, instances in found.natives.items():
            group = self.groups.setdefault(prototype, _Group("native"))
            group.anchors.update(dict.fromkeys(instances))
            group.purposes.update((instance, found.instance_purposes[instance]) for instance in instances)
            touched.add(prototype)
        for instancer in found.instancers:
            self.groups.setdefault(instancer, _Group("pointInstancer")).anchors[instancer] = None
            touched.add(instancer)
        for key in sorted(touched):
            self._remake_group(key, path if resync else None, moved=path)
        if self._stage_has("Material") and not had_materials:  # the first material: bindings were not resolved before
            for key in sorted(k for k, group in self.groups.items() if group.kind == "native"):
                self._remake_group(key, None, rebound="/")
            for id, record in self.rprims.items():
                self._rebind(id, record, mark=True)

    def _outside_state(self, prim: Usd.Prim) -> bool | None:
        """For a walk from `prim`: whether an ancestor hides it (True), or None when it is not walked from the top
        (inside a prototype, an instance or a PointInstancer, where its group re-makes it)."""
        if prim.IsPseudoRoot():
            return False
        if prim.IsInPrototype() or prim.IsInstanceProxy():
            return None
        hidden = False
        parent = prim.GetParent()
        while parent and not parent.IsPseudoRoot():
            if parent.IsA(UsdGeom.PointInstancer):
                return None
            imageable = UsdGeom.Imageable(parent)
            if imageable:
                hidden = hidden or imageable.GetVisibilityAttr().Get(self.time) == UsdGeom.Tokens.invisible
            parent = parent.GetParent()
        return hidden

    def _groups_touching(self, path: str) -> set[str]:
        """Instancing groups that read a prim at, under or above `path`."""
        keys = set(self._watch.under(path))
        for ancestor in ancestors(path):
            keys.update(self._watch.at(ancestor))
        return keys

    def _remake_group(self, key: str, resynced: str | None, moved: str | None = None, rebound: str | None = None) -> None:
        """Visits an instancing group again and makes its rprims match: new ones inserted, gone ones removed, the
        others dirtied with what changed (their copies' transforms, their material; everything where they were
        read from the resynced path). `moved`: a path whose transforms changed (instances under it are re-read);
        `rebound`: a path whose material bindings changed (instances under it resolve theirs again)."""
        group = self.groups[key]
        records: dict[str, _Rprim] = {}
        watched = set(group.anchors)
        if group.anchors:
            prim = self.stage.GetPrimAtPath(key)
            if group.kind == "native" and prim:
                watched.add(key)
                copies = self._instance_copies(group, moved or resynced)
                for context, rows, instance, purpose in self._binding_partitions(key, group, rebound or resynced):
                    self._visit(prim, copies if rows is None else copies[rows], None, context, records, watched,
                                proxy=(key, instance), purpose=purpose)
            elif group.kind == "pointInstancer" and prim:
                self._visit_point_instancer(UsdGeom.PointInstancer(prim), None, None, key, records, watched)
        for id in group.rprims - records.keys():
            self._remove_rprim(id)
        for id, record in records.items():
            record.group = key
            old = self.rprims.get(id)
            if old is None:
                self._insert_rprim(id, record)
                continue
            bits = 0
            if resynced is not None and is_at_or_under(str(record.prim.GetPath()), resynced):
                bits = _dirty.ALL
            if not _same_copies(old, record):
                bits |= _dirty.INSTANCER
            old.prim, old.frames, old.points, old.prototype, old.local = record.prim, record.frames, record.points, record.prototype, record.local
            old.binding = record.binding
            if self._rebind(id, old):
                bits |= _dirty.MATERIAL_ID
            if bits:
                self.index.mark_dirty(id, bits)
        for path in group.watched - watched:
            self._watch.discard(path, key)
        for path in watched - group.watched:
            self._watch.add(path, key)
        group.rprims, group.watched = set(records), watched
        if not group.anchors:
            for path in group.watched:
                self._watch.discard(path, key)
            del self.groups[key]

    def _binding_partitions(self, key: str, group: _Group, rebound: str | None) -> list[tuple]:
        """A native group's instances split by what they inherit from outside the prototype, as UsdImaging groups
        them: the material bindings and the purpose. (context, rows of the group's copies or None for all, one instance
        of those, their purpose). One prototype is visited per part: its meshes are built once (the same cache key),
        only their material differs, and a prim inside draws where its purpose (its own, else the instance's) is drawn.
        The part without an outside binding and of the default purpose keeps the group's key as its context; others
        add `<MATERIAL>` (`!` after a strong binding) and `(PURPOSE)`."""
        for anchor in [a for a in group.purposes if a not in group.anchors]:
            del group.purposes[anchor]
        anchors = list(group.anchors)
        default = UsdGeom.Tokens.default_
        purpose_of = [group.purposes.get(anchor, default) for anchor in anchors]
        if not self._stage_has("Material"):
            bindings = [("", False)] * len(anchors)
        else:
            keys = group.binding_keys
            for anchor in [a for a in keys if a not in group.anchors]:
                del keys[anchor]
            for anchor in anchors:
                if anchor not in keys or (rebound is not None and is_at_or_under(anchor, rebound)):
                    keys[anchor] = self._instance_binding_key(anchor)
            bindings = [keys[anchor] for anchor in anchors]
        rows: dict[tuple, list[int]] = {}
        for row, part in enumerate(zip(bindings, purpose_of)):
            rows.setdefault(part, []).append(row)
        if len(rows) == 1 and (("", False), default) in rows:
            return [(key, None, anchors[0], default)]
        return [(key + (f"<{binding[0]}{'!' if binding[1] else ''}>" if binding != ("", False) else "") +
                 (f"({purpose})" if purpose != default else ""),
                 np.asarray(part), anchors[part[0]], purpose) for (binding, purpose), part in rows.items()]

    def _instance_binding_key(self, anchor: str) -> tuple[str, bool]:
        """(material, strong) an instance prim resolves: what decides the binding of every gprim of its prototype
        (the outside binding, unless weaker than the prototype's own). Collection bindings that name prims inside the
        instance (not the instance or its ancestors) are not told apart."""
        binding = UsdShade.MaterialBindingAPI(self.stage.GetPrimAtPath(anchor))
        material, relationship = binding.ComputeBoundMaterial(_MATERIAL_PURPOSE)
        if not material:
            return ("", False)
        strength = UsdShade.MaterialBindingAPI.GetMaterialBindingStrength(relationship)
        return (str(material.GetPath()), strength == UsdShade.Tokens.strongerThanDescendants)

    def _instance_copies(self, group: _Group, moved: str | None) -> np.ndarray:
        """A native group's instance world transforms: those kept, except under `moved` and for new instances."""
        anchors = list(group.anchors)
        read = lambda anchor: self._relative(self.stage.GetPrimAtPath(anchor), None)
        if group.copies is not None and group.order == anchors:
            if moved in group.anchors:  # one instance moved (the common edit): its row alone
                group.copies[anchors.index(moved)] = read(moved)
            elif moved is not None:
                for row, anchor in enumerate(anchors):
                    if is_at_or_under(anchor, moved):
                        group.copies[row] = read(anchor)
            return group.copies
        kept = dict(zip(group.order, group.copies)) if group.copies is not None else {}
        group.copies = np.stack([kept[a] if a in kept and not (moved and is_at_or_under(a, moved)) else read(a) for a in anchors])
        group.order = anchors
        return group.copies

    def _insert_walked(self, ids: list[str], found: _Found) -> None:
        """Gprims drawn once that a walk found and the index lacks, inserted into the index in one call. What the walk
        saw of a mesh's visibility and material, when they are the defaults (visible; no material, no subsets), and the
        world transform it computed for a mesh that shows go with it, so that its first sync does not call back for
        them. (A hidden mesh's transform is noted for the sync that shows it.)"""
        visible, unbound, placed = _dirty.VISIBILITY, _dirty.MATERIAL_ID, _dirty.TRANSFORM
        defaults, worlds = [], []
        for id in ids:
            shown = id not in found.hidden
            record = self.rprims[id] = _Rprim(found.rprims[id], walked_visible=None if shown else False,
                                              walked_authored=found.authored[id])
            self._paths.add(id, id)
            self._rebind(id, record)
            world = found.worlds.pop(id, None) if shown else None
            worlds.append(_NO_TRANSFORM if world is None else world)
            defaults.append((visible if shown else 0) | (0 if record.material or record.subset_materials else unbound) |
                            (0 if world is None else placed))
        transforms = np.frombuffer(b"".join(worlds)).reshape(-1, 16) if ids else None  # Gf's buffers, joined in C
        self.index.insert_rprims("mesh", ids, defaults, transforms)

    def _insert_rprim(self, id: str, record: _Rprim) -> None:
        self.rprims[id] = record
        self._paths.add(id if record.group is None else str(record.prim.GetPath()), id)  # a plain rprim's id is its path
        self._rebind(id, record)
        self.index.insert_rprim("mesh", id, record.instancer_id)

    def _remove_rprim(self, id: str) -> None:
        record = self.rprims.pop(id)
        self._paths.discard(str(record.prim.GetPath()), id)
        for material in {record.material, *record.subset_materials}:
            self._release_material(material, id)
        self.index.remove_prim(id)

    def _insert_sprim(self, kind: str, id: str) -> None:
        self.sprims[id] = kind
        self._paths.add(id, id)
        self.index.insert_sprim(kind, id)
        if kind == "camera":
            self.cameras.append(id)
        elif kind in _LIGHT_TYPES:
            self.lights.append(id)

    def _remove_sprim(self, id: str) -> None:
        kind = self.sprims.pop(id)
        self._paths.discard(id, id)
        self.index.remove_prim(id)
        for names in (self.cameras, self.lights):
            if id in names:
                names.remove(id)

    # -- materials ------------------------------------------------------------------------------------

    def _material_subsets(self, prim: Usd.Prim) -> list:
        """A mesh's GeomSubsets of family materialBind over faces, in order: subset i is material slot i + 1 (at most 255)."""
        if not self._stage_has("GeomSubset") or not prim.IsA(UsdGeom.Mesh):
            return []
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        return [s for s in subsets if s.GetElementTypeAttr().Get() == UsdGeom.Tokens.face][:255]

    def get_subset_material_ids(self, id: str) -> list[str]:
        """The material of each GeomSubset (slot 1, 2, ...): its own binding, else its mesh's (UsdShade's resolution)."""
        return self.rprims[id].subset_materials  # a tuple: C++ takes any sequence

    def _stage_has(self, type_name: str) -> bool:
        """Whether a walk or a visit has met a prim of this type (the walks see every prim's type once)."""
        return type_name in self._kinds

    def _bound_material(self, prim: Usd.Prim) -> str:
        if not self._stage_has("Material"):
            return ""  # nothing to bind to: the binding need not be resolved
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(_MATERIAL_PURPOSE)
        return str(material.GetPath()) if material else ""

    def _rebind(self, id: str, record: _Rprim, mark: bool = False) -> bool:
        """Resolves the rprim's material binding (inserting the material's sprim when it is new); True if it changed."""
        if not record.material and not record.subset_materials and not self._stage_has("Material") and \
                not self._stage_has("GeomSubset"):
            return False  # nothing bound and nothing to bind: what the resolution below would find
        prim = record.prim if record.binding is None else self.stage.GetPrimAtPath(record.binding)
        material = self._bound_material(prim)
        subsets = tuple(self._bound_material(s.GetPrim()) for s in self._material_subsets(prim))
        if (material, subsets) == (record.material, record.subset_materials) and \
                all(id in self._material_users.get(m, ()) for m in (material, *subsets) if m):
            return False
        for old in {record.material, *record.subset_materials}:
            self._release_material(old, id)
        record.material, record.subset_materials = material, subsets
        for new in {material, *subsets}:
            if not new:
                continue
            if new not in self._material_users:
                self._material_users[new] = set()
                self._insert_sprim("material", new)
            self._material_users[new].add(id)
        if mark:
            self.index.mark_dirty(id, _dirty.MATERIAL_ID)
        return True

    def _release_material(self, material: str, id: str) -> None:
        users = self._material_users.get(material)
        if users is None:
            return
        users.discard(id)
        if not users:  # no mesh binds it any more
            del self._material_users[material]
            self._needs.pop(material, None)
            self._remove_sprim(material)

    # -- edits and time ---------------------------------------------------------------------------------

    def apply_changes(self, resynced: set[str], changed: dict[str, set[str]]) -> None:
        """Dirties what the edits named by a ChangeTracker (recomposed prim paths; changed properties per prim)
        touch, as change_tracker.py's table says. Call before syncing."""
        if not resynced and not changed:
            return
        self.xform_cache.Clear()
        for path in changed:  # what a walk saw of an edited prim no longer holds (a walk below may see it again)
            for id in self._paths.at(path):
                record = self.rprims.get(id)
                if record is not None:
                    record.walked_visible = record.walked_authored = None
        self._forget_walked_worlds()  # an edit above a prim moves it: walked transforms not yet synced are read afresh
        roots = _outermost(resynced)
        if roots:
            self._time_varying = None  # recomposed: what varies in time is looked up again when next needed
            self._report_composition_errors()  # a variant or reference switched to an asset that cannot be opened
        for root in roots:
            self._repopulate(root, _dirty.ALL)
        for path, names in changed.items():
            if any(is_at_or_under(path, root) for root in roots):
                continue  # already re-synced whole
            prim = self.stage.GetPrimAtPath(path)
            if not prim:
                continue
            for name in sorted(names):
                effect = change_tracker.classify(prim, name)
                if effect is None:
                    continue
                if effect.scope == change_tracker.INHERITED_PRIMVAR:
                    self._inherited_primvar_edited(path, name)
                else:
                    self._apply(path, prim, effect)

    def _inherited_primvar_edited(self, path: str, name: str) -> None:
        """A primvar edited on a prim that is not a gprim: the meshes under it whose materials read that primvar (a
        reader's, or the fallback surface's displayColor) read their primvars again; the others are left alone (a
        primvar nothing reads rebuilds nothing)."""
        primvar = name[len("primvars:"):].removesuffix(":indices")
        if primvar == "displayColor":
            self._inherited_display_color = True
        for id in self._paths.under(path):
            record = self.rprims.get(id)
            if record is not None and record.group is None and any(r.primvar == primvar for r in self._primvar_needs(record).channel):
                self.index.mark_dirty(id, _dirty.PRIMVAR)

    def _apply(self, path: str, prim: Usd.Prim, effect: change_tracker.Effect) -> None:
        scope, bits = effect
        if scope == change_tracker.RESYNC:
            self._repopulate(path, _dirty.ALL)
        elif scope == change_tracker.VISIBILITY:
            self._repopulate(path, _dirty.VISIBILITY)
        elif scope == change_tracker.SUBTREE:
            for id in self._paths.under(path):
                record = self.rprims.get(id)
                if record is not None and record.group is None:
                    if bits & _dirty.MATERIAL_ID:
                        self._rebind(id, record, mark=True)
                    if bits & ~_dirty.MATERIAL_ID:
                        self.index.mark_dirty(id, bits & ~_dirty.MATERIAL_ID)
                elif record is None and self.sprims.get(id) in _LIGHT_TYPES | {"camera"} and bits & _dirty.TRANSFORM:
                    self.index.mark_dirty(id, _dirty.PARAMS)
            for key in sorted(self._groups_touching(path)):
                self._remake_group(key, None, path if bits & _dirty.TRANSFORM else None,
                                   path if bits & _dirty.MATERIAL_ID else None)
        elif scope == change_tracker.EVERY_MESH:
            for key in sorted(k for k, group in self.groups.items() if group.kind == "native"):
                self._remake_group(key, None, rebound="/")  # a collection may name any instance
            for id, record in self.rprims.items():
                self._rebind(id, record, mark=True)
        elif scope == change_tracker.INSTANCER:
            for key in sorted(self._groups_touching(path)):
                self._remake_group(key, None)
        elif scope == change_tracker.SPRIM:
            for candidate in (path, *ancestors(path)):  # the light or camera itself, or the material a shader is in
                if candidate in self.sprims:
                    self.index.mark_dirty(candidate, bits)
                    if self.sprims[candidate] == "material":
                        self._renew_needs(candidate)
                    break
        elif scope == change_tracker.GPRIM:
            for id in self._paths.at(path):
                if id in self.rprims:
                    self.index.mark_dirty(id, bits)

    def set_time(self, time: Usd.TimeCode) -> None:
        """Moves to another time: dirties what an edit of each time-varying attribute whose value differs between
        the two times would, and nothing else (a held sample dirties nothing)."""
        if time == self.time:
            return
        if self._time_varying is None:
            self._time_varying = self._find_time_varying()
        changed: dict[str, set[str]] = {}
        for path, names in self._time_varying.items():
            prim = self.stage.GetPrimAtPath(path)
            for name in names:
                attribute = prim.GetAttribute(name)
                if attribute.Get(self.time) != attribute.Get(time):  # arrays: shared until they differ, cheap to compare
                    changed.setdefault(path, set()).add(name)
        self.time = time
        self.xform_cache.SetTime(time)
        self.apply_changes(set(), changed)

    def _forget_walked_worlds(self) -> None:
        """Drops the world transforms that walks noted and no sync used yet: an edit or a new time may have moved them.
        (Those handed to the index with new meshes are forgotten there by the edit's own dirty bits.)"""
        self._walked_worlds.clear()

    def _find_time_varying(self) -> dict[str, set[str]]:
        """Every authored attribute whose value may change with time, on the stage and in its prototypes."""
        varying: dict[str, set[str]] = {}
        prims = [Usd.PrimRange.Stage(self.stage)] + [Usd.PrimRange(p) for p in self.stage.GetPrototypes()]
        for prim_range in prims:
            for prim in prim_range:
                names = {a.GetName() for a in prim.GetAuthoredAttributes() if a.ValueMightBeTimeVarying()}
                if names:
                    varying[str(prim.GetPath())] = names
        return varying

    # -- SceneDelegate ----------------------------------------------------------------------------------

    def set_complexity(self, complexity: float) -> None:
        """Refines subdivision surfaces at `complexity`'s refine level (Hydra's convention: subdivision.refine_level)
        from the next sync. A new level re-syncs the meshes that have a subdivision scheme (and were read), no others."""
        level = subdivision.refine_level(complexity)
        self.complexity = float(complexity)
        if level == self.refine_level:
            return
        self.refine_level = level
        for id, record in self.rprims.items():
            if record.subdivided:
                self.index.mark_dirty(id, _dirty.TOPOLOGY)

    def _authored_names(self, names: list[str]) -> _AuthoredNames:
        key = tuple(names)
        shared = self._authored_sets.get(key)
        if shared is None:
            shared = self._authored_sets[key] = _AuthoredNames(key)
        return shared

    def get_mesh(self, id: str):
        record = self.rprims[id]
        prim = record.prim
        # One call says which properties carry opinions: the reads below skip the others (a mesh authors a few of the
        # dozen attributes a mesh may have; each read is a round trip through usd-core).
        authored, record.walked_authored = record.walked_authored, None
        if authored is None:
            authored = self._authored_names(prim.GetAuthoredPropertyNames())
        name = id if record.group is None else str(prim.GetPath())
        # Without a material (the common case of big stages) the needs are known without asking.
        unbound = not record.material and not record.subset_materials and not self._all_uvs
        needs = materials.NO_MATERIAL if unbound else self._primvar_needs(record, name)
        # A plain mesh authors no primvars: only a material's primvar reader fallback would need the full path.
        if authored.plain and "points" in authored and not self._stage_has("GeomSubset") and \
                (unbound or all(r.fallback is None for r in needs.channel)) and not self._inherited_display_color:
            source = self._plain_mesh_source(prim, authored, name, record)
        else:
            source = self._mesh_source(prim, authored, needs, name, record)
        if authored.tessera:
            source.settings = self._mesh_settings(prim, self.build_settings, self.time, self.warnings)
        else:  # nothing of TesseraMeshAPI authored: the render's defaults, applied or not
            source.settings = self.build_settings
        return source

    def _plain_mesh_source(self, prim: Usd.Prim, authored: _AuthoredNames, name: str, record: _Rprim):
        """The common mesh, read in as few steps as can be: no primvars, normals or holes authored, no GeomSubsets on
        the stage (what _mesh_source makes of it, with less Python per mesh)."""
        t = self.time
        attribute = prim.GetAttribute
        points = attribute("points").Get(t)
        counts = attribute("faceVertexCounts").Get(t) if "faceVertexCounts" in authored else None
        indices = attribute("faceVertexIndices").Get(t) if "faceVertexIndices" in authored else None
        if points is None or counts is None or indices is None:
            return self._mesh_source(prim, authored, materials.NO_MATERIAL, name, record)  # a Cube or Sphere, or the error
        scheme = (attribute("subdivisionScheme").Get(t) if "subdivisionScheme" in authored else None) or "catmullClark"
        record.subdivided = scheme != UsdGeom.Tokens.none
        left_handed = "orientation" in authored and attribute("orientation").Get(t) == UsdGeom.Tokens.leftHanded
        double_sided = "doubleSided" in authored and bool(attribute("doubleSided").Get(t))
        try:  # USD's arrays themselves, through their buffers (numpy views of them cost 5 us a mesh more)
            return _tessera.plain_mesh_source(name, points, counts, indices, left_handed, double_sided, scheme, self.refine_level)
        except ValueError:  # not point3f[] and int[] as the schema says (double3[] points, say): converted
            return _tessera.plain_mesh_source(name, np.asarray(points, np.float32), np.asarray(counts, np.int32),
                                              np.asarray(indices, np.int32), left_handed, double_sided, scheme, self.refine_level)

    def _primvar_needs(self, record: _Rprim, name: str | None = None) -> materials.PrimvarNeeds:
        """What the rprim's materials read of its primvars (its own and its GeomSubsets'): the first UV set and the
        first vertex channel any of them reads."""
        needs = self._textured_needs(record, name)
        if self._all_uvs and needs.uv is None:
            return materials.PrimvarNeeds(uv="st", channel=needs.channel)
        return needs

    def _textured_needs(self, record: _Rprim, name: str | None = None) -> materials.PrimvarNeeds:
        """`name`: the mesh's, to warn when its materials (its own and its GeomSubsets') read different vertex channels."""
        bound = [m for m in (record.material, *record.subset_materials) if m]
        if not bound:
            return materials.NO_MATERIAL
        if record.subset_materials and not record.material:
            bound.append("")  # faces in no subset: no material, the fallback surface
        found = [self._material_needs(m) if m else materials.NO_MATERIAL for m in bound]
        uv = next((n.uv for n in found if n.uv), None)
        channel = next((n.channel for n in found if n.channel), ())
        if name is not None:
            others = [m or "the fallback surface" for m, n in zip(bound, found) if n.channel and n.channel != channel]
            if others:
                first = next(m or "the fallback surface" for m, n in zip(bound, found) if n.channel == channel)
                self.warnings.append(f"{name}: its materials read different primvars into its vertex channel; {first}'s are "
                                     f"read, and {', '.join(others)} read(s) them in place of its own")
        return materials.PrimvarNeeds(uv=uv, channel=channel)

    def read_all_uvs(self) -> None:
        """From now on every mesh reads texture coordinates (its material's UV set, else st), as the `uv` debug view
        shows them; those that read none so far read their primvars again."""
        if self._all_uvs:
            return
        self._all_uvs = True
        for id, record in self.rprims.items():
            if self._textured_needs(record).uv is None:
                self.index.mark_dirty(id, _dirty.PRIMVAR)

    def _material_needs(self, material: str) -> materials.PrimvarNeeds:
        needs = self._needs.get(material)
        if needs is None:
            needs = self._needs[material] = materials.primvar_needs(self.stage.GetPrimAtPath(material), self.time)
        return needs

    def _renew_needs(self, material: str) -> None:
        """A material was edited: if what its meshes must read changed (a texture now reads UVs, a reader another
        primvar), they read their primvars again."""
        old = self._needs.pop(material, None)
        if old is not None and material in self._material_users and self._material_needs(material) != old:
            for user in self._material_users[material]:
                self.index.mark_dirty(user, _dirty.PRIMVAR)

    def _vertex_channel(self, prim: Usd.Prim, authored: _AuthoredNames, needs: materials.PrimvarNeeds, name: str, topology=None):
        """(values, interpolation, indices, components) of the mesh's vertex channel (vertex_channel.pack), or
        (None, "constant", None, 3) when its materials read none. `topology`: (point count, faceVertexCounts,
        faceVertexIndices); None for an implicit shape, which takes each primvar's first element (a constant)."""
        if not needs.channel:
            return None, "constant", None, 3
        found = [self._channel_primvar(prim, authored, read, name) for read in needs.channel]
        return vertex_channel.pack(needs.channel, found, topology, name, self.warnings)

    def _channel_primvar(self, prim: Usd.Prim, authored: _AuthoredNames, read: materials.ChannelRead, name: str):
        """(values as `read.components` columns, interpolation, indices) of one primvar of the vertex channel: on the mesh,
        else, for a primvar reader, a constant one inherited from an ancestor (UsdGeomPrimvarsAPI's
        FindPrimvarWithInheritance, as UsdImaging reads them; the fallback surface's displayColor too, once some prim
        that is not a mesh authors one: before that, no ancestor walk per mesh); None where the mesh lacks it (the
        reader's fallback then)."""
        if not read.primvar:
            return None
        primvars = UsdGeom.PrimvarsAPI(prim)
        if f"primvars:{read.primvar}" in authored:
            pv = primvars.GetPrimvar(read.primvar)
        elif read.fallback is not None or (read.primvar == "displayColor" and self._inherited_display_color):
            pv = primvars.FindPrimvarWithInheritance(read.primvar)
        else:
            return None
        values = pv.Get(self.time) if pv and pv.HasAuthoredValue() else None
        if values is None:
            return None
        try:
            a = np.asarray(values, np.float32)
        except (TypeError, ValueError):
            a = np.zeros((0,), np.float32)
        if not pv.GetTypeName().isArray:  # a single value (a float or a colour), as a constant primvar often is
            a = a.reshape(1, -1)
        elif a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2 or a.shape[1] not in (1, 2, 3, 4) or not len(a):
            self.warnings.append(f"{name}: primvars:{read.primvar} is {pv.GetTypeName()}, not a number or vector; ignored")
            return None
        if read.components == 1:
            a = a[:, :1]
        else:  # a colour: grey from one component, (x, y, 0) from two
            a = np.repeat(a, 3, axis=1) if a.shape[1] == 1 else np.pad(a, ((0, 0), (0, max(0, 3 - a.shape[1]))))[:, :3]
        idx = pv.GetIndices(self.time)
        idx = np.asarray(idx, np.int32) if idx is not None and len(idx) else None
        return a, str(pv.GetInterpolation()), idx

    def _mesh_source(self, prim: Usd.Prim, authored: _AuthoredNames, needs: materials.PrimvarNeeds, name: str, record: _Rprim):
        record.subdivided = False
        if not prim.IsA(UsdGeom.Mesh):
            color, _, _, components = self._vertex_channel(prim, authored, needs, name)
            return implicit.mesh_source(prim, self.time, color, components)
        t = self.time

        def array(attribute_name, dtype, width=None):
            value = prim.GetAttribute(attribute_name).Get(t) if attribute_name in authored else None
            if value is None:
                return None
            a = np.asarray(value, dtype=dtype)
            return np.ascontiguousarray(a.reshape(-1)) if width else np.ascontiguousarray(a)

        def value(attribute_name, default):
            if attribute_name not in authored:
                return default
            v = prim.GetAttribute(attribute_name).Get(t)
            return default if v is None else v

        points = array("points", np.float32, 3)
        counts = array("faceVertexCounts", np.int32)
        indices = array("faceVertexIndices", np.int32)
        if points is None or counts is None or indices is None:
            raise _tessera.MeshError(f"{name}: points, faceVertexCounts or faceVertexIndices is not authored")
        holes = array("holeIndices", np.int32)

        def primvar(primvar_name, default_interpolation, width=3):
            """(values, interpolation, indices) of an authored primvar of `width` components, else (None, default, None)."""
            if f"primvars:{primvar_name}" not in authored:
                return None, default_interpolation, None
            pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(primvar_name)
            if not (pv and pv.HasAuthoredValue()):
                return None, default_interpolation, None
            values = pv.Get(t)
            shape = np.shape(values) if values is not None else ()
            if len(shape) != 2 or shape[1] != width:
                self.warnings.append(f"{name}: primvars:{primvar_name} is {pv.GetTypeName()}, not {width} floats per element; ignored")
                return None, default_interpolation, None
            idx = pv.GetIndices(t)
            idx = np.ascontiguousarray(np.asarray(idx, np.int32)) if idx is not None and len(idx) else None
            return np.ascontiguousarray(np.asarray(values, np.float32).reshape(-1)), pv.GetInterpolation(), idx

        scheme = value("subdivisionScheme", "") or "catmullClark"
        record.subdivided = scheme != UsdGeom.Tokens.none
        # primvars:normals wins over the normals attribute, as in UsdImaging. Like UsdImaging (its mesh adapter reads
        # normals only when subdivisionScheme is none), a subdivision surface's authored normals are not read, at any
        # refine level: its normals are smooth ones from its geometry.
        normals, normals_interp, normals_idx = None, "vertex", None
        if not record.subdivided:
            normals, normals_interp, normals_idx = primvar("normals", "vertex")
            if normals is None and "normals" in authored and prim.GetAttribute("normals").HasAuthoredValue():
                normals, normals_interp = array("normals", np.float32, 3), UsdGeom.Mesh(prim).GetNormalsInterpolation()
        # Only what the materials read: the colour primvar one routes into diffuseColor, the UV set textures read.
        color, color_interp, color_idx, color_components = self._vertex_channel(prim, authored, needs, name, (len(points) // 3, counts, indices))
        uvs, uvs_interp, uvs_idx = primvar(needs.uv, "faceVarying", width=2) if needs.uv else (None, "faceVarying", None)
        face_materials = None
        subsets = self._material_subsets(prim)
        if subsets:  # faces in no subset keep slot 0 (the mesh's own material); a face in several takes the last
            face_materials = np.zeros(len(counts), np.int32)
            for slot, subset in enumerate(subsets, start=1):
                faces = np.asarray(subset.GetIndicesAttr().Get(t) or [], np.int64)
                bad = (faces < 0) | (faces >= len(counts))
                if bad.any():
                    self.warnings.append(f"{subset.GetPath()}: {int(bad.sum())} face indices outside 0..{len(counts) - 1}; ignored")
                face_materials[faces[~bad]] = slot
        # Subdivision tags matter only to a refined mesh: read then alone.
        tags = (subdivision.tags(prim, authored, t, name, self.warnings)
                if record.subdivided and self.refine_level > 0 and not authored.isdisjoint(subdivision.TAG_ATTRIBUTES) else {})
        return _tessera.mesh_source(
            name, points, counts, indices,
            hole_indices=holes,
            left_handed=value("orientation", UsdGeom.Tokens.rightHanded) == UsdGeom.Tokens.leftHanded,
            double_sided=bool(value("doubleSided", False)),
            normals=normals, normals_interpolation=normals_interp, normals_indices=normals_idx,
            display_color=color, display_color_interpolation=color_interp, display_color_indices=color_idx,
            display_color_components=color_components,
            uvs=uvs, uvs_interpolation=uvs_interp, uvs_indices=uvs_idx, face_materials=face_materials,
            subdivision_scheme=scheme, refine_level=self.refine_level, **tags)

    def uv_primvar(self, prim: Usd.Prim) -> str | None:
        """The texture coordinate set a mesh is built with: the primvar its bound material's texture readers read
        (a UsdPrimvarReader_float2's varname, else "st", the convention of UsdPreviewSurface materials); None when
        no texture of it reads coordinates (none are read or uploaded)."""
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(_MATERIAL_PURPOSE)
        return materials.primvar_needs(material.GetPrim(), self.time).uv if material else None

    def get_transform(self, id: str):
        world = self._walked_worlds.pop(id, None)
        if world is None:
            world = self.xform_cache.GetLocalToWorldTransform(self.rprims[id].prim)
        return to_column_major(world)

    def get_visible(self, id: str) -> bool:
        record = self.rprims[id]
        if record.frames is not None:
            return True  # visibility inside prototypes was resolved while populating
        if record.walked_visible is not None:  # the walk that just found it saw its visibility
            visible, record.walked_visible = record.walked_visible, None
            return visible
        return UsdGeom.Imageable(record.prim).ComputeVisibility(self.time) != UsdGeom.Tokens.invisible

    def get_extent(self, id: str):
        """The mesh's authored extent in its own space (lo xyz, hi xyz), or None: a mesh without one is built whether
        a view sees it or not."""
        attribute = self.rprims[id].prim.GetAttribute("extent")
        if not attribute.HasAuthoredValue():
            return None
        value = attribute.Get(self.time)
        if value is None or len(value) != 2:
            return None
        lo, hi = value
        return (lo[0], lo[1], lo[2], hi[0], hi[1], hi[2])

    def get_material_id(self, id: str) -> str:
        return self.rprims[id].material

    def get_instances(self, instancer_id: str, prototype_id: str):
        record = self.rprims[prototype_id]
        arrays = record.points.instance_arrays(record.prototype, record.local) if record.points is not None else None
        return _tessera.instance_set(record.frames, arrays)

    def get_material(self, id: str):
        return materials.material_desc(self.stage.GetPrimAtPath(id), self.time, self.warnings)

    def get_light(self, id: str):
        prim = self.stage.GetPrimAtPath(id)
        return lights.light_desc(prim, self.time, self.xform_cache.GetLocalToWorldTransform(prim), self.warnings)

    def get_camera(self, id: str):
        return camera_desc(UsdGeom.Camera(self.stage.GetPrimAtPath(id)).GetCamera(self.time))


def _same_copies(a: _Rprim, b: _Rprim) -> bool:
    """Whether two records of an instanced rprim draw the same copies (so no DirtyInstancer)."""
    if not np.array_equal(a.frames, b.frames) or (a.points is None) != (b.points is None):
        return False
    if a.points is None:
        return True
    return a.prototype == b.prototype and np.array_equal(a.local, b.local) and b.points.same_as(a.points, b.prototype)


def _outermost(paths: set[str]) -> list[str]:
    """The paths none of whose ancestors is in the set."""
    return sorted(p for p in paths if not any(a in paths for a in ancestors(p)))


def camera_desc(camera: Gf.Camera):
    """A Gf.Camera as the renderer's CameraDesc."""
    desc = _tessera.CameraDesc()
    desc.camera_to_world = to_column_major(camera.transform)
    ortho = camera.projection == Gf.Camera.Orthographic
    desc.orthographic = ortho
    # Perspective apertures only matter relative to the focal length; orthographic ones are in tenths of a unit.
    unit = Gf.Camera.APERTURE_UNIT if ortho else 1.0
    desc.focal_length = camera.focalLength
    desc.horizontal_aperture = camera.horizontalAperture * unit
    desc.vertical_aperture = camera.verticalAperture * unit
    desc.horizontal_aperture_offset = camera.horizontalApertureOffset * unit
    desc.vertical_aperture_offset = camera.verticalApertureOffset * unit
    clip = camera.clippingRange
    desc.near_clip = max(clip.min, 1e-6)
    desc.far_clip = clip.max if clip.max > clip.min else float("inf")
    return desc


def _world_bounds(stage: Usd.Stage, cache: UsdGeom.BBoxCache, avoid: set[str]) -> Gf.Range3d:
    """The stage's bounds, leaving out the subtrees of the prims in `avoid` (PointInstancers in a cycle, which
    USD's bounds computation would follow forever)."""
    if not avoid:
        return cache.ComputeWorldBound(stage.GetPseudoRoot()).ComputeAlignedRange()
    box = Gf.Range3d()
    it = iter(Usd.PrimRange(stage.GetPseudoRoot()))
    for prim in it:
        path = str(prim.GetPath())
        if path in avoid:
            it.PruneChildren()
        elif not any(is_at_or_under(a, path) for a in avoid):  # holds none of them: its bound as a whole
            box.UnionWith(cache.ComputeWorldBound(prim).ComputeAlignedRange())
            it.PruneChildren()
    return box


def framing_camera(stage: Usd.Stage, time: Usd.TimeCode, width: int, height: int, purposes=(UsdGeom.Tokens.render,),
                   avoid: set[str] = frozenset()):
    """The camera OpenUSD's image tests call -frameAll (testUsdImagingGLBasicDrawing): looking down the
    stage's horizontal depth axis from one bounds-diagonal away, 60 degrees vertical field of view. The bounds are
    those of the purposes drawn, without the subtrees of the prims in `avoid`."""
    cache = UsdGeom.BBoxCache(time, [UsdGeom.Tokens.default_, *purposes], useExtentsHint=True)
    box = _world_bounds(stage, cache, set(avoid))
    if box.IsEmpty():
        center, size = Gf.Vec3d(0, 0, 0), 1.0
    else:
        center, size = (box.GetMin() + box.GetMax()) / 2.0, max(box.GetSize().GetLength(), 1e-6)
    if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z:
        translate = Gf.Vec3d(-center[0], -center[2], -center[1] - size)
        model_view = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(1, 0, 0), -90)) * Gf.Matrix4d().SetTranslate(translate)
    else:
        model_view = Gf.Matrix4d().SetTranslate(Gf.Vec3d(-center[0], -center[1], -center[2] - size))
    desc = _tessera.CameraDesc()
    desc.camera_to_world = to_column_major(model_view.GetInverse())
    desc.focal_length = 1.0
    desc.vertical_aperture = 2.0 * np.tan(np.radians(30.0))
    desc.horizontal_aperture = desc.vertical_aperture * width / height
    desc.near_clip = size * 1e-4
    desc.far_clip = float("inf")
    return desc
