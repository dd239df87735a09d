"""Tessera: a virtualized-geometry renderer for USD stages.

    import tessera
    session = tessera.Session("stage.usda")
    result = session.render(resolution=(960, 540), aovs=["color", "primId"])
    result.write("out.png")
"""
from ._tessera import DeviceError, ImageIoError, MeshError, read_image
from .build import BuildSettings, build_mesh
from .session import AOVS, VISUALIZATIONS, RenderResult, Session, StageError, ocio_config_path

__version__ = "0.1.0"
__all__ = ["Session", "RenderResult", "StageError", "DeviceError", "MeshError", "ImageIoError", "read_image", "ocio_config_path",
           "AOVS", "VISUALIZATIONS", "build_mesh", "BuildSettings"]
