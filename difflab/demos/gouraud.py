"""Gouraud's scan-line interpolation as the lecture draws it, and two of its defects.

- `incremental_span`: shade the pixels of one span A..B by adding a constant gradient per pixel,
  starting with the lecture's sub-pixel correction (frac(Ax)).
- `polygon_scanline_shade` / `triangle_shade`: interpolation over a polygon edge-then-span (the
  result depends on the polygon's orientation on screen) against barycentric interpolation over its
  triangles (it does not).
- `tiled_surface`: the "tiled" roof whose averaged vertex normals are all equal, so that Gouraud
  shading paints it flat.
- `edge_kinks`: how sharply a scan line's intensity breaks where it crosses from one triangle to the
  next (the Mach bands of flat and Gouraud shading).
Raster convention (difflab's): pixel j covers [j, j + 1) and is sampled at its centre j + 0.5.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import TriMesh


def span_columns(ax: float, bx: float) -> np.ndarray:
    """The pixel columns j whose centres j + 0.5 lie in [ax, bx) (the pixels a span A..B owns)."""
    return np.arange(math.ceil(ax - 0.5), math.ceil(bx - 0.5))


def incremental_span(ax: float, bx: float, a_shade: float, b_shade: float, correct: bool = True):
    """Shade the span from A (x = ax, shade As) to B the lecture's way: one division, then one
    addition per pixel.

        gradient = (Bs - As) / (Bx - Ax)
        Cs = As + e * gradient,   e = (first pixel centre) - Ax   (the lecture: e = 1 - frac(Ax)
                                                                    for centres on integers)
        each next pixel: s += gradient

    `correct=False` starts at Cs = As, ignoring the sub-pixel offset e: every pixel of the span is
    then off by e * gradient. Returns (columns, shades) as numpy arrays.
    """
    columns = span_columns(ax, bx)
    gradient = (b_shade - a_shade) / (bx - ax)
    if not columns.size:
        return columns, np.zeros(0)
    offset = columns[0] + 0.5 - ax
    first = a_shade + offset * gradient if correct else a_shade
    steps = np.full(columns.size, gradient)
    steps[0] = first
    return columns, np.cumsum(steps)  # first, first + g, first + 2g, ...: repeated addition


def polygon_scanline_shade(xy, shades, points) -> np.ndarray:
    """Shades at `points` (N, 2) of a convex polygon (`xy` (K, 2) in order, vertex `shades` (K,))
    interpolated the scan-line way: along the edges to the two points where the scan line
    y = point.y crosses them, then linearly between those along the line. NaN outside the polygon."""
    xy, shades, points = np.asarray(xy, float), np.asarray(shades, float), np.asarray(points, float)
    out = np.full(len(points), np.nan)
    ends = np.roll(np.arange(len(xy)), -1)
    for k, (x, y) in enumerate(points):
        crossings = []
        for i, j in zip(range(len(xy)), ends):
            (x0, y0), (x1, y1) = xy[i], xy[j]
            if (y0 <= y < y1) or (y1 <= y < y0):  # half-open: a vertex row is counted once per edge pair
                t = (y - y0) / (y1 - y0)
                crossings.append((x0 + t * (x1 - x0), shades[i] + t * (shades[j] - shades[i])))
        if len(crossings) < 2:
            continue
        (xa, sa), (xb, sb) = sorted(crossings)[0], sorted(crossings)[-1]
        if xa <= x <= xb:
            out[k] = sa if xb == xa else sa + (x - xa) / (xb - xa) * (sb - sa)
    return out


def triangle_shade(xy, shades, faces, points) -> np.ndarray:
    """Shades at `points` (N, 2) interpolated barycentrically over the triangles `faces` (F, 3) of
    the vertices `xy` (K, 2) with `shades` (K,) -- Gouraud on triangles. NaN outside every triangle."""
    xy, shades, points = np.asarray(xy, float), np.asarray(shades, float), np.asarray(points, float)
    out = np.full(len(points), np.nan)
    for face in np.asarray(faces):
        a, b, c = xy[face]
        m = np.array([b - a, c - a]).T
        w1, w2 = np.linalg.solve(m, (points - a).T)
        inside = (w1 >= -1e-12) & (w2 >= -1e-12) & (w1 + w2 <= 1 + 1e-12)
        values = shades[face[0]] * (1 - w1 - w2) + shades[face[1]] * w1 + shades[face[2]] * w2
        out = np.where(inside & np.isnan(out), values, out)
    return out


def tiled_surface(tiles: int = 6, width: float = 3.0, depth: float = 2.0, height: float = 0.25) -> TriMesh:
    """A corrugated "tiled" roof in the xz plane: `tiles` ridges along z, each a ridge line `height`
    above the valleys, `width` wide in x and `depth` deep in z, as triangles without normals.

    Every interior ridge and valley vertex is shared by as many faces tilted by +a as by -a (the
    strips' diagonals alternate), so its averaged normal is exactly +y: all vertex normals are equal (the border lines aside), and Gouraud shading
    gives one colour where flat shading shows the tiles."""
    xs = np.linspace(-width / 2, width / 2, 2 * tiles + 1)
    ys = np.where(np.arange(xs.size) % 2 == 1, height, 0.0)
    front = np.stack([xs, ys, np.full(xs.size, depth / 2)], axis=1)
    back = front * [1, 1, -1]
    vertices = np.concatenate([front, back])
    n = xs.size
    faces = []
    for s in range(n - 1):  # diagonals alternate, so each vertex sees as many faces on either side
        if s % 2 == 0:
            faces += [[s, s + 1, s + 1 + n], [s, s + 1 + n, s + n]]
        else:
            faces += [[s, s + 1, s + n], [s + 1, s + 1 + n, s + n]]
    return TriMesh(vertices, np.array(faces), name="tiled_surface")


def edge_kinks(values, faces) -> np.ndarray:
    """|second difference| of a scan line's `values` (W,) at each crossing between two triangles
    (`faces` (W,) their ids, -1 where nothing is drawn): |(v[j+1] - v[j]) - (v[j] - v[j-1])| where
    face[j] != face[j+1] and the four pixels j-1 .. j+2 are all drawn. A step in intensity (flat
    shading) or in its slope (Gouraud) shows here; smooth shading (Phong) leaves only curvature."""
    values, faces = np.asarray(values, float), np.asarray(faces)
    j = np.arange(1, len(values) - 2)
    crossing = (faces[j] != faces[j + 1]) & (faces[j - 1] >= 0) & (faces[j + 2] >= 0) & (faces[j] >= 0) & (faces[j + 1] >= 0)
    j = j[crossing]
    return np.abs((values[j + 1] - values[j]) - (values[j] - values[j - 1]))
