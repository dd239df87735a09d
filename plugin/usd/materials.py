"""UsdPreviewSurface networks as the renderer's MaterialDesc: the surface's constant inputs, and a texture slot for
each input driven by a UsdUVTexture (file, wrap modes, colour space, scale, bias, fallback, output channel), its st
through UsdTransform2d nodes down to a UsdPrimvarReader_float2, whose primvar is the material's UV set; and the
UsdPrimvarReaders driving colour and scalar inputs, whose primvars the mesh packs into its vertex channel
(`_channel_layout`, vertex_channel.py).

Values are followed through NodeGraph and Material interface inputs (UsdShade's value-producing attributes). Asset
paths are resolved relative to the layer that authored them; the C++ side loads the files when the material syncs.
"""

from __future__ import annotations

from dataclasses import dataclass

from pxr import Sdf, UsdShade

from tessera import _tessera

# UsdPreviewSurface inputs a UsdUVTexture may drive, with their defaults (the spec's).
_TEXTURE_INPUTS = {
    "diffuseColor": _tessera.MaterialInput.diffuseColor,
    "emissiveColor": _tessera.MaterialInput.emissiveColor,
    "specularColor": _tessera.MaterialInput.specularColor,
    "metallic": _tessera.MaterialInput.metallic,
    "roughness": _tessera.MaterialInput.roughness,
    "opacity": _tessera.MaterialInput.opacity,
    "occlusion": _tessera.MaterialInput.occlusion,
    "normal": _tessera.MaterialInput.normal,
    "displacement": _tessera.MaterialInput.displacement,
}
# Tessera's displacement settings, authored on the Material prim (defaults: MaterialDesc's). Offset along the normal =
# (displacement - center) * magnitude, mesh units; it fades out while its largest offset projects to between fadeStart
# and fadeEnd pixels. A bool tessera:displacement:bake displaces the bound meshes when they are built instead.
_DISPLACEMENT_SETTINGS = {
    "tessera:displacement:magnitude": "displacement_magnitude",
    "tessera:displacement:center": "displacement_center",
    "tessera:displacement:fadeStart": "displacement_fade_start",
    "tessera:displacement:fadeEnd": "displacement_fade_end",
}
_WRAPS = {"repeat": _tessera.TextureWrap.repeat, "mirror": _tessera.TextureWrap.mirror,
          "clamp": _tessera.TextureWrap.clamp, "black": _tessera.TextureWrap.black,
          "useMetadata": _tessera.TextureWrap.repeat}  # texture files carry no wrap metadata we read: repeat
_COLOR_SPACES = {"auto": _tessera.ColorSpace.auto, "sRGB": _tessera.ColorSpace.sRGB, "raw": _tessera.ColorSpace.raw}
_CHANNELS = {"r": _tessera.TextureChannel.r, "g": _tessera.TextureChannel.g, "b": _tessera.TextureChannel.b,
             "a": _tessera.TextureChannel.a, "rgb": _tessera.TextureChannel.rgb}
_IDENTITY_2X3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
# UsdPrimvarReader outputs: components read from the primvar (int and float read as grey by a colour input).
_READER_TYPES = {"UsdPrimvarReader_float": 1, "UsdPrimvarReader_int": 1, "UsdPrimvarReader_float2": 2,
                 "UsdPrimvarReader_float3": 3, "UsdPrimvarReader_float4": 4, "UsdPrimvarReader_normal": 3,
                 "UsdPrimvarReader_point": 3, "UsdPrimvarReader_vector": 3}


# UsdPreviewSurface inputs a UsdPrimvarReader may drive, through the mesh's vertex channel: their index in
# MaterialInput's order (the 4-bit field of MaterialDesc.vertex_inputs) and whether they are colours (3 components).
_READER_INPUTS = {"diffuseColor": (0, True), "emissiveColor": (1, True), "specularColor": (2, True), "metallic": (3, False),
                  "roughness": (4, False), "opacity": (5, False), "occlusion": (6, False)}
CHANNEL_COMPONENTS = 4  # the vertex channel: 4 components per vertex (rgba16f on the GPU)


def vertex_input(input_index: int, offset: int, rgb: bool) -> int:
    """MaterialDesc.vertex_inputs bits (TS_VERTEX_INPUT_* in shaders/shared.h): the input reads the vertex channel from
    component `offset`, 3 components (rgb) or one."""
    return (8 | (4 if rgb else 0) | offset) << (4 * input_index)


