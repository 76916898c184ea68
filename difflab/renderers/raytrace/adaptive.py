"""Adaptive supersampling (Whitted 1980): trace the pixel corners, refine only where they disagree.

Every pixel's four corners are traced once (a (H + 1) x (W + 1) grid of rays, shared between
neighbours). A pixel whose corners differ by at most `threshold` (largest channel of max - min over
the four) is their mean; any other pixel is traced again on a regular `refine` x `refine` grid of
sample centres inside it and is the mean of those (each filtering its textures over its own
footprint, 1/refine of a pixel: the same values as "grid" supersampling at spp refine^2). Both
patterns are fixed, so the render is deterministic. The ray tree is not recorded here (use `raytrace` for fitting).
"""

from __future__ import annotations

import time

import numpy as np

from ...errors import RenderError
from ...guards import nonfinite_pixels
from ..frame import Frame
from .driver import trace_points


def raytrace_adaptive(compiled, settings, threshold: float = 0.05, refine: int = 4,
                      threads: int | None = None) -> Frame:
    """Ray-trace with adaptive supersampling.

    Arguments:
        compiled, settings: as for `raytrace` (spp and sampling are not used).
        threshold: corner disagreement (linear RGB, largest channel) above which a pixel is refined, >= 0.
        refine: side of the regular sample grid of a refined pixel (refine^2 samples), >= 2.

    Returns: a `Frame` (image (H, W, 3) float32, no ray tree) whose stats (rays, `shadow_rays_cut`:
    as `raytrace`'s, over both passes) add `refined_pixels`,
    `refined_fraction` and `refine_mask` (H, W) bool.
    """
    if not threshold >= 0:
        raise RenderError(f"threshold: must be >= 0, got {threshold!r}")
    if not isinstance(refine, int) or refine < 2:
        raise RenderError(f"refine: must be an integer >= 2, got {refine!r}")
    scene = compiled.scene
    width, height = scene.camera.width, scene.camera.height
    start = time.perf_counter()
    ys, xs = np.meshgrid(np.arange(height + 1, dtype=np.float32), np.arange(width + 1, dtype=np.float32), indexing="ij")
    corners = trace_points(compiled, settings, np.stack([xs, ys], -1), threads)
    c = corners.color
    quad = np.stack([c[:-1, :-1], c[:-1, 1:], c[1:, :-1], c[1:, 1:]])  # (4, H, W, 3)
    image = quad.mean(axis=0, dtype=np.float64).astype(np.float32)
    spread = (quad.max(axis=0) - quad.min(axis=0)).max(axis=-1)
    mask = ~(spread <= threshold)  # NaN corners refine too
    rays = dict(corners.rays)
    cut = corners.shadow_rays_cut
    rows, cols = np.nonzero(mask)
    if rows.size:
        offsets = (np.arange(refine) + 0.5) / refine
        oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
        pts = np.stack([cols[:, None] + ox.ravel()[None, :], rows[:, None] + oy.ravel()[None, :]], -1)
        refined = trace_points(compiled, settings, pts.astype(np.float32), threads, footprint=1.0 / refine)
        image[rows, cols] = refined.color.mean(axis=1, dtype=np.float64).astype(np.float32)
        rays = {k: rays[k] + refined.rays[k] for k in rays}
        cut += refined.shadow_rays_cut
    seconds = time.perf_counter() - start
    total = sum(rays.values())
    stats = {"method": "raytrace", "adaptive_supersampling": True, "threshold": threshold, "refine": refine,
             "seconds": seconds, "rays": rays, "total_rays": total, "rays_per_second": total / max(seconds, 1e-9),
             "shadow_rays_cut": cut, "refined_pixels": int(mask.sum()), "refined_fraction": float(mask.mean()),
             "refine_mask": mask, "nonfinite_pixels": nonfinite_pixels(image)}
    return Frame(image=image, buffers=None, stats=stats, ray_tree=None)
