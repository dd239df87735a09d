"""Tessera: a virtualized-geometry renderer for USD stages.

    import tessera
    session = tessera.Session("stage.usda")
    result = session.render(resolution=(960, 540), aovs=["color", "primId"])
    result.write("out.png")
"""
import os as _os
import sys as _sys

# The TesseraMeshAPI schema (tessera/schema/plugInfo.json) is found through PXR_PLUGINPATH_NAME, which pxr reads
# when it first loads its plugins: add our folder before anything imports pxr. When pxr is loaded already, register
# the folder with its plugin registry directly (that works until USD first uses its schema registry; after that,
# meshes that apply the schema get a warning). A pipeline may put the same folder (tessera.SCHEMA_PATH) on
# PXR_PLUGINPATH_NAME itself, for tools that never import tessera.
SCHEMA_PATH = _os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "schema")
_plugin_paths = [p for p in _os.environ.get("PXR_PLUGINPATH_NAME", "").split(_os.pathsep) if p]
if SCHEMA_PATH not in _plugin_paths:
    _os.environ["PXR_PLUGINPATH_NAME"] = _os.pathsep.join([SCHEMA_PATH] + _plugin_paths)
if "pxr" in _sys.modules:
    from pxr import Plug as _Plug

    _Plug.Registry().RegisterPlugins(SCHEMA_PATH)  # registering twice does nothing

import atexit as _atexit

from ._tessera import DeviceError, ImageIoError, MeshError, pixel_sample_offset, read_image
from ._tessera import release_shared_devices as _release_shared_devices
from .build import BuildSettings, build_mesh
from .session import AOVS, PIXEL_FILTERS, VISUALIZATIONS, RenderResult, Session, StageError, ocio_config_path

# Sessions share the process's device and its compiled pipelines (only the first one waits for them); they must be
# destroyed while Python is still whole, not by static destruction after the Vulkan driver may be gone.
_atexit.register(_release_shared_devices)

__version__ = "0.1.0"
__all__ = ["SCHEMA_PATH", "Session", "RenderResult", "StageError", "DeviceError", "MeshError", "ImageIoError", "read_image", "pixel_sample_offset", "ocio_config_path",
           "AOVS", "VISUALIZATIONS", "PIXEL_FILTERS", "build_mesh", "BuildSettings"]
