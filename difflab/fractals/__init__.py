"""difflab.fractals: the lecture's fractal chapter, exact and measurable.

- curves (numpy): `koch`, `koch_snowflake`, `peano`, `hilbert` (and their integer `peano_cells`,
  `hilbert_cells`), `cantor_set`, `cantor_mask`, `cantor_staircase`, `staircase_steps`,
  `staircase_measure`, `x_cos_pi_over_x`
- measures: `polyline_length`, `box_counts`, `box_counting_dimension`, `variogram`, `variogram_slope`
- terrain (numpy): `diamond_square`, `midpoint_displacement` height grids; `terrain` (a TriMesh, y up);
  `terrain_bands`, `terrain_colors`, `terrain_parts` (water / grass / rock / snow); `terrain_scene`
  writes the bands as OBJ files and returns a scene dict for `difflab.render`
- 2D sets (Warp): `mandelbrot`, `julia` (smoothly coloured images), `escape_time` (raw nu)
- 3D (Warp): `mandelbulb`, ray marched and lit by the illumination model, with shadows

Invalid arguments raise `FractalError` (a `DifflabError` and `ValueError`); image sizes and devices
raise `RenderError`, camera / light / material records `SceneError`.
"""

from ._checks import FractalError
from .cantor import cantor_mask, cantor_set, cantor_staircase, staircase_measure, staircase_steps
from .escape import escape_time, julia, mandelbrot
from .heightfield import diamond_square, midpoint_displacement, variogram, variogram_slope
from .koch import koch, koch_snowflake
from .mandelbulb import mandelbulb
from .measures import box_counting_dimension, box_counts, polyline_length
from .oscillating import x_cos_pi_over_x
from .space_filling import hilbert, hilbert_cells, peano, peano_cells
from .terrain import (TERRAIN_BANDS, TERRAIN_COLORS, TERRAIN_LEVELS, terrain, terrain_bands,
                      terrain_colors, terrain_parts)
from .terrain_scene import terrain_scene

__all__ = [
    "FractalError",
    "koch", "koch_snowflake", "peano", "peano_cells", "hilbert", "hilbert_cells",
    "cantor_set", "cantor_mask", "cantor_staircase", "staircase_steps", "staircase_measure",
    "x_cos_pi_over_x",
    "polyline_length", "box_counts", "box_counting_dimension", "variogram", "variogram_slope",
    "diamond_square", "midpoint_displacement", "terrain", "terrain_bands", "terrain_colors",
    "terrain_parts", "terrain_scene", "TERRAIN_BANDS", "TERRAIN_COLORS", "TERRAIN_LEVELS",
    "mandelbrot", "julia", "escape_time", "mandelbulb",
]
