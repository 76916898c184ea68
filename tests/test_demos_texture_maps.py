"""The texture -> screen chain as one projective map (difflab.demos.texture_maps)."""

import numpy as np

import difflab
from difflab.demos import apply_projective, checker_texture, mip_pyramid, texture_to_object, texture_to_screen
from difflab.geometry import quad


def test_texture_to_object_reproduces_every_vertex():
    mesh = quad(size=(2.0, 3.0), center=(1, 2, 3), normal=(0, 0, 1), divisions=3)
    to = texture_to_object(mesh)
    np.testing.assert_allclose(np.c_[mesh.uvs, np.ones(len(mesh.uvs))] @ to.T, mesh.vertices, atol=1e-12)


def test_inverse_projective_map_gives_the_rasterizers_uv(tmp_path):
    scene = difflab.Scene.from_dict({
        "camera": {"eye": [0.4, 1.5, 2.5], "target": [0, 0, 0], "fov_y": 40, "width": 40, "height": 30},
        "lights": [], "ambient": [1, 1, 1], "materials": {"m": {"ka": [1, 1, 1]}},
        "objects": [{"type": "mesh", "builtin": "quad", "material": "m",
                     "transform": {"rotate_deg": [0, 25, 0], "scale": 2.0}}],
        "render": {"method": "raster", "shadows": False}})
    g = difflab.render_frame(scene).gbuffer
    rows, cols = np.nonzero(g.mask)
    uv = apply_projective(np.linalg.inv(texture_to_screen(scene)), np.c_[cols + 0.5, rows + 0.5])
    assert len(rows) > 200
    np.testing.assert_allclose(uv, g.uv[rows, cols], atol=2e-4)


def test_mip_pyramid_halves_and_keeps_the_mean():
    levels = mip_pyramid(checker_texture(16, 4))
    assert [lv.shape[:2] for lv in levels] == [(16, 16), (8, 8), (4, 4), (2, 2), (1, 1)]
    np.testing.assert_allclose([lv.mean() for lv in levels], levels[0].mean(), rtol=1e-6)
