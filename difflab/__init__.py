"""difflab: a differentiable shading lab.

The classic illumination model (ambient + Lambert + Phong / Blinn / Torrance specular, attenuation,
coloured point, directional and spot lights) rendered by NVIDIA Warp kernels -- a rasterizer with
flat, Gouraud and Phong shading and a Whitted ray tracer -- and implemented again in JAX, so that
material coefficients can be fitted to images with optimistix.
"""

from .errors import DifflabError, FitError, MeshError, RenderError, SceneError, TextureError
from .fit import FitResult, Identifiability, fit_material, fit_scene, identify
from .io import load_image, save_image
from .render.api import render, render_frame
from .render.frame import Frame, GBuffer, ShadingPoints
from .scene import Scene, load_scene, save_scene

__version__ = "0.1.0"

__all__ = [
    "DifflabError", "FitError", "FitResult", "Frame", "Identifiability", "GBuffer", "MeshError", "RenderError", "Scene", "SceneError",
    "ShadingPoints", "TextureError", "fit_material", "fit_scene", "identify", "load_image", "load_scene", "render", "render_frame", "save_image",
    "save_scene",
]