@dataclass(frozen=True)
class ChannelRead:
    """One primvar a material reads into the mesh's vertex channel: `components` (3 for a colour input, else 1) from
    component `offset`. `fallback`: the reader's, where the mesh lacks the primvar (found on the gprim, else a constant
    one inherited from an ancestor); None for the fallback surface's displayColor, read on the gprim, else inherited
    (missing: no channel, Hydra's grey)."""
    primvar: str | None
    components: int
    offset: int
    fallback: tuple | None


@dataclass(frozen=True)
class PrimvarNeeds:
    """What a mesh must read for its materials: nothing else is read or uploaded.
    `uv`: the UV set its textures read (None: no texture reads coordinates). `channel`: the primvars packed into the
    mesh's vertex channel (displayColor for a surface that is not a preview surface; the primvar readers of a preview
    surface's inputs); empty: no channel."""
    uv: str | None = None
    channel: tuple = ()


NO_MATERIAL = PrimvarNeeds(channel=(ChannelRead("displayColor", 3, 0, None),))  # Hydra's fallback surface: displayColor, else grey


def _producer(shader_input):
    """The attribute that gives an input its value: an upstream shader's output, or an input holding a value
    (through NodeGraph and Material interface connections). None when nothing is authored."""
    if not shader_input:
        return None
    attributes = shader_input.GetValueProducingAttributes()
    return attributes[0] if attributes else None


def _is_output(attribute) -> bool:
    return UsdShade.Utils.GetType(attribute.GetName()) == UsdShade.AttributeType.Output


def _four(value, default: tuple) -> tuple:
    """A float4 input as 4 floats: missing components (a float3 authored) from the default."""
    values = [float(x) for x in value][:4] if value is not None else []
    return tuple(values + list(default[len(values):]))


def _compose(outer, inner):
    """2x3 matrices (row-major, acting on (s, t, 1)): outer after inner."""
    a, b, c, d, e, f = outer
    g, h, i, j, k, l = inner
    return (a * g + b * j, a * h + b * k, a * i + b * l + c, d * g + e * j, d * h + e * k, d * i + e * l + f)


class _Reader:
    """Reads one material's network; `warnings` collects what it cannot use, naming the material."""

    def __init__(self, path: str, time, warnings: list[str]):
        self.path = path
        self.time = time
        self.warnings = warnings

    def value(self, shader, name: str, default):
        """A constant input (through interface connections); the default when unauthored or connected to a shader."""
        producer = _producer(shader.GetInput(name))
        if producer is None or _is_output(producer):
            return default
        v = producer.Get(self.time)
        return default if v is None else v

    # -- UsdUVTexture ------------------------------------------------------------------------------

    def texture_slot(self, input_name: str, texture: UsdShade.Shader, output: str):
        """(TextureSlot, primvar name or None) for a UsdUVTexture output feeding `input_name`."""
        slot = _tessera.TextureSlot()
        slot.input = _TEXTURE_INPUTS[input_name]
        where = f"{self.path}: {texture.GetPath()}"
        if output not in _CHANNELS:
            self.warnings.append(f"{where}: output '{output}' is not a UsdUVTexture output (r, g, b, a, rgb); rgb is used")
        slot.channel = _CHANNELS.get(output, _tessera.TextureChannel.rgb)
        slot.file = self.texture_file(texture, where)
        for attr, name in (("wrap_s", "wrapS"), ("wrap_t", "wrapT")):
            token = str(self.value(texture, name, "useMetadata"))
            if token not in _WRAPS:
                self.warnings.append(f"{where}: {name} '{token}' is not a wrap mode (black, clamp, repeat, mirror); repeat is used")
            setattr(slot, attr, _WRAPS.get(token, _tessera.TextureWrap.repeat))
        space = str(self.value(texture, "sourceColorSpace", "auto"))
        if space not in _COLOR_SPACES:
            self.warnings.append(f"{where}: sourceColorSpace '{space}' is not auto, sRGB or raw; auto is used")
        slot.color_space = _COLOR_SPACES.get(space, _tessera.ColorSpace.auto)
        # float4 in the spec; a float3 (a common authoring) keeps the default's fourth component.
        slot.scale = _four(self.value(texture, "scale", None), (1.0, 1.0, 1.0, 1.0))
        slot.bias = _four(self.value(texture, "bias", None), (0.0, 0.0, 0.0, 0.0))
        slot.fallback = _four(self.value(texture, "fallback", None), (0.0, 0.0, 0.0, 1.0))
        slot.transform, primvar = self.st(texture.GetInput("st"), where)
        return slot, primvar

    def texture_file(self, texture: UsdShade.Shader, where: str) -> str:
        """The absolute path of inputs:file: resolved by USD's resolver, else (a file that does not exist, which the
        resolver leaves unresolved) anchored to the layer that authored it, so that the warning names the real path."""
        producer = _producer(texture.GetInput("file"))
        asset = producer.Get(self.time) if producer is not None and not _is_output(producer) else None
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            return ""
        if "<UDIM>" in asset.path:
            self.warnings.append(f"{where}: UDIM textures ({asset.path}) are not supported; the fallback is used")
        if asset.resolvedPath:
            return asset.resolvedPath
        specs = producer.GetPropertyStack(self.time)  # strongest opinion first
        return Sdf.ComputeAssetPathRelativeToLayer(specs[0].layer, asset.path) if specs else asset.path

    def st(self, st_input, where: str):
        """(2x3 matrix, primvar name or None) of a texture's st: UsdTransform2d nodes composed down to a
        UsdPrimvarReader_float2; a constant st is a matrix that ignores its input."""
        matrix = _IDENTITY_2X3
        producer = _producer(st_input)
        for _ in range(32):  # a chain of UsdTransform2d nodes (a cycle is not valid UsdShade)
            if producer is None or not _is_output(producer):
                constant = producer.Get(self.time) if producer is not None else None
                s, t = (float(constant[0]), float(constant[1])) if constant is not None else (0.0, 0.0)
                return _compose(matrix, (0.0, 0.0, s, 0.0, 0.0, t)), None
            node = UsdShade.Shader(producer.GetPrim())
            kind = node.GetShaderId()
            if kind == "UsdTransform2d":
                rotation = float(self.value(node, "rotation", 0.0))
                scale = tuple(float(x) for x in self.value(node, "scale", (1.0, 1.0)))
                translation = tuple(float(x) for x in self.value(node, "translation", (0.0, 0.0)))
                matrix = _compose(matrix, tuple(_tessera.transform2d(rotation, scale, translation)))
                producer = _producer(node.GetInput("in"))
                continue
            if kind and kind.startswith("UsdPrimvarReader"):
                varname = self.value(node, "varname", "")
                return matrix, str(varname) if varname else None
            self.warnings.append(f"{where}: st comes from {node.GetPath()} ({kind or 'no info:id'}), which is not a primvar reader "
                                 "or UsdTransform2d; st (0, 0) is used")
            return _compose(matrix, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)), None
        return matrix, None


