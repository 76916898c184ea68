"""The Warp renderers: two ways to turn a compiled scene into a `Frame`.

    raster/     the z-buffer pipeline: stages as kernels (clip, coverage, resolve, shade) + one driver
    raytrace/   the Whitted ray tracer: kernels, driver, recorded ray tree, optics, item buffer,
                adaptive sampling
    texture/    image textures: mip pyramids on the device and the filters both renderers sample with

and what they share, beside them: `api` (render / render_frame), `compile` (scene -> device arrays
and BVH, once), `camera`, `trace` (ray queries: analytic shapes and the BVH, shadow rays), `frame`
(Frame / GBuffer / ShadingPoints) and `launch` (device choice, banded CPU launches).
Both renderers light every surface with the one illumination model of `difflab.lighting`.
"""
