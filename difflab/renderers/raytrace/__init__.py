"""The Whitted ray tracer: `driver.raytrace(compiled, settings)` walks one ray tree per sample
(`kernels`), optionally records it (`tree`) for re-evaluation and fitting; `optics` holds Snell,
Fresnel and Beer, `nesting` the media a ray travels in (glass in water), `itembuffer` primary
visibility from the rasterizer's z-buffer, `adaptive` Whitted's adaptive supersampling (refine
pixels whose corners disagree).
"""
