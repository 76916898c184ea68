"""Texels fitted through the recorded ray tree: the tree's nodes carry the uv their texture was read
at, the JAX tree image samples the fitted texels there as the Warp ray tracer did (nearest /
bilinear, repeat wrap), and `fit_material(..., ("texture", ...))` on a ray-traced scene -- a textured
floor seen directly and in a mirror sphere -- recovers them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import scene_dict
from jax.test_util import check_grads
from test_fit_texels import assert_same_stderr

from difflab import Scene, render_frame
from difflab.fit import Setup, fit_batch, fit_material, solve
from difflab.fit.matfree import linearisation
from difflab.fit.sparse_jacobian import sparse_jacobian
from difflab.fit.texels import texel_linearisation

W, H = 40, 32


def textured_scene(tmp_path, texels, filter="bilinear", name="floor.npy") -> Scene:
    """A ray-traced floor (plane, uv = world (x, -z): the texture repeats every unit) whose kd the
    texture `texels` modulates, a mirror sphere (kr 0.7) that shows it, and a ball with a texture of
    its own (trilinear, on ks: not fitted, its recorded texels stay); shadows on, depth 3."""
    np.save(tmp_path / name, np.asarray(texels, np.float32))
    ball = np.random.default_rng(9).uniform(0.2, 1.0, (4, 4, 3)).astype(np.float32)
    np.save(tmp_path / "ball.npy", ball)
    return Scene.from_dict(scene_dict(
        [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"},
         {"type": "sphere", "center": [0.0, 0.45, -0.2], "radius": 0.45, "material": "mirror"},
         {"type": "sphere", "center": [0.9, 0.3, 0.3], "radius": 0.3, "material": "ball"}],
        {"m": {"ka": [0.2] * 3, "kd": [1, 1, 1], "ks": [0.3] * 3, "n": 20, "texture": str(tmp_path / name),
               "filter": filter},
         "mirror": {"kd": [0.05] * 3, "ks": [0.2] * 3, "n": 50, "kr": 0.7},
         "ball": {"kd": [0.6, 0.3, 0.2], "ks": [0.5] * 3, "n": 30, "texture": str(tmp_path / "ball.npy"),
                  "filter": "trilinear", "texture_target": "ks"}},
        camera={"eye": [0, 1.4, 2.2], "target": [0, 0.2, 0], "fov_y": 50, "width": W, "height": H},
        lights=[{"type": "point", "position": [2, 4, 3]}], ambient=(0.3, 0.3, 0.3),
        render={"method": "raytrace", "shadows": True, "max_depth": 3}))


def random_texels(seed, shape=(8, 8)):
    return np.random.default_rng(seed).uniform(0.1, 0.9, shape + (3,)).astype(np.float32)


def mirror_pixels(tree, scene) -> np.ndarray:
    """(H, W) bool: pixels where a primary ray hits the mirror."""
    hits = tree.material[tree.primary()] == scene.material_index("mirror")
    side = tree.spp_side
    return hits.reshape(H, side, W, side).any(axis=(1, 3))


def render_at(setup, texels, ks=(0.3, 0.3, 0.3)) -> np.ndarray:
    """The fit's tree image (H, W, 3) at `texels` (image orientation) and ks."""
    return setup.render({"texture": np.flipud(texels).reshape(-1), "ks": ks})[0]


@pytest.mark.parametrize("filter, spp", [("nearest", 1), ("bilinear", 1), ("bilinear", 4)])
def test_tree_image_at_other_texels_equals_warp(tmp_path, filter, spp, compare_images):
    """Recorded with texture A, re-formed at texture B (and another ks): Warp's render with B, to
    float32 rounding (measured 7.2e-7 for both filters at spp 1; 2.8e-7 on the mirror's pixels),
    mirror pixels that show the floor included."""
    a, b = random_texels(1), random_texels(2)
    recorded = textured_scene(tmp_path, a, filter).with_overrides(render={"spp": spp})
    frame = render_frame(recorded)
    tree = frame.ray_tree
    assert tree.uv.shape == (tree.n_nodes, 2) and tree.texel.shape == (tree.n_nodes, 3)
    setup = Setup(recorded, frame.image, "m", ("texture", "ks"))
    assert setup.method == "raytrace"
    compare_images(render_at(setup, a), frame.image, atol=2e-6, name=f"{filter}_{spp}_a")

    np.save(tmp_path / "b.npy", b)
    d = recorded.to_dict()
    d["materials"]["m"].update(texture=str(tmp_path / "b.npy"), ks=[0.5] * 3)
    want = render_frame(Scene.from_dict(d))
    got = render_at(setup, b, ks=(0.5, 0.5, 0.5))
    compare_images(got, want.image, atol=2e-6, name=f"{filter}_{spp}_b")
    reflected = mirror_pixels(tree, recorded) & (np.abs(want.image - frame.image).max(axis=-1) > 1e-2)
    assert reflected.sum() >= 20  # the mirror's pixels change with the floor's texels


