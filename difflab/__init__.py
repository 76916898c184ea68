"""difflab: a differentiable shading lab.

The classic illumination model (ambient + Lambert + Phong / Blinn / Torrance specular, attenuation,
coloured point, directional and spot lights) rendered by NVIDIA Warp kernels -- a rasterizer with
flat, Gouraud and Phong shading and a Whitted ray tracer -- and implemented again in JAX, so that
material coefficients can be fitted to images with optimistix.

The names below are the public API (`docs/api.md`). Public subpackages: `difflab.scene`,
`difflab.geometry`, `difflab.fractals`, `difflab.fit`, `difflab.demos`, `difflab.vocabulary`,
`difflab.errors`, `difflab.io`; every other module is internal and may change. The fitting names
(`fit_material`, `fit_scene`, `identify`, `FitResult`, `Identifiability`) are imported from
`difflab.fit` on first use, so `import difflab` loads neither JAX nor optimistix.
"""

from .batch import fit_many as fit_many
from .demos.examples import example_scene as example_scene
from .errors import DifflabError as DifflabError
from .errors import FitError as FitError
from .errors import MeshError as MeshError
from .errors import OutputError as OutputError
from .errors import RenderError as RenderError
from .errors import SceneError as SceneError
from .errors import TextureError as TextureError
from .io import load_image as load_image
from .io import save_image as save_image
from .renderers.api import render as render
from .renderers.api import render_frame as render_frame
from .renderers.compile import CompiledScene as CompiledScene
from .renderers.compile import compile_scene as compile_scene
from .renderers.frame import Frame as Frame
from .renderers.frame import GBuffer as GBuffer
from .renderers.frame import ShadingPoints as ShadingPoints
from .scene import Camera as Camera
from .scene import Checker as Checker
from .scene import Fog as Fog
from .scene import Light as Light
from .scene import Material as Material
from .scene import Mesh as Mesh
from .scene import Plane as Plane
from .scene import RenderSettings as RenderSettings
from .scene import Scene as Scene
from .scene import Sphere as Sphere
from .scene import Transform as Transform
from .scene import load_scene as load_scene
from .scene import save_scene as save_scene

__version__ = "0.1.0"

#: Public names of `difflab.fit`, imported on first use (module `__getattr__`, PEP 562).
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
    # scenes
    "Scene", "Camera", "Light", "Material", "Checker", "Sphere", "Plane", "Mesh", "Transform", "Fog",
    "RenderSettings", "load_scene", "save_scene", "example_scene",
    # rendering
    "render", "render_frame", "compile_scene", "CompiledScene", "Frame", "GBuffer", "ShadingPoints",
    # images
    "load_image", "save_image",
    # fitting (lazy)
    "fit_material", "fit_scene", "identify", "FitResult", "Identifiability", "fit_many",
    # errors
    "DifflabError", "SceneError", "MeshError", "TextureError", "RenderError", "FitError", "OutputError",
]
