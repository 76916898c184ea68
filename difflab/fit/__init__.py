"""Fitting: the illumination model in JAX on what Warp recorded once per view, solved by one engine.

`fit` (and its classic spellings `fit_material`, `fit_scene`, `fit_batch`) recovers material
coefficients (ka, kd, ks, n, m, f0, kr, kt, absorption) and light intensities from target images,
through the G-buffer ("raster") or the recorded ray tree ("raytrace") as the scene requires;
`FitOptions` says how to solve; `FitResult` reports values, standard errors, noise, chi-square and
flags. `shade_gbuffer` / `evaluate_tree` re-form a rendered image differentiably; `identify` tells
which parameters a set of views determines; `fit_texture` fits a texture's texels (views from
`texture_view`).

The names load on first use (PEP 562), so that importing `difflab.fit.command` for the command
line's parser imports neither JAX nor optimistix.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "FitOptions": "options", "SOLVERS": "options", "FitResult": "result", "fit": "engine", "fit_material": "engine",
    "fit_scene": "engine", "solve": "engine", "fit_batch": "batch", "Identifiability": "identifiability", "identify": "identifiability",
    "MaterialTable": "materials", "KINDS": "params", "DEFAULT_PARAMS": "params", "Param": "params", "evaluate_tree": "raytree",
    "tree_to_jax": "raytree", "METHODS": "arguments", "SceneSetup": "setup", "Setup": "setup",
    "shade_gbuffer": "shading", "fit_texture": "texture_fit", "texture_view": "texture_fit",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
