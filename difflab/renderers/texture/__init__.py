"""Image textures: `store` loads images into mip pyramids on the device, `sampling` filters them
(nearest, bilinear, trilinear, EWA) with the screen-space footprints both renderers compute
(`footprint`).
"""
