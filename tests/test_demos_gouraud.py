"""The lecture's scan-line shading helpers (difflab.demos.gouraud) against closed forms."""

import numpy as np
import pytest

from difflab.demos.gouraud import (edge_kinks, incremental_span, polygon_scanline_shade, span_columns, tiled_surface,
                                   triangle_shade)
from difflab.geometry import face_normals, vertex_normals


def test_span_owns_the_pixels_whose_centres_it_covers():
    np.testing.assert_array_equal(span_columns(2.3, 9.7), np.arange(2, 10))
    np.testing.assert_array_equal(span_columns(2.5, 3.5), [2])
    assert span_columns(2.6, 3.4).size == 0


@pytest.mark.parametrize("ax, bx", [(2.3, 9.7), (0.0, 17.0), (5.9, 6.6), (-1.25, 3.75)])
def test_incremental_span_equals_interpolation_at_pixel_centres(ax, bx):
    a, b = 0.2, 0.9
    columns, shades = incremental_span(ax, bx, a, b)
    exact = a + (columns + 0.5 - ax) / (bx - ax) * (b - a)
    np.testing.assert_allclose(shades, exact, atol=1e-12)
    # Without the frac(Ax) correction every pixel is off by the sub-pixel offset times the gradient.
    _, uncorrected = incremental_span(ax, bx, a, b, correct=False)
    offset = columns[0] + 0.5 - ax
    np.testing.assert_allclose(exact - uncorrected, offset * (b - a) / (bx - ax), atol=1e-12)


def rotated(xy, degrees):
    t = np.radians(degrees)
    return xy @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])


def test_scanline_interpolation_of_a_polygon_depends_on_its_orientation_triangles_do_not():
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    shades = [1.0, 0.0, 0.0, 0.0]
    centre = [[0.0, 0.0]]
    # Upright: edges give 0.5 (left) and 0 (right) at mid-height -> 0.25. As a diamond turned -45
    # degrees the centre row runs from vertex 0 (1) to vertex 2 (0) -> 0.5; turned +45 degrees from
    # vertex 3 (0) to vertex 1 (0) -> 0.
    assert polygon_scanline_shade(square, shades, centre)[0] == pytest.approx(0.25)
    assert polygon_scanline_shade(rotated(square, -45), shades, centre)[0] == pytest.approx(0.5)
    assert polygon_scanline_shade(rotated(square, 45), shades, centre)[0] == pytest.approx(0.0, abs=1e-12)
    for degrees in (0, 30, 45, 90):
        xy = rotated(square, degrees)
        assert triangle_shade(xy, shades, [[0, 1, 2], [0, 2, 3]], centre)[0] == pytest.approx(0.5)
        assert triangle_shade(xy, shades, [[0, 1, 3], [1, 2, 3]], centre)[0] == pytest.approx(0.0)
    assert np.isnan(polygon_scanline_shade(square, shades, [[2.0, 0.0]])[0])


def test_tiled_surface_has_equal_averaged_normals_inside():
    mesh = tiled_surface(tiles=4, height=0.3)
    normals = vertex_normals(mesh.vertices, mesh.faces)
    inner = np.abs(mesh.vertices[:, 0]) < 1.5 - 1e-9
    np.testing.assert_allclose(normals[inner], np.tile([0, 1.0, 0], (inner.sum(), 1)), atol=1e-12)
    tilt = face_normals(mesh.vertices, mesh.faces)[:, 0]
    assert np.all(np.abs(tilt) > 0.1) and (tilt > 0).sum() == (tilt < 0).sum()


def test_edge_kinks_measure_steps_and_slope_breaks_at_triangle_crossings():
    faces = np.array([-1, 0, 0, 0, 1, 1, 1, -1])
    step = np.array([0, 1, 1, 1, 2, 2, 2, 0.0])            # flat: a step of 1 at the crossing
    ramp = np.array([0, 0, 1, 2, 4, 6, 8, 0.0])            # Gouraud: slope 1 then 2
    line = np.array([0, 0, 1, 2, 3, 4, 5, 0.0])            # one straight line: nothing
    assert edge_kinks(step, faces).tolist() == [1.0]
    assert edge_kinks(ramp, faces).tolist() == [1.0]
    assert edge_kinks(line, faces).tolist() == [0.0]
