"""glsynth: synthetic in-the-wild dermatology images with dense annotations."""
from .camera import Camera
from .mesh import Mesh, MeshError

__version__ = "0.1.0"

__all__ = ["Camera", "Mesh", "MeshError", "__version__"]
