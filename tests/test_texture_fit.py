"""Texture fitting: a kd texture of unknowns recovered from rendered images (noise-free)."""

import numpy as np
import pytest

from difflab import FitError, render_frame
from difflab.fit.texture_fit import fit_texture, texture_taps, texture_view
from difflab.renderers.api import as_scene


def quad_scene(texture_path, eye=(0, 0, 3), size=72, filter="bilinear"):
    return as_scene({
        "camera": {"eye": list(eye), "target": [0, 0, 0], "fov_y": 40, "width": size, "height": size},
        "ambient": [0.1, 0.1, 0.1],
        "lights": [{"type": "point", "position": [1, 2, 4], "intensity": [1, 1, 1]},
                   {"type": "directional", "direction": [0, 0, -1], "intensity": [0.3, 0.3, 0.3]}],
        "materials": {"m": {"ka": 0.2, "kd": 1, "ks": 0.3, "n": 20, "texture": str(texture_path),
                            "filter": filter, "wrap": "clamp"}},
        "objects": [{"type": "mesh", "builtin": "quad", "material": "m", "transform": {"rotate_deg": [90, 0, 0],
                                                                                        "scale": 2.0}}],
        "render": {"shadows": False}})


@pytest.fixture(scope="module")
def truth(tmp_path_factory):
    texels = np.random.default_rng(3).uniform(0.1, 0.9, (24, 24, 3)).astype(np.float32)
    path = tmp_path_factory.mktemp("fit") / "truth.npy"
    np.save(path, texels)
    return texels, path


@pytest.mark.parametrize("solver", ["lm", "gauss_newton"])
def test_a_kd_texture_is_recovered_from_noise_free_renders(truth, solver):
    texels, path = truth
    views = []
    for eye in [(0, 0, 3), (0.8, 0.4, 2.8)]:
        scene = quad_scene(path, eye)
        frame = render_frame(scene)
        views.append(texture_view(frame.gbuffer, frame.image, scene, "m", texels.shape[:2]))
    result = fit_texture(views, texels.shape[:2], solver=solver, init=0.5)
    assert result.result == "successful" and result.converged
    assert result.n_params == 24 * 24 * 3
    assert result.visible.mean() > 0.95
    assert np.abs(result.texture - texels)[result.visible].max() < 1e-3
    assert result.rmse < 1e-5


def test_the_smoothness_prior_fills_unseen_texels(truth):
    """Only the left half of the texture is visible (a mask keeps the pixels whose taps all read
    its left half): without a prior the unseen texels stay at the start value; with one they are
    finite and near their seen neighbours."""
    texels, path = truth
    scene = quad_scene(path, eye=(0, 0, 3))
    frame = render_frame(scene)
    taps, _ = texture_taps(frame.gbuffer.uv.reshape(-1, 2), (24, 24), "bilinear", "clamp")
    u_left = (taps % 24 < 12).all(axis=1).reshape(frame.gbuffer.material.shape) & (frame.gbuffer.material == 0)
    assert 0.2 < u_left.mean() < 0.5
    view = texture_view(frame.gbuffer, frame.image, scene, "m", texels.shape[:2], mask=u_left)
    plain = fit_texture([view], (24, 24), init=0.5)
    smooth = fit_texture([view], (24, 24), init=0.5, smoothness=1e-3, rtol=1e-8, atol=1e-8)
    assert plain.converged and smooth.converged
    assert not plain.visible[:, 14:].any()
    np.testing.assert_allclose(plain.texture[:, 14:], 0.5)
    assert np.all(np.isfinite(smooth.texture))
    assert np.abs(smooth.texture - texels)[plain.visible].max() < 0.05


def test_failure_is_a_value_and_throw_raises(truth):
    texels, path = truth
    scene = quad_scene(path)
    frame = render_frame(scene)
    view = texture_view(frame.gbuffer, frame.image, scene, "m", texels.shape[:2])
    result = fit_texture([view], (24, 24), max_steps=1)
    assert result.result == "nonlinear_max_steps_reached" and not result.converged
    with pytest.raises(FitError, match="did not converge"):
        fit_texture([view], (24, 24), max_steps=1, throw=True)


def test_bad_inputs_raise_fit_error(truth):
    texels, path = truth
    scene = quad_scene(path)
    frame = render_frame(scene, shading="gouraud")
    with pytest.raises(FitError, match="Phong"):
        texture_view(frame.gbuffer, frame.image, scene, "m", (24, 24))
    frame = render_frame(scene)
    with pytest.raises(FitError, match="material"):
        texture_view(frame.gbuffer, frame.image, scene, "nope", (24, 24))
    with pytest.raises(FitError, match="filter"):
        texture_taps(np.zeros((1, 2)), (4, 4), "ewa", "repeat")


def test_taps_match_the_warp_bilinear_filter():
    from difflab.renderers.texture.store import TextureStore, sample

    rng = np.random.default_rng(4)
    image = rng.random((5, 9, 3)).astype(np.float32)
    uv = rng.uniform(-2, 2, (300, 2)).astype(np.float32)
    store = TextureStore.from_images([image])
    flat = np.flipud(image).reshape(-1, 3)
    for filter in ("nearest", "bilinear"):
        for wrap in ("repeat", "clamp", "mirror"):
            index, weight = texture_taps(uv, (5, 9), filter, wrap)
            want = sample(store, 0, uv, filter=filter, wrap=wrap)
            np.testing.assert_allclose((weight[..., None] * flat[index]).sum(axis=1), want, atol=2e-6)


@pytest.mark.parametrize("linear_solver", ["cg", "dense"])
def test_a_texel_fit_with_a_view_at_weight_0_is_the_fit_of_the_other_view(tmp_path, linear_solver):
    """Two views of the textured quad, the second at weight 0 everywhere (no used pixel: its model
    keeps one dummy point): the texels come out as the first view's alone fits them. (The direct
    formation's gain per residual -- 2700 -- was multiplied by the points' values -- 2703 with the
    dummy: TypeError in the solve.)"""
    from difflab.fit import Setup, solve

    truth = np.random.default_rng(11).uniform(0.2, 0.8, (8, 8, 3)).astype(np.float32)
    np.save(tmp_path / "t.npy", truth)
    scene = quad_scene(tmp_path / "t.npy", size=32)
    target = render_frame(scene).image + np.random.default_rng(1).normal(0, 0.02, (32, 32, 3)).astype(np.float32)
    ones, zeros = np.ones((32, 32, 3), np.float32), np.zeros((32, 32, 3), np.float32)
    both = solve(Setup(scene, [target, target], "m", ("texture",), weights=[ones, zeros]), linear_solver=linear_solver)
    alone = solve(Setup(scene, [target], "m", ("texture",), weights=[ones]), linear_solver=linear_solver)
    assert both.converged and alone.converged
    np.testing.assert_allclose(both.texture, alone.texture, rtol=1e-5, atol=1e-6)
