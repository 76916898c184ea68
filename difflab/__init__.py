"""difflab: a differentiable shading lab.

The classic illumination model (ambient + Lambert + Phong / Blinn / Torrance specular, attenuation,
coloured point, directional and spot lights) rendered by NVIDIA Warp kernels -- a rasterizer with
flat, Gouraud and Phong shading and a Whitted ray tracer -- and implemented again in JAX, so that
material coefficients can be fitted to images with optimistix.

The names below are the public API (`docs/api.md`). Public subpackages: `difflab.scene`,
`difflab.geometry`, `difflab.fractals`, `difflab.fit`, `difflab.demos`, `difflab.vocabulary`,
`difflab.errors`, `difflab.io`; every other module is internal and may change. The rendering names
(`render`, `render_frame`, `compile_scene`, `CompiledScene`, `Frame`, `GBuffer`, `ShadingPoints`,
`RayTree`, `example_scene`) and the fitting names (`fit_material`, `fit_scene`, `identify`, `FitResult`,
`Identifiability`, `interior_mask`) are imported on first use, so `import difflab` loads neither Warp nor JAX.
"""

from .batch import fit_many as fit_many
from .errors import DifflabError as DifflabError
from .errors import FitError as FitError
from .errors import MeshError as MeshError
from .errors import OutputError as OutputError
from .errors import RenderError as RenderError
from .errors import SceneError as SceneError
from .errors import TextureError as TextureError
from .io import load_image as load_image
from .io import save_image as save_image
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

#: Public names imported on first use (module `__getattr__`, PEP 562), by the module that holds them:
#: the renderers load Warp and the fitting names load JAX, neither of which `import difflab` needs.
_LAZY = {
    "render": ".renderers.api", "render_frame": ".renderers.api",
    "CompiledScene": ".renderers.compile", "compile_scene": ".renderers.compile",
    "Frame": ".renderers.frame", "GBuffer": ".renderers.frame", "ShadingPoints": ".renderers.frame",
    "RayTree": ".renderers.raytrace.tree",
    "example_scene": ".demos.examples",
    "FitResult": ".fit", "Identifiability": ".fit", "fit_material": ".fit", "fit_scene": ".fit", "identify": ".fit",
    "interior_mask": ".fit.edges",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'difflab' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    # scenes
    "Scene", "Camera", "Light", "Material", "Checker", "Sphere", "Plane", "Mesh", "Transform", "Fog",
    "RenderSettings", "load_scene", "save_scene", "example_scene",
    # rendering
    "render", "render_frame", "compile_scene", "CompiledScene", "Frame", "GBuffer", "ShadingPoints", "RayTree",
    # images
    "load_image", "save_image",
    # fitting (lazy)
    "fit_material", "fit_scene", "identify", "FitResult", "Identifiability", "fit_many", "interior_mask",
    # errors
    "DifflabError", "SceneError", "MeshError", "TextureError", "RenderError", "FitError", "OutputError",
]
