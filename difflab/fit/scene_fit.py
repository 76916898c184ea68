"""The names `fit_scene` and `SceneSetup` under their first module path (notebook 06 imports them
from here); both live in the one engine (`engine.py`, `setup.py`)."""

from .engine import fit_scene
from .setup import SceneSetup

__all__ = ["SceneSetup", "fit_scene"]
