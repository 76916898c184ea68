"""The names `fit_scene` and `SceneSetup` under their first module path (notebook 06 imports them
from here); both live in the one engine (`fit.py`, `setup.py`)."""

from .fit import fit_scene
from .setup import SceneSetup

__all__ = ["SceneSetup", "fit_scene"]
