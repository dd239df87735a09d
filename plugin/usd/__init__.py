"""USD side of Tessera: the scene delegate over usd-core (installed as tessera.usd)."""
from .scene_delegate import UsdSceneDelegate, camera_desc, framing_camera

__all__ = ["UsdSceneDelegate", "camera_desc", "framing_camera"]
