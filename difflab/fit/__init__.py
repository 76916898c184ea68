"""Fitting: the illumination model in JAX on Warp's G-buffers, solved with optimistix.

`fit_material` recovers material coefficients (ka, kd, ks, n, and m, f0, light intensities) from
target images; `shade_gbuffer` re-forms a rasterized image from its G-buffer, differentiably.
"""

from .batch import fit_batch
from .fit import Setup, fit_material, solve
from .params import Param
from .result import FitResult
from .shading import MaterialTable, shade_gbuffer
from .solve import SOLVERS

__all__ = ["FitResult", "MaterialTable", "Param", "SOLVERS", "Setup", "fit_batch", "fit_material", "shade_gbuffer",
           "solve"]

# Issue 7: fitting through the recorded ray tree (reflections, refractions, several materials at once)
from .identify import Identifiability, identify  # noqa: E402
from .raytree import TreeMaterials, evaluate_tree, tree_to_jax  # noqa: E402
from .scene_fit import SceneSetup, fit_scene  # noqa: E402

__all__ += ["Identifiability", "SceneSetup", "TreeMaterials", "evaluate_tree", "fit_scene", "identify", "tree_to_jax"]
