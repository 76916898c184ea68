"""difflab.demos: the figures of `difflab demo` and the example scenes shipped with the package.

The engine (scene, geometry, lighting, renderers, fit, fractals) never imports this package; it imports
them. Sections (each `section(out, size) -> [(path, what it shows), ...]`):

- `lighting`: flat / Gouraud / Phong, the model term by term, the lecture's material table
- `textures`: texture filters on a receding checkerboard against a supersampled truth
- `raytracing`: the ray-tree depth series and glass with total internal reflection
- `fractals`: one figure per fractal kind (also `difflab fractal KIND`)

Figure helpers: `save_figure`, `image_grid`, `strip` (in `figures`). Lecture helpers the notebooks
use: `incremental_span`, `polygon_scanline_shade`, `triangle_shade`, `tiled_surface`, `edge_kinks` (Gouraud's
scan line and its defects, in `gouraud`), `wireframe` (a scene's edges in raster coordinates, in
`pipeline`), `lit_patch`, `lecture_phong_table`, `lecture_intensities`, `lecture_material`,
`LECTURE_GEOMETRY` (the illumination model measured on one patch at stated angles, in
`illumination`). Example scenes:
`example_scene(name, *, width=None, height=None)`, `scene_path(name)`, `example_names()`.
"""

from __future__ import annotations

import time
from pathlib import Path

from .examples import example_names as example_names
from .examples import example_scene as example_scene
from .examples import scene_path as scene_path
from .figures import image_grid as image_grid
from .gouraud import edge_kinks as edge_kinks
from .gouraud import incremental_span as incremental_span
from .gouraud import polygon_scanline_shade as polygon_scanline_shade
from .gouraud import tiled_surface as tiled_surface
from .gouraud import triangle_shade as triangle_shade
from .illumination import LECTURE_GEOMETRY as LECTURE_GEOMETRY
from .illumination import lecture_intensities as lecture_intensities
from .illumination import lecture_material as lecture_material
from .illumination import lecture_phong_table as lecture_phong_table
from .illumination import lit_patch as lit_patch
from .pipeline import wireframe as wireframe
from .figures import save_figure as save_figure

#: Image size (pixels) of the demo's panels: full, and with `--quick`.
DEMO_SIZE, QUICK_SIZE = 256, 96


def sections() -> list:
    """The demo's sections in the order they run."""
    from .fractals import gallery
    from .lighting import decomposition, materials_table, shading_models
    from .raytracing import ray_tracing
    from .textures import texture_figures

    return [shading_models, decomposition, materials_table, texture_figures, ray_tracing, gallery]


def run_demo(out, quick: bool = False) -> list[tuple[Path, str]]:
    """Write every section's figures to the folder `out` (created if needed) and print where they
    are and what each shows; `quick` uses QUICK_SIZE panels. Returns (path, description) pairs."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    size = QUICK_SIZE if quick else DEMO_SIZE
    written = []
    for section in sections():
        start = time.perf_counter()
        written += section(out, size)
        print(f"[{section.__module__.rsplit('.', 1)[-1]}.{section.__name__}] {time.perf_counter() - start:.1f} s",
              flush=True)
    print(f"difflab demo: {len(written)} files in {out.resolve()}")
    for path, description in written:
        print(f"  {path.name}: {description}")
    return written


__all__ = ["DEMO_SIZE", "LECTURE_GEOMETRY", "lecture_intensities", "lecture_material", "lecture_phong_table",
           "lit_patch", "QUICK_SIZE", "edge_kinks", "example_names", "example_scene", "image_grid", "incremental_span",
           "polygon_scanline_shade", "run_demo", "save_figure", "scene_path", "sections", "tiled_surface",
           "triangle_shade", "wireframe"]
