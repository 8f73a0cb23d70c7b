"""Asset sources: bodies, skin conditions (lesions) and backgrounds."""
from .colour import fitzpatrick_from_ita, ita_degrees, ita_range, shades_of_gray
from .lesions import Lesion, LesionError, LesionSet, load_lesions, procedural_lesions
from .backgrounds import BackgroundError, fit_cover, load_backgrounds, procedural_backgrounds
from .bodies import Body, make_body
from .bodytex import BodyError, load_bodytex, load_mesh_body
