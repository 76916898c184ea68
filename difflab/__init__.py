"""difflab: a differentiable shading lab.

The classic illumination model (ambient + Lambert + Phong / Blinn / Torrance specular, attenuation,
coloured point, directional and spot lights) rendered by NVIDIA Warp kernels -- a rasterizer with
flat, Gouraud and Phong shading and a Whitted ray tracer -- and implemented again in JAX, so that
material coefficients can be fitted to images with optimistix.
"""

from .demos.examples import example_scene
from .errors import DifflabError, FitError, MeshError, RenderError, SceneError, TextureError
from .io import load_image, save_image
from .render.api import render, render_frame
from .render.frame import Frame, GBuffer, ShadingPoints
from .scene import Scene, load_scene, save_scene

__version__ = "0.1.0"

#: Fitting names, imported from `difflab.fit` on first use so that `import difflab` loads neither JAX
#: nor optimistix.
_FIT_NAMES = ("FitResult", "Identifiability", "fit_material", "fit_scene", "identify")


def __getattr__(name: str):
    if name in _FIT_NAMES:
        import importlib

        value = getattr(importlib.import_module(".fit", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'difflab' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_FIT_NAMES))

__all__ = [
    "DifflabError", "FitError", "FitResult", "Frame", "Identifiability", "GBuffer", "MeshError", "RenderError", "Scene", "SceneError",
    "ShadingPoints", "TextureError", "example_scene", "fit_material", "fit_scene", "identify", "load_image", "load_scene", "render", "render_frame", "save_image",
    "save_scene",
]