def material_desc(material_prim, time, warnings: list[str]):
    """The MaterialDesc of a material prim's UsdPreviewSurface (its textures not loaded yet: the material's sync
    loads them). Not a preview surface: the mesh's displayColor, diffuse only."""
    return read_material(material_prim, time, warnings)[0]


def primvar_needs(material_prim, time) -> PrimvarNeeds:
    """The primvars a mesh bound to this material must read (warnings are the material's sync's to give)."""
    return read_material(material_prim, time, [])[1]


def read_material(material_prim, time, warnings: list[str]):
    """(MaterialDesc, PrimvarNeeds) of a material prim."""
    desc = _tessera.MaterialDesc()
    material = UsdShade.Material(material_prim)
    shader = material.ComputeSurfaceSource()[0] if material else None
    if not shader or shader.GetShaderId() != "UsdPreviewSurface":
        desc.vertex_inputs = vertex_input(0, 0, True)  # not a preview surface: the mesh's displayColor, diffuse only
        desc.diffuse_color = (0.5, 0.5, 0.5)
        desc.ior = 1.0
        return desc, NO_MATERIAL
    path = str(material_prim.GetPath())
    reader = _Reader(path, time, warnings)
    slots, primvars = [], []
    readers = {}  # input -> (primvar or None, components, fallback) of the primvar reader driving it

    def value(name, default, source=shader):
        producer = _producer(source.GetInput(name))
        if producer is None:
            return default
        if not _is_output(producer):
            v = producer.Get(time)
            return default if v is None else v
        upstream = UsdShade.Shader(producer.GetPrim())
        kind = upstream.GetShaderId()
        output = UsdShade.Utils.GetBaseNameAndType(producer.GetName())[0]
        if kind == "UsdUVTexture" and name in _TEXTURE_INPUTS:
            slot, primvar = reader.texture_slot(name, upstream, output)
            slots.append(slot)
            if primvar:
                primvars.append(primvar)
        elif name in _READER_INPUTS and kind in _READER_TYPES:
            # Routed into the mesh's vertex channel (any interpolation, interpolated over the surface); where the mesh
            # lacks the primvar, the reader's fallback (the spec's default: zeros), as Storm draws it. A colour input
            # takes 3 components ((x, y, 0) from a float2; a float or int is one component, read as grey); a scalar
            # input the first.
            width = _READER_TYPES[kind]
            components = 3 if _READER_INPUTS[name][1] and width > 1 else 1
            fallback = reader.value(upstream, "fallback", None)
            fallback = [float(fallback)] if isinstance(fallback, (int, float)) else [float(x) for x in (fallback or [])]
            fallback = (fallback + [0.0] * 3)[:components]
            varname = str(reader.value(upstream, "varname", "") or "")
            readers[name] = (varname or None, components, tuple(fallback))
        else:
            warnings.append(f"{path}: {name} is connected to {upstream.GetPath()} ({kind or 'no info:id'}), which Tessera does not "
                            "evaluate; its default is used")
        return default

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
    value("normal", (0.0, 0.0, 1.0))
    _read_displacement(material, desc, value, path, time, warnings)
    desc.textures = slots
    uv = (primvars[0] if primvars else "st") if any(_reads_coordinates(slot) for slot in slots) else None
    needs = PrimvarNeeds(uv=uv, channel=_channel_layout(desc, readers, path, warnings))
    if primvars:
        desc.uv_primvar = primvars[0]
        others = sorted(set(primvars) - {primvars[0]})
        if others:
            warnings.append(f"{path}: its textures read several UV sets ({', '.join([primvars[0]] + others)}); "
                            f"only {primvars[0]} is read, for all of them")
    return desc, needs


