"""The one illumination model: `warp_model` (for kernels) and `jax_model` (for fitting), same names."""

from .warp_model import FOG_MODES, LIGHT_KINDS, SPECULAR_MODELS

__all__ = ["FOG_MODES", "LIGHT_KINDS", "SPECULAR_MODELS"]
