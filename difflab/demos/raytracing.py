"""The ray tracer's demo figures: the lecture's "ray tree depth" series and glass with total internal
reflection. `demo_figures(out_dir)` writes them and returns (path, description) pairs.

The scenes are the example scenes "lecture_teapot" and "glass_sphere" shipped in the package
(`difflab.example_scene(name)`; the files `difflab.demos.scene_path(name)` that
`difflab render FILE --method raytrace` renders).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io import save_image
from ..renderers.compile import compile_scene
from ..renderers.raytrace.driver import raytrace
from .examples import example_scene
from .figures import strip


def depth_series(out: Path, width: int = 240, height: int = 180, depths=range(1, 8)) -> list[tuple[Path, str]]:
    """The chrome teapot and mirror at ray-tree depths 1..7, one strip (left to right)."""
    scene = example_scene("lecture_teapot", width=width, height=height)
    compiled = compile_scene(scene)
    images, counts = [], []
    for depth in depths:
        frame = raytrace(compiled, scene.with_overrides(render={"max_depth": depth}).render, record_tree=False)
        images.append(frame.image)
        counts.append(frame.stats["total_rays"])
    path = save_image(out / "raytrace_depth_series.png", strip(images))
    change = [float(np.abs(b - a).mean()) for a, b in zip(images, images[1:])]
    return [(path, f"ray tree depth {depths[0]}..{depths[-1]} (left to right): chrome teapot and mirror on a shiny "
                   f"checker floor, shadows, 2 point lights; rays per frame {counts}; mean change per extra level "
                   + ", ".join(f"{c:.4f}" for c in change))]


def glass(out: Path, width: int = 240, height: int = 180) -> list[tuple[Path, str]]:
    """A glass sphere and a glass cube: refraction, Fresnel reflection, Beer absorption, and a map of
    the pixels whose ray tree meets total internal reflection."""
    scene = example_scene("glass_sphere", width=width, height=height)
    frame = raytrace(compile_scene(scene), scene.render)
    tree = frame.ray_tree
    kt = np.array([scene.materials[name].kt for name in scene.material_names])
    hit = tree.material >= 0
    tir_node = hit & (kt[np.maximum(tree.material, 0)] > 0) & (tree.fresnel_t == 0.0)
    n_samples = tree.sample_offset.size - 1
    tir = np.bincount(tree.sample[tir_node], minlength=n_samples).reshape(tree.grid_shape) > 0
    side = tree.spp_side
    tir_pixels = tir.reshape(height, side, width, side).any(axis=(1, 3))
    overlay = 0.35 * frame.image.copy()
    overlay[tir_pixels] = [1.0, 0.15, 0.05]
    path = save_image(out / "raytrace_glass.png", strip([frame.image, overlay]))
    objects = [type(o).__name__.lower() for o in scene.objects]
    where = np.bincount(tree.object[tir_node], minlength=len(objects))
    events = ", ".join(f"{n} in {objects[k]} {k}" for k, n in enumerate(where) if n)
    return [(path, f"glass sphere (left) and glass cube (ior 1.5, exact Fresnel, Beer absorption), depth "
                   f"{scene.render.max_depth}; right: pixels whose ray tree meets total internal reflection "
                   f"anywhere ({tir_pixels.mean():.1%}; TIR events: {events or 'none'} -- a sphere never traps "
                   f"light that enters it from outside, every chord meets its surface at the entry angle)")]


def demo_figures(out_dir, width: int = 240, height: int = 180) -> list[tuple[Path, str]]:
    """Write the ray tracer's figures to `out_dir`; returns (path, description) pairs."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return depth_series(out, width, height) + glass(out, width, height)


def ray_tracing(out: Path, size: int) -> list[tuple[Path, str]]:
    """`difflab demo` section: the figures at size x 3/4 size."""
    return demo_figures(out, size, size * 3 // 4)