def test_untextured_trees_spend_no_memory_on_uv(tmp_path):
    scene = textured_scene(tmp_path, random_texels(1))
    d = scene.to_dict()
    for mat in d["materials"].values():
        mat.pop("texture", None)
    tree = render_frame(Scene.from_dict(d)).ray_tree
    assert tree.n_nodes > W * H and tree.uv.shape == (0, 2) and tree.texel.shape == (0, 3)


@pytest.mark.parametrize("filter", ["nearest", "bilinear"])
def test_fit_material_recovers_texels_and_ks_through_the_tree(tmp_path, filter):
    """From a flat start (texels 0.5, ks 0.2): 192 texels + 3 ks (dense LM, <= DENSE_MAX)."""
    truth = random_texels(3)
    scene = textured_scene(tmp_path, truth, filter)
    target = render_frame(scene).image
    result = fit_material(scene, target, "m", ("texture", "ks"), init={"texture": 0.5, "ks": [0.2] * 3})
    assert result.model == "raytrace" and result.converged and not result.model_mismatch
    assert result.visible.all()  # the floor repeats the texture: every texel is seen
    assert np.abs(result.texture - truth).max() < 1e-5  # measured 6e-8 (bilinear), 1.5e-8 (nearest), 4 steps
    np.testing.assert_allclose(result.params["ks"], 0.3, rtol=1e-5)
    assert np.all(np.isfinite(result.stderr["texture"]))  # dense: a covariance is formed


def test_a_large_texture_is_fitted_matrix_free_through_the_tree(tmp_path):
    truth = random_texels(4, (12, 12))  # 432 unknowns: above DENSE_MAX
    scene = textured_scene(tmp_path, truth)
    target = render_frame(scene).image
    result = fit_material(scene, target, "m", ("texture",), init={"texture": 0.5})
    assert result.model == "raytrace" and result.converged and result.n_params == 432
    err = result.stderr["texture"]  # matrix-free: the covariance from the sparse Jacobian
    assert np.all(np.isfinite(err)) and 0 < err.max() < 1e-6  # a noise-free target: rounding's residuals
    assert result.visible.all() and np.abs(result.texture - truth).max() < 1e-5  # measured 1.3e-7, 6 steps


def test_a_batch_of_targets_recovers_each_texture_through_the_tree(tmp_path):
    a, b = random_texels(1), random_texels(2)
    scene = textured_scene(tmp_path, a)
    np.save(tmp_path / "b.npy", b)
    d = scene.to_dict()
    d["materials"]["m"]["texture"] = str(tmp_path / "b.npy")
    results = fit_batch(scene, [render_frame(scene).image, render_frame(Scene.from_dict(d)).image], "m",
                        ("texture",), init={"texture": 0.5})
    assert [(r.result, r.model) for r in results] == [("successful", "raytrace")] * 2
    assert np.abs(results[0].texture - a).max() < 1e-5 and np.abs(results[1].texture - b).max() < 1e-5  # 6e-8


