"""The synthesis pipeline: select & paste, blend, generate views, write the dataset.

Imports run one way: ``run`` (generate) -> the executors (``local_executor``,
``ray_executor``) -> ``worker`` -> ``stages`` -> the modules each stage uses.
"""
from .run import generate
from .stages import BlendLesions, Generate2DViews, SelectAndPaste

__all__ = ["SelectAndPaste", "BlendLesions", "Generate2DViews", "generate"]
