"""USD side of Tessera: the scene delegate over usd-core (installed as tessera.usd)."""
from .change_tracker import ChangeTracker
from .scene_delegate import UsdSceneDelegate, camera_desc, framing_camera

__all__ = ["ChangeTracker", "UsdSceneDelegate", "camera_desc", "framing_camera"]
