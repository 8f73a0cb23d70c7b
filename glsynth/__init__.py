"""glsynth: synthetic in-the-wild dermatology images with dense annotations.

    import glsynth as gs
    mesh = gs.Mesh.load("body.obj")
    cam = gs.Camera.from_surface(point, normal, w=0.5)
    out = gs.Renderer(512, 512).render(mesh, cam, passes=("gbuffer", "rgb"))
"""
import importlib

from .camera import Camera
from .errors import MeshError
from .lighting import Material, PointLight
from .mesh import Mesh

__version__ = "0.1.0"

__all__ = ["Camera", "Material", "Mesh", "MeshError", "PointLight", "Renderer", "diff",
           "assets", "__version__"]

_LAZY = {"Renderer": ("glsynth.gl.renderer", "Renderer"),
         "vertex_label_image": ("glsynth.gl.renderer", "vertex_label_image"),
         "diff": ("glsynth.diff", None),
         "assets": ("glsynth.assets", None),
         "pipeline": ("glsynth.pipeline", None),
         "load_config": ("glsynth.config", "load_config"),
         "SelectAndPaste": ("glsynth.pipeline", "SelectAndPaste"),
         "BlendLesions": ("glsynth.pipeline", "BlendLesions"),
         "Generate2DViews": ("glsynth.pipeline", "Generate2DViews"),
         "SynthDataset": ("glsynth.dataset", "SynthDataset")}


def __getattr__(name):
    # GL and torch load on first use, so `import glsynth` stays light.
    if name in _LAZY:
        module, attr = _LAZY[name]
        mod = importlib.import_module(module)
        return mod if attr is None else getattr(mod, attr)
    raise AttributeError(f"module 'glsynth' has no attribute {name!r}")
