"""The frame a fit renders (`renderers.api.fit_frame`): render_frame(..., image=False) without what
the fit never reads -- under Phong shading no point is lit (the fit shades the recorded light
geometry itself), uv is formed only where a texture is sampled, and neither uv derivatives nor
faces and barycentrics are formed. Every field it keeps is render_frame's; the fields it skips are
None, not zeros passed off as values, and uv is 0 where no texture is sampled, as in a ray-traced
G-buffer."""

import dataclasses

import numpy as np
import pytest

from test_raster_spheres import RED, sphere_scene, textured
from difflab import render_frame
from difflab.renderers.api import fit_frame
from difflab.renderers.frame import POINT_ROWS

SKIPPED = {"duv_dx", "duv_dy", "color", "texture_factor", "face", "bary"}  # (`raster.gbuffer.FIT_SKIPS`)


def arrays(gbuffer) -> dict:
    """Every array (or None) of a G-buffer and of its points, by name."""
    out = {f.name: getattr(gbuffer, f.name) for f in dataclasses.fields(gbuffer) if f.name != "points"}
    out.update({f.name: getattr(gbuffer.points, f.name) for f in dataclasses.fields(gbuffer.points)})
    return {k: v for k, v in out.items() if v is None or isinstance(v, np.ndarray)}


@pytest.mark.parametrize("shading, method", [("phong", "raster"), ("gouraud", "raster"), ("phong", "raytrace")])
@pytest.mark.parametrize("texture", [False, True])
def test_a_fits_frame_is_render_frames_less_what_the_fit_does_not_read(tmp_path, shading, method, texture):
    """A sphere (and a mesh quad beside it) with shadows: under rasterized Phong shading the fit's
    G-buffer equals render_frame's in every field but the points' colours and texture factors, the
    uv derivatives, the faces and barycentrics, which are None, and uv, there only on a textured
    material -- the texels it samples (textured)
    included, as they need uv and its derivatives; Gouraud frames and ray-traced ones are
    render_frame's in full."""
    quad = {"type": "mesh", "builtin": "quad", "material": "red",
            "transform": {"rotate_deg": [-90, 0, 0], "translate": [0, -0.01, 0], "scale": 3}}
    d = sphere_scene("outside", size=24, material=textured(tmp_path) if texture else RED,
                     objects=[{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}, quad])
    d["render"].update(shading=shading, method=method)
    full, fitted = render_frame(d, image=False), fit_frame(d)
    assert fitted.image is None and fitted.stats["method"] == method
    skipped = SKIPPED if (shading, method) == ("phong", "raster") else set()
    want, got = arrays(full.gbuffer), arrays(fitted.gbuffer)
    if skipped and not texture:
        assert np.abs(want["uv"]).max() > 0.5
        want["uv"] = np.zeros_like(want["uv"])
    assert want.keys() == got.keys()
    for name, value in want.items():
        if name in skipped:
            assert got[name] is None and value is not None, name
        elif name == "rows" and skipped:  # the fit's points side by side (`ShadingPoints.rows`)
            side_by_side = [want[k].reshape(len(want[k]), -1).view(np.float32) for k in POINT_ROWS]
            np.testing.assert_array_equal(got[name].view(np.int32), np.concatenate(side_by_side, 1).view(np.int32))
        elif value is None:
            assert got[name] is None, name
        else:
            np.testing.assert_array_equal(got[name], value, err_msg=name)
    if texture:
        assert np.abs(want["texture"]).max() > 0.1
    assert np.abs(want["visibility"]).min() == 0.0 and want["visibility"].max() == 1.0  # the sphere's shadow
