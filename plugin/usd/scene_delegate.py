"""The USD scene delegate: reads a stage through usd-core and answers the render index's questions.

Populate walks the stage once and inserts prims into the render index: every drawable gprim becomes a
"mesh" rprim; native instances and PointInstancers become *one* rprim per prototype mesh whose instance
transforms are composed here (nesting included), so a prototype is built once however many copies it has.
Sync later pulls data through the get_* methods; arrays come out of USD as numpy views, without copies.

Matrices handed to C++ are row-major and act on column vectors: the transpose of Gf's row-vector layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdLux, UsdShade

from tessera import _tessera
from . import implicit

_IDENTITY = np.eye(4)


def to_column_major(gf_matrix) -> list[float]:
    """Gf (row vectors) -> the C++ convention (row-major, column vectors)."""
    return list(np.asarray(gf_matrix, dtype=np.float64).T.reshape(16))


@dataclass
class _Rprim:
    prim: Usd.Prim
    # For instanced rprims: world transforms of every copy (N, 4, 4), Gf row-vector convention.
    instance_transforms: np.ndarray | None = None
    # Transform of the gprim relative to the frame the copies are expressed in (row-vector convention).
    local: np.ndarray = field(default_factory=lambda: _IDENTITY)


class UsdSceneDelegate(_tessera.SceneDelegate):
    def __init__(self, stage: Usd.Stage, render_index, time: Usd.TimeCode = Usd.TimeCode.Default(), refine_level: int = 2,
                 build_settings: _tessera.BuildSettings | None = None):
        super().__init__()
        self.refine_level = refine_level  # uniform refinements of subdivision surfaces (catmullClark, loop, bilinear)
        # Every mesh's build settings (render-wide defaults; per-mesh TesseraMeshAPI values are not read yet).
        self.build_settings = build_settings or _tessera.BuildSettings()
        self.stage = stage
        self.index = render_index
        self.time = time
        self.xform_cache = UsdGeom.XformCache(time)
        self.rprims: dict[str, _Rprim] = {}
        self.instancer_of: dict[str, str] = {}
        self.materials: set[str] = set()
        self.cameras: list[str] = []
        self.lights: list[str] = []
        self.warnings: list[str] = []
        self._instanced_contexts = 0

    # -- populate ---------------------------------------------------------------------------------

    def populate(self) -> None:
        prototypes: dict[str, list[np.ndarray]] = {}
        self._visit(self.stage.GetPseudoRoot(), None, None, prototypes)
        # Native instances: each prototype is visited once, with every instance's transform stacked.
        for path, transforms in prototypes.items():
            self._visit(self.stage.GetPrimAtPath(path), np.stack(transforms), None, {})

    def _relative(self, prim: Usd.Prim, frame: Usd.Prim | None) -> np.ndarray:
        if frame is None:
            return np.asarray(self.xform_cache.GetLocalToWorldTransform(prim))
        matrix, _ = self.xform_cache.ComputeRelativeTransform(prim, frame)
        return np.asarray(matrix)

    def _visit(self, root: Usd.Prim, copies: np.ndarray | None, frame: Usd.Prim | None, prototypes) -> None:
        """Walks `root`'s subtree. `copies` (N, 4, 4) are the world transforms of `frame` for instanced
        subtrees (None for the stage itself); transforms inside are taken relative to `frame`."""
        if frame is None and copies is not None:
            frame = root
        it = iter(Usd.PrimRange(root))
        for prim in it:
            if prim.IsPseudoRoot():
                continue
            imageable = UsdGeom.Imageable(prim)
            if imageable:
                if imageable.GetVisibilityAttr().Get(self.time) == UsdGeom.Tokens.invisible:
                    it.PruneChildren()
                    continue
                purpose = imageable.GetPurposeAttr().Get()
                if purpose in (UsdGeom.Tokens.proxy, UsdGeom.Tokens.guide):
                    it.PruneChildren()
                    continue
            if prim.IsInstance():  # also a PointInstancer prototype root that is itself instanceable
                world = self._relative(prim, frame)
                if copies is None:
                    prototypes.setdefault(str(prim.GetPrototype().GetPath()), []).append(world)
                else:  # nested native instance: its own context, one per encounter
                    self._visit(prim.GetPrototype(), world[None] @ copies, None, {})
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.PointInstancer):
                self._add_point_instancer(UsdGeom.PointInstancer(prim), copies, frame)
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.Camera) and copies is None:
                self.index.insert_sprim("camera", str(prim.GetPath()))
                self.cameras.append(str(prim.GetPath()))
            elif (prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight)) and copies is None:
                kind = "distantLight" if prim.IsA(UsdLux.DistantLight) else "domeLight"
                self.index.insert_sprim(kind, str(prim.GetPath()))
                self.lights.append(str(prim.GetPath()))
            elif prim.IsA(UsdGeom.Gprim):
                if not (prim.IsA(UsdGeom.Mesh) or implicit.supported(prim)):
                    self.warnings.append(f"{prim.GetPath()}: {prim.GetTypeName()} is not drawn (not supported yet)")
                    continue
                self._add_gprim(prim, copies, frame)

    def _add_gprim(self, prim: Usd.Prim, copies: np.ndarray | None, frame: Usd.Prim | None) -> None:
        path = str(prim.GetPath())
        if copies is None:
            rprim_id, instancer_id = path, ""
            record = _Rprim(prim)
        else:
            self._instanced_contexts += 1
            instancer_id = f"/__tessera_instancer_{self._instanced_contexts}"
            rprim_id = f"{path}{{{self._instanced_contexts}}}"
            local = self._relative(prim, frame)
            record = _Rprim(prim, np.ascontiguousarray(np.swapaxes(local[None] @ copies, 1, 2)), local)
            self.instancer_of[rprim_id] = instancer_id
        self.rprims[rprim_id] = record
        for bound in [self._bound_material(prim)] + [self._bound_material(s.GetPrim()) for s in self._material_subsets(prim)]:
            if bound:
                self.materials.add(bound)
        self.index.insert_rprim("mesh", rprim_id, instancer_id)

    def _add_point_instancer(self, instancer: UsdGeom.PointInstancer, copies, frame) -> None:
        prim = instancer.GetPrim()
        path = prim.GetPath()
        prototypes = instancer.GetPrototypesRel().GetTargets()
        proto_indices = instancer.GetProtoIndicesAttr().Get(self.time)
        if proto_indices is None or len(proto_indices) == 0:
            return
        proto_indices = np.asarray(proto_indices)
        bad = (proto_indices < 0) | (proto_indices >= len(prototypes))
        if bad.any():
            self.warnings.append(f"{path}: {int(bad.sum())} protoIndices out of range (0..{len(prototypes) - 1}); those instances are skipped")
        # Per-instance transforms relative to the instancer (row vectors). The prototype root's own transform
        # is applied by visiting the prototype relative to its parent; the mask (invisibleIds) below.
        transforms = instancer.ComputeInstanceTransformsAtTime(
            self.time, self.time, UsdGeom.PointInstancer.ExcludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
        if transforms is None or len(transforms) != len(proto_indices):
            self.warnings.append(f"{path}: positions and protoIndices disagree in length; the instancer is skipped")
            return
        transforms = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
        mask = np.asarray(instancer.ComputeMaskAtTime(self.time) or [True] * len(proto_indices), dtype=bool) & ~bad
        instancer_world = self._relative(prim, frame)
        world = instancer_world[None] if copies is None else instancer_world[None] @ copies  # (C, 4, 4)
        for index, target in enumerate(prototypes):
            selected = transforms[(proto_indices == index) & mask]
            if len(selected) == 0:
                continue
            proto = self.stage.GetPrimAtPath(target)
            if not proto:
                self.warnings.append(f"{path}: prototype {target} does not exist")
                continue
            # Every instance transform times every copy of the instancer.
            proto_copies = (selected[:, None] @ world[None]).reshape(-1, 4, 4)
            self._visit(proto, proto_copies, proto.GetParent(), {})

    # -- materials ------------------------------------------------------------------------------------

    @staticmethod
    def _material_subsets(prim: Usd.Prim) -> list:
        """A mesh's GeomSubsets of family materialBind over faces, in order: subset i is material slot i + 1 (at most 255)."""
        if not prim.IsA(UsdGeom.Mesh):
            return []
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        return [s for s in subsets if s.GetElementTypeAttr().Get() == UsdGeom.Tokens.face][:255]

    def get_subset_material_ids(self, id: str) -> list[str]:
        """The material of each GeomSubset (slot 1, 2, ...): its own binding, else its mesh's (UsdShade's resolution)."""
        return [self._bound_material(s.GetPrim()) for s in self._material_subsets(self.rprims[id].prim)]

    def _bound_material(self, prim: Usd.Prim) -> str:
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not material:
            return ""
        path = str(material.GetPath())
        if path not in self.materials:
            self.index.insert_sprim("material", path)
        return path

    # -- SceneDelegate ----------------------------------------------------------------------------------

    def get_mesh(self, id: str):
        source = self._mesh_source(self.rprims[id].prim)
        source.settings = self.build_settings
        return source

    def _mesh_source(self, prim: Usd.Prim):
        if not prim.IsA(UsdGeom.Mesh):
            return implicit.mesh_source(prim, self.time)
        mesh = UsdGeom.Mesh(prim)
        t = self.time
        name = str(prim.GetPath())

        def array(attr, dtype, width=None):
            value = attr.Get(t) if attr else None
            if value is None:
                return None
            a = np.asarray(value, dtype=dtype)
            return np.ascontiguousarray(a.reshape(-1)) if width else np.ascontiguousarray(a)

        points = array(mesh.GetPointsAttr(), np.float32, 3)
        counts = array(mesh.GetFaceVertexCountsAttr(), np.int32)
        indices = array(mesh.GetFaceVertexIndicesAttr(), np.int32)
        if points is None or counts is None or indices is None:
            raise _tessera.MeshError(f"{name}: points, faceVertexCounts or faceVertexIndices is not authored")
        holes = array(mesh.GetHoleIndicesAttr(), np.int32)
        primvars = UsdGeom.PrimvarsAPI(prim)

        def primvar(primvar_name, default_interpolation, width=3):
            """(values, interpolation, indices) of an authored primvar of `width` components, else (None, default, None)."""
            pv = primvars.GetPrimvar(primvar_name)
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

        # primvars:normals wins over the normals attribute, as in UsdImaging.
        normals, normals_interp, normals_idx = primvar("normals", "vertex")
        if normals is None and mesh.GetNormalsAttr().HasAuthoredValue():
            normals, normals_interp = array(mesh.GetNormalsAttr(), np.float32, 3), mesh.GetNormalsInterpolation()
        color, color_interp, color_idx = primvar("displayColor", "constant")
        uvs, uvs_interp, uvs_idx = primvar(self.uv_primvar(prim), "faceVarying", width=2)
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
        return _tessera.mesh_source(
            name, points, counts, indices,
            hole_indices=holes,
            left_handed=mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded,
            double_sided=bool(mesh.GetDoubleSidedAttr().Get(t)),
            normals=normals, normals_interpolation=normals_interp, normals_indices=normals_idx,
            display_color=color, display_color_interpolation=color_interp, display_color_indices=color_idx,
            uvs=uvs, uvs_interpolation=uvs_interp, uvs_indices=uvs_idx, face_materials=face_materials,
            subdivision_scheme=mesh.GetSubdivisionSchemeAttr().Get(t) or "catmullClark", refine_level=self.refine_level)

    def uv_primvar(self, prim: Usd.Prim) -> str:
        """The texture coordinate set a mesh is built with: "st", the convention of UsdPreviewSurface materials."""
        return "st"

    def get_transform(self, id: str):
        return to_column_major(self.xform_cache.GetLocalToWorldTransform(self.rprims[id].prim))

    def get_visible(self, id: str) -> bool:
        record = self.rprims[id]
        if record.instance_transforms is not None:
            return True  # visibility inside prototypes was resolved while populating
        return UsdGeom.Imageable(record.prim).ComputeVisibility(self.time) != UsdGeom.Tokens.invisible

    def get_material_id(self, id: str) -> str:
        return self._bound_material(self.rprims[id].prim)

    def get_instance_transforms(self, instancer_id: str, prototype_id: str):
        return _tessera.matrix_array(self.rprims[prototype_id].instance_transforms)

    def get_material(self, id: str):
        desc = _tessera.MaterialDesc()
        material = UsdShade.Material(self.stage.GetPrimAtPath(id))
        shader = material.ComputeSurfaceSource()[0] if material else None
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            desc.use_display_color = True  # not a preview surface: fall back to the mesh's displayColor, diffuse only
            desc.diffuse_color = (0.5, 0.5, 0.5)
            desc.ior = 1.0
            return desc

        def value(name, default):
            shader_input = shader.GetInput(name)
            if not shader_input:
                return default
            source = shader_input.GetConnectedSource() if shader_input.HasConnectedSource() else None
            if source:  # textures arrive with the renderer's material issue; use the texture's fallback
                fallback = source[0].GetInput("fallback")
                v = fallback.Get() if fallback else None
                if v is None:
                    return default
                return tuple(v)[:3] if isinstance(default, tuple) else float(v if np.ndim(v) == 0 else tuple(v)[0])
            v = shader_input.Get(self.time)
            return v if v is not None else default

        desc.diffuse_color = tuple(value("diffuseColor", (0.18, 0.18, 0.18)))
        desc.emissive_color = tuple(value("emissiveColor", (0.0, 0.0, 0.0)))
        desc.opacity = float(value("opacity", 1.0))
        desc.opacity_threshold = float(value("opacityThreshold", 0.0))
        desc.metallic = float(value("metallic", 0.0))
        desc.roughness = float(value("roughness", 0.5))
        desc.use_specular_workflow = bool(value("useSpecularWorkflow", 0))
        desc.specular_color = tuple(value("specularColor", (0.0, 0.0, 0.0)))
        desc.ior = float(value("ior", 1.5))
        desc.occlusion = float(value("occlusion", 1.0))
        return desc

    def get_light(self, id: str):
        prim = self.stage.GetPrimAtPath(id)
        light = UsdLux.LightAPI(prim)
        t = self.time
        intensity = light.GetIntensityAttr().Get(t) or 0.0
        exposure = light.GetExposureAttr().Get(t) or 0.0
        color = np.asarray(light.GetColorAttr().Get(t) or (1, 1, 1), dtype=np.float64)
        desc = _tessera.LightDesc()
        radiance = color * intensity * 2.0 ** exposure
        if prim.IsA(UsdLux.DistantLight):
            # UsdLux: a distant light's intensity is the radiance of a disk `angle` degrees across; the irradiance
            # it delivers is that times the disk's solid angle, unless inputs:normalize says it already is one.
            if not light.GetNormalizeAttr().Get(t):
                half_angle = np.radians(UsdLux.DistantLight(prim).GetAngleAttr().Get(t) or 0.53) / 2.0
                radiance = radiance * 2.0 * np.pi * (1.0 - np.cos(half_angle))
            desc.radiance = tuple(float(c) for c in radiance)
            desc.type = _tessera.LightType.distant
            world = self.xform_cache.GetLocalToWorldTransform(prim)
            desc.direction = tuple(world.TransformDir(Gf.Vec3d(0, 0, -1)))  # lights emit along their -Z
        else:
            desc.radiance = tuple(float(c) for c in radiance)
            desc.type = _tessera.LightType.dome
        return desc

    def get_camera(self, id: str):
        return camera_desc(UsdGeom.Camera(self.stage.GetPrimAtPath(id)).GetCamera(self.time))


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


def framing_camera(stage: Usd.Stage, time: Usd.TimeCode, width: int, height: int):
    """The camera OpenUSD's image tests call -frameAll (testUsdImagingGLBasicDrawing): looking down the
    stage's horizontal depth axis from one bounds-diagonal away, 60 degrees vertical field of view."""
    cache = UsdGeom.BBoxCache(time, [UsdGeom.Tokens.default_, UsdGeom.Tokens.render], useExtentsHint=True)
    box = cache.ComputeWorldBound(stage.GetPseudoRoot()).ComputeAlignedRange()
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