def _channel_layout(desc, readers: dict, path: str, warnings: list[str]) -> tuple:
    """The material's vertex channel: each distinct (primvar, components, fallback) its readers read gets components of
    the channel, in input order, while they fit (CHANNEL_COMPONENTS); desc.vertex_inputs says which input reads which.
    Inputs the material ignores read nothing: metallic or specularColor by the workflow, opacity without a threshold
    (there is no blending)."""
    ignored = {"specularColor" if not desc.use_specular_workflow else "metallic"}
    if not desc.opacity_threshold > 0:
        ignored.add("opacity")
    reads, placed, used = [], {}, 0
    for name in _READER_INPUTS:  # input order: diffuseColor first
        if name not in readers or name in ignored:
            continue
        primvar, components, fallback = readers[name]
        key = (primvar, components, fallback)
        if key not in placed:
            if used + components > CHANNEL_COMPONENTS:
                warnings.append(f"{path}: {name} is read from primvar {primvar} but the mesh's vertex channel holds "
                                f"{CHANNEL_COMPONENTS} components, which earlier inputs fill; its default is used")
                continue
            placed[key] = used
            reads.append(ChannelRead(primvar, components, used, fallback))
            used += components
        desc.vertex_inputs |= vertex_input(_READER_INPUTS[name][0], placed[key], components == 3)
    return tuple(reads)


def _reads_coordinates(slot) -> bool:
    """Whether a texture slot reads the mesh's UVs: a constant st is a matrix whose linear part is zero."""
    return any(slot.transform[i] != 0.0 for i in (0, 1, 3, 4))


def _read_displacement(material, desc, value, path: str, time, warnings: list[str]) -> None:
    """UsdPreviewSurface displacement, as Storm reads it: the `displacement` input of the preview surface the material's
    displacement output is connected to (nothing displaces without that connection), constant or from a UsdUVTexture;
    then the material's tessera:displacement:* settings."""
    source = material.ComputeDisplacementSource()[0]
    if not source:
        return
    if source.GetShaderId() != "UsdPreviewSurface":
        warnings.append(f"{path}: its displacement output comes from {source.GetPath()} ({source.GetShaderId() or 'no info:id'}), "
                        "not a UsdPreviewSurface; nothing is displaced")
        return
    desc.displacement = float(value("displacement", 0.0, source))
    prim = material.GetPrim()
    for attribute, field in _DISPLACEMENT_SETTINGS.items():
        attr = prim.GetAttribute(attribute)
        v = attr.Get(time) if attr else None
        if v is None:
            continue
        try:
            number = float(v)
        except (TypeError, ValueError):
            warnings.append(f"{path}: {attribute} must be a number, not {v!r}; the default is used")
            continue
        if number != number or number in (float("inf"), float("-inf")):
            warnings.append(f"{path}: {attribute} is {number}; the default is used")
            continue
        setattr(desc, field, number)
    bake = prim.GetAttribute("tessera:displacement:bake")
    if bake and bake.Get(time) is not None:
        desc.displacement_bake = bool(bake.Get(time))
