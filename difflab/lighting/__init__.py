"""The one illumination model: `warp_model` (for kernels) and `jax_model` (for fitting); the terms both
compute have the same names (README lists them; `checker_cell` and `fog_blend` are the kernels' alone).

The names and integer ids they switch on (specular models, light types, fog modes, texture targets)
come from `difflab.vocabulary`; this package imports neither half, so `jax_model` loads without Warp.
"""