def test_the_mirror_alone_recovers_the_texels_it_reflects(tmp_path):
    """Only the mirror's pixels count: the texels the reflected rays read (nearest: one each) are
    recovered and flagged seen, the others stay at the start and are flagged unseen."""
    truth = random_texels(5)
    scene = textured_scene(tmp_path, truth, "nearest")
    frame = render_frame(scene)
    tree = frame.ray_tree
    mirror = mirror_pixels(tree, scene)
    result = fit_material(scene, frame.image, "m", ("texture",), masks=mirror, init={"texture": 0.5})
    assert result.converged and result.poorly_determined == ["texture"]

    pixel = tree.sample  # spp 1: sample = flat pixel index
    lit = tree.visibility[:, 0] > 0  # the texture modulates kd: a shadowed node shows ka only
    seen = (tree.material == scene.material_index("m")) & (tree.depth == 2) & mirror.reshape(-1)[pixel] & lit
    rows, cols = (np.floor(tree.uv[seen, ::-1] * np.float32(8)).astype(int) % 8).T  # (v, u): texture orientation
    expected = np.zeros((8, 8), bool)
    expected[rows, cols] = True
    expected = np.flipud(expected)  # image orientation, as `visible`
    assert 5 <= expected.sum() < 64
    np.testing.assert_array_equal(result.visible, expected)
    assert np.abs(result.texture - truth)[expected].max() < 1e-5  # measured 1.2e-7 (34 texels, 120 pixels)
    np.testing.assert_allclose(result.texture[~expected], 0.5)


def test_texel_gradients_match_warp_finite_differences(tmp_path):
    """d(pixels)/d(texel) through the tree (jvp, float64) equals the central difference of two Warp
    renders with one texel moved by +-0.1 -- the texel the floor shows most directly and the one the
    mirror shows most -- and the texel fit's affine Jacobian products equal jax.linearize's."""
    truth = random_texels(6)
    scene = textured_scene(tmp_path, truth, "nearest")
    frame = render_frame(scene)
    setup = Setup(scene, frame.image, "m", ("texture",))
    problem = setup.problem
    pixels = setup.views[0].pixels
    mirror = mirror_pixels(frame.ray_tree, scene).reshape(-1)[pixels]
    values = setup.layout.flatten(setup.initial)
    with jax.enable_x64(True):
        def image(v):
            return problem.images(v)[0]

        jac = jax.jacfwd(image)(jnp.asarray(values))  # (U, 3, 192): image orientation flipped in the layout
    jac = np.asarray(jac)
    in_mirror = np.abs(jac[mirror]).sum(axis=(0, 1))  # per entry: what the mirror's pixels see of it
    for entry in (int(np.argmax(np.abs(jac[~mirror]).sum(axis=(0, 1)))), int(np.argmax(in_mirror))):
        texel, channel = divmod(entry, 3)
        row, col = divmod(texel, 8)  # texture orientation
        moved = []
        for sign in (1, -1):
            t = truth.copy()
            t[7 - row, col, channel] += sign * 0.1
            image = render_frame(textured_scene(tmp_path, t, "nearest", f"fd{sign}.npy")).image
            moved.append((t[7 - row, col, channel], image))
        (up, image_up), (down, image_down) = moved
        fd = (image_up - image_down).reshape(-1, 3)[pixels] / (up - down)
        assert np.abs(jac[..., entry] - fd).max() < 1e-5  # float32 renders: measured 3.0e-7, 1.7e-7
    assert np.abs(fd[mirror]).max() > 0.1  # the second texel reaches the mirror's pixels

    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        x = jnp.asarray(setup.x0 + rng.uniform(-0.05, 0.05, setup.x0.shape))
        r, jvp, vjp, _ = linearisation(lambda y, p: p.residuals(y, p.point_texels(p.layout.values(y))),
                                       np.zeros(0, np.int64), x, problem)
        fast = texel_linearisation(x, problem)
        v, u = rng.normal(size=x.shape), rng.normal(size=r.shape)
        assert np.abs(fast[0] - r).max() <= 1e-14 * np.abs(r).max()
        assert np.abs(fast[1](v) - jvp(v)).max() <= 1e-12 * np.abs(jvp(v)).max()
        assert np.abs(fast[2](u) - vjp(u)).max() <= 1e-12 * np.abs(vjp(u)).max()
        check_grads(lambda t: problem.images(t)[0], (jnp.asarray(values),), order=1,
                                  modes=("fwd", "rev"), atol=1e-5, rtol=1e-5)


