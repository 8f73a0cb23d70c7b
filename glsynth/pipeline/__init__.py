"""The synthesis pipeline: select & paste, blend, generate views, write the dataset."""
from .stages import BlendLesions, Generate2DViews, SelectAndPaste, generate

__all__ = ["SelectAndPaste", "BlendLesions", "Generate2DViews", "generate"]
