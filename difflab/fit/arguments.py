"""A fit's arguments checked, and its image model chosen, before anything is rendered: what
`setup.Setup` and the command line (`command.py`, `edges.margin_masks`) decide alike. No JAX here,
so that the command line's parser imports none.

The image model: "raytrace" re-forms the Whitted ray tracer's image from each view's recorded ray
tree (`raytree.py`), "raster" the rasterizer's from its G-buffer (`shading.py`). Unless told, the
scene decides: the ray tree when the scene is ray-traced, when any material it uses has kr or kt > 0
(reflections or transparent shadows can carry a fitted material's colour to other pixels), or when a
fitted material has an image texture whose texels are not fitted; else the G-buffer. Fitted texels
go with that image model (`texels.py`: the G-buffer's samples and the ray tree's nodes both carry
the uv their texture was read at).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..errors import FitError
from ..vocabulary import METHODS


def choose_method(scene, materials, method, texels=False) -> str:
    """The image model: `method` when given, else from the scene (see the module docstring);
    `texels`: a texture is fitted (the G-buffer, unless the scene needs the ray tree)."""
    if method is not None:
        if method not in METHODS:
            raise FitError(f"method: expected one of {', '.join(METHODS)} (or None: from the scene), got {method!r}")
        return method
    used = {obj.material for obj in scene.objects}
    if scene.render.method == "raytrace" or any(scene.materials[m].kr > 0 or scene.materials[m].kt > 0 for m in used):
        return "raytrace"
    if texels:
        return "raster"
    if any(scene.materials[m].texture is not None for m in materials):
        return "raytrace"
    return "raster"


def check_ceiling(value):
    """None (detect), False (none: also inf), or a finite number > 0 as a float; FitError otherwise."""
    if value is None or value is False:
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)) and value == math.inf:
        return False
    return check_number(value, "ceiling")


def check_number(value, name, *, allow_none=False):
    """A finite number > 0 as a float (None when allowed), or FitError naming the argument."""
    if value is None and allow_none:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real) or not np.isfinite(value) or value <= 0:
        raise FitError(f"{name}: must be a finite number > 0, got {value!r}")  # (numpy scalars are numbers.Real)
    return float(value)


def check_smoothness(value, textures) -> float:
    """The texture prior's weight: a finite number >= 0, and 0 unless a texture is fitted."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise FitError(f"smoothness: must be a finite number >= 0, got {value!r}")
    if value > 0 and not textures:
        raise FitError("smoothness: a prior on texels, but no 'texture' is among the params")
    return float(value)