def test_choose_method_sends_texels_with_the_scene_s_image_model(tmp_path):
    from difflab.fit.arguments import choose_method
    from test_texture_fit import quad_scene

    traced = textured_scene(tmp_path, random_texels(1))
    quad = quad_scene(tmp_path / "floor.npy", size=16)
    assert choose_method(traced, ("m",), None, texels=True) == "raytrace"
    assert choose_method(quad, ("m",), None, texels=True) == "raster"
    assert choose_method(quad, ("m",), None, texels=False) == "raytrace"  # an unfitted texture: the tree carries it
    assert choose_method(traced, ("m",), "raster", texels=True) == "raster"


def noisy_tree_setup(tmp_path, filter, params, spp=1, sigma=0.02, floor=False):
    """(Setup, mirror (H, W) bool): the textured floor and mirror with an 8 x 8 texture, its render
    plus seeded noise, the mirror's pixels used -- and with `floor` the image's left half (the floor
    repeats the texture: every texel seen directly)."""
    scene = textured_scene(tmp_path, random_texels(7), filter).with_overrides(render={"spp": spp})
    frame = render_frame(scene)
    target = frame.image + np.random.default_rng(8).normal(0.0, sigma, frame.image.shape).astype(np.float32)
    mirror = mirror_pixels(frame.ray_tree, scene)
    mask = mirror.copy()
    mask[:, :W // 2] |= floor
    init = {"texture": 0.5, "ks": [0.2] * 3}
    return Setup(scene, target, "m", params, masks=mask, init={k: init[k] for k in params if k in init}), mirror


@pytest.mark.parametrize("filter, params, floor", [
    ("nearest", ("texture",), False),  # the mirror alone: the texels it does not show are inf
    ("bilinear", ("texture",), True),  # every texel seen: all finite
    ("nearest", ("texture", "ks"), True),
    ("bilinear", ("texture", "ks"), False),  # 55 pixels for 195 unknowns: underdetermined, every stderr inf
])
def test_matrix_free_standard_errors_through_the_tree_equal_the_dense_ones(tmp_path, filter, params, floor):
    """Through the ray tree (a pixel sums its nodes' lookups: the mirror's and the floor's), the noisy fit
    solved densely and matrix-free has the same standard errors to rtol 1e-8 (measured <= 7.8e-16),
    inf for the same texels: unseen, or in a direction the pixels do not tell apart."""
    setup, _ = noisy_tree_setup(tmp_path, filter, params, floor=floor)
    dense, free = solve(setup, linear_solver="dense"), solve(setup, linear_solver="cg")
    assert dense.converged and free.converged
    assert_same_stderr(dense, free, rtol=1e-8)
    finite = np.isfinite(free.stderr["texture"])
    assert finite.all() if floor else not finite.all()
    assert np.isinf(free.stderr["texture"][~free.visible]).all()
    assert (~free.visible).any() == (filter == "nearest" and not floor)


@pytest.mark.parametrize("filter, spp", [("nearest", 1), ("bilinear", 4)])
def test_the_sparse_jacobian_through_the_tree_equals_jacfwd(tmp_path, filter, spp):
    """The column-compressed J through the tree (a pixel reads the texels of every node of its
    samples: the mirror's pixels those of two places on the floor) equals jax.jacfwd of
    `Problem.weighted`, to 1e-12 relative in float64 (measured 1.1e-16 absolute)."""
    setup, mirror = noisy_tree_setup(tmp_path, filter, ("texture", "ks", "n"), spp=spp)
    with jax.enable_x64(True):
        values = np.asarray(setup.layout.flatten(setup.initial))
        values = values * np.random.default_rng(3).uniform(0.9, 1.1, values.size)
        jac, r, skipped = sparse_jacobian(setup.problem, values)
        want = np.asarray(jax.jacfwd(setup.problem.weighted)(jnp.asarray(values)))
    assert jac.shape == want.shape == (r.size, 196) and not skipped.any()
    assert np.abs(jac.toarray() - want).max() <= 1e-12 * np.abs(want).max()
    texels_read = np.count_nonzero(want[:, :192].reshape(-1, 3, 64, 3).any(axis=(1, 3)), axis=1)  # per pixel
    assert texels_read[mirror.reshape(-1)[setup.views[0].pixels]].max() > (1 if filter == "nearest" else 4)
