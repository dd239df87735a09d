"""Per-mesh build settings from the TesseraMeshAPI schema (plugin/schema/schema.usda) over the render's defaults."""

from __future__ import annotations

from pxr import Usd

from tessera import _tessera

API = "TesseraMeshAPI"

# TesseraMeshAPI attribute -> BuildSettings keyword (tessera.build_mesh's).
ATTRIBUTES = {
    "tessera:preserveArea": "preserve_area",
    "tessera:trimRelativeError": "trim_relative_error",
    "tessera:keepTrianglePercent": "keep_triangle_percent",
    "tessera:positionPrecision": "position_precision",
    "tessera:fallbackRelativeError": "fallback_relative_error",
    "tessera:fallbackTrianglePercent": "fallback_triangle_percent",
    "tessera:maxEdgeLengthFactor": "max_edge_length_factor",
}


def registered() -> bool:
    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API) is not None


class SettingsReader:
    """Reads each mesh's settings; says once when meshes apply the schema but USD has not registered it."""

    def __init__(self):
        self._unregistered_reported = False

    def __call__(self, prim: Usd.Prim, defaults: _tessera.BuildSettings, time: Usd.TimeCode, warnings: list[str]):
        """The settings `prim` is built with: its authored TesseraMeshAPI attributes over `defaults` (an attribute
        that is not authored takes the render's default, not the schema's fallback). An invalid value is a warning
        naming the prim and the attribute, and that setting keeps the default."""
        # The authored apiSchemas list, which holds the name even when the schema is not registered.
        if not (prim.HasAPI(API) or API in prim.GetPrimTypeInfo().GetAppliedAPISchemas()):
            stray = [p.GetName() for p in prim.GetAuthoredPropertiesInNamespace("tessera") if p.GetName() in ATTRIBUTES]
            if stray:
                warnings.append(f"{prim.GetPath()}: {', '.join(stray)} authored without {API} applied; ignored (apply the schema)")
            return defaults
        if not self._unregistered_reported and not registered():
            import tessera

            self._unregistered_reported = True
            warnings.append(f"{prim.GetPath()}: {API} is applied but USD has not registered it (pxr loaded its schemas before "
                            f"tessera was imported): its authored values are read, USD shows no fallbacks; import tessera first, "
                            f"or put {tessera.SCHEMA_PATH} on PXR_PLUGINPATH_NAME")
        settings = defaults
        for name, keyword in ATTRIBUTES.items():
            attribute = prim.GetAttribute(name)
            if not (attribute and attribute.HasAuthoredValue()):
                continue
            value = attribute.Get(time)
            try:
                settings = settings.replace(**{keyword: value})
            except (ValueError, TypeError, RuntimeError) as error:
                reason = str(error).replace(f"build setting {keyword}", "it") if isinstance(error, ValueError) else f"{value!r} is not a usable value"
                default = defaults.as_dict()[keyword]
                warnings.append(f"{prim.GetPath()}: {name} = {value!r}: {reason}; the mesh is built with the default "
                                f"({'automatic' if default is None else default})")
        return settings
