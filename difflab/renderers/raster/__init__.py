"""The rasterizer: vertices -> clip space -> near-plane clipping -> z-buffer -> G-buffer -> shaded image.

`driver.rasterize(compiled, settings)` launches the stages; each stage is a kernel module.
"""
