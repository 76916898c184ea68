"""Texels through the one engine: `fit_material(..., params=("texture", ...))` on the G-buffer model,
solved matrix-free (box LM with CG) for large layouts and densely for small ones."""

import dataclasses

import jax
import lineax as lx
import numpy as np
import optimistix as optx
import pytest
from test_texture_fit import quad_scene

from difflab import FitError, Scene, render, render_frame
from difflab.fit import FitOptions, Setup, fit_batch, fit_material, identify, solve
from difflab.fit import sparse_jacobian as jacobian
from difflab.fit import stats
from difflab.fit.matfree import linearisation
from difflab.fit.sparse_jacobian import sparse_jacobian
from difflab.fit.texels import texel_linearisation
from difflab.fit.texture_fit import fit_texture, texture_view

SHAPE = (12, 12)  # 432 unknowns: above DENSE_MAX, so "auto" is matrix-free


@pytest.fixture(scope="module")
def known(tmp_path_factory):
    """A 12 x 12 random texture on a quad (ks 0.3, n 20) and its 40 x 40 render."""
    texels = np.random.default_rng(7).uniform(0.1, 0.9, SHAPE + (3,)).astype(np.float32)
    path = tmp_path_factory.mktemp("texels") / "truth.npy"
    np.save(path, texels)
    scene = quad_scene(path, size=40)
    return texels, scene, render(scene)


def test_texels_are_recovered_through_fit_material(known):
    texels, scene, target = known
    result = fit_material(scene, target, "m", ("texture",), init={"texture": 0.5})
    assert result.model == "raster" and result.converged and result.result == "successful"
    assert result.n_params == 12 * 12 * 3 and result.params["texture"].shape == SHAPE + (3,)
    assert result.visible.all()  # the quad fills the view: every texel is seen
    assert np.abs(result.texture - texels).max() < 1e-5  # float32 render: error ~1e-7 measured
    assert result.psnr > 100 and not result.model_mismatch
    err = result.stderr["texture"]  # matrix-free: the covariance from the sparse Jacobian
    assert np.all(np.isfinite(err)) and 0 < err.max() < 1e-6  # a noise-free target: rounding's residuals
    assert result.poorly_determined == []


def test_texels_with_specular_scalars_in_one_fit(known):
    """ks and n beside the kd texture's texels: all recovered from a perturbed start."""
    texels, scene, target = known
    result = fit_material(scene, target, "m", ("texture", "ks", "n"),
                          init={"texture": 0.5, "ks": [0.2, 0.2, 0.2], "n": 12.0})
    assert result.converged
    np.testing.assert_allclose(result.params["ks"], [0.3, 0.3, 0.3], rtol=1e-4)
    np.testing.assert_allclose(result.params["n"], 20.0, rtol=1e-4)
    assert np.abs(result.texture - texels).max() < 1e-4


def test_the_engine_agrees_with_optimistix_lm_normal_cg(known):
    """The previous texture solver -- optimistix's Levenberg-Marquardt with lineax CG on the normal
    equations, unbounded texels -- on the same problem gives the same texels; a dense solve of a
    small texture agrees with the CG one."""
    texels, scene, target = known
    setup = Setup(scene, target, "m", ("texture",), init={"texture": 0.5})
    ours = solve(setup)
    method = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10, linear_solver=lx.Normal(lx.CG(rtol=1e-10, atol=1e-10,
                                                                                           max_steps=500)))

    with jax.enable_x64(True):
        sol = optx.least_squares(lambda x, p: p.residuals(x), method, jax.numpy.asarray(setup.x0), args=setup.problem,
                                 max_steps=50, throw=False)
        theirs = np.flipud(np.asarray(sol.value).reshape(SHAPE + (3,)))
    assert np.abs(ours.texture - theirs).max() < 1e-6

    small = Setup(scene, target, "m", ("texture",), init={"texture": np.full((6, 6, 3), 0.5)})
    dense, cg = solve(small, linear_solver="dense"), solve(small, linear_solver="cg")
    assert dense.converged and cg.converged
    assert np.abs(dense.texture - cg.texture).max() < 1e-7
    assert np.all(np.isfinite(dense.stderr["texture"])) and np.all(np.isfinite(cg.stderr["texture"]))


def test_fit_texture_is_a_front_end_and_to_scene_saves_the_texels(known, tmp_path):
    texels, scene, target = known
    frame = render_frame(scene)
    view = texture_view(frame.gbuffer, target, scene, "m", SHAPE)
    result = fit_texture([view], SHAPE, init=0.5)
    assert result.converged and result.model == "raster"
    with pytest.raises(FitError, match="folder"):
        result.to_scene()
    fitted = result.to_scene(tmp_path)
    assert fitted.materials["m"].texture == str(tmp_path / "fitted.m.texture.npy")
    np.testing.assert_allclose(render(fitted), target, atol=1e-5)


def test_to_scene_names_texture_files_as_the_commands_do(known, tmp_path):
    """A material named "../evil" (a valid scene name) gets <stem>.texture<index>.npy inside the
    folder, as `difflab fit` and fit-batch name it; the old <material>_texture.npy wrote
    folder/../evil_texture.npy, outside the folder."""
    texels, scene, target = known
    result = fit_material(scene, target, "m", ("texture",), init={"texture": 0.5})
    data = result.scene.to_dict()
    data["materials"] = {"../evil": data["materials"]["m"]}
    data["objects"][0]["material"] = "../evil"
    evil = dataclasses.replace(result, scene=Scene.from_dict(data))
    folder = tmp_path / "out"
    folder.mkdir()
    fitted = evil.to_scene(folder, stem="run")
    assert sorted(p.name for p in tmp_path.rglob("*.npy")) == ["run.texture0.npy"]
    assert fitted.materials["../evil"].texture == str(folder / "run.texture0.npy")
    assert list(evil.texture_files("run")) == ["run.texture0.npy"]  # the commands' name for it
    np.testing.assert_allclose(np.load(folder / "run.texture0.npy"), result.texture)


def test_unseen_texels_are_flagged(known):
    texels, scene, target = known
    mask = np.zeros(target.shape[:2], bool)
    mask[:, :20] = True  # the left half of the image: the right texels are unseen
    result = fit_material(scene, target, "m", ("texture",), masks=mask, init={"texture": 0.5})
    assert result.converged and 0.3 < result.visible.mean() < 0.7
    assert result.poorly_determined == ["texture"]
    assert np.abs(result.texture - texels)[result.visible].max() < 1e-4
    np.testing.assert_allclose(result.texture[~result.visible], 0.5)


@pytest.mark.parametrize("case, kwargs, match", [
    ("no texture", {"material": "plain"}, r"params: 'texture': material 'plain' has no image texture"),
    ("ray tree mipmap", {"method": "raytrace", "filter": "mipmap"}, r"materials\['m'\]\.filter: texture fitting supp"),
    ("gouraud", {"render": {"shading": "gouraud"}}, r"params: fitting texels needs Phong shading"),
    ("trilinear", {"filter": "trilinear"}, r"materials\['m'\]\.filter: texture fitting supports"),
    ("init shape", {"init": {"texture": np.ones((4, 4, 2))}}, r"init\['texture'\]: expected an \(H_t, W_t, 3\)"),
    ("init negative", {"init": {"texture": -1.0}}, r"init\['texture'\]: texels must be finite and >= 0"),
    ("smoothness", {"smoothness": -1.0}, r"smoothness: must be a finite number >= 0"),
    ("bfgs", {"solver": "bfgs"}, r"solver: 'bfgs' forms dense 432 x 432 matrices"),
    ("linear solver", {"linear_solver": "qr"}, r"linear_solver: expected one of auto, dense, cg"),
    ("cg steps", {"cg_steps": 0}, r"cg_steps: must be an integer >= 1"),
])
def test_bad_texel_fits_raise_fit_error_naming_the_argument(known, case, kwargs, match):
    texels, scene, target = known
    d = scene.to_dict()
    d["materials"]["plain"] = {"kd": 0.5}
    if "filter" in kwargs:
        d["materials"]["m"]["filter"] = kwargs.pop("filter")
    if "render" in kwargs:
        d["render"].update(kwargs.pop("render"))

    material = kwargs.pop("material", "m")
    with pytest.raises(FitError, match=match):
        fit_material(Scene.from_dict(d), target, material, ("texture",), **kwargs)


def test_smoothness_without_a_texture_and_bad_front_end_arguments(known):
    texels, scene, target = known
    with pytest.raises(FitError, match="smoothness: a prior on texels, but no 'texture'"):
        fit_material(scene, target, "m", ("ks",), smoothness=1.0, method="raytrace")
    with pytest.raises(FitError, match="views: need at least one view"):
        fit_texture([], SHAPE)
    frame = render_frame(scene)
    with pytest.raises(FitError, match=r"shape: expected \(H_t, W_t\), two integers >= 1, got \(0, 4\)"):
        texture_view(frame.gbuffer, target, scene, "m", (0, 4))
    with pytest.raises(FitError, match="wrap: texture fitting supports"):
        texture_view(frame.gbuffer, target, scene, "m", SHAPE, wrap="spiral")
    with pytest.raises(FitError, match="init: expected a number, an RGB triple or an"):
        fit_texture([texture_view(frame.gbuffer, target, scene, "m", SHAPE)], SHAPE, init=np.ones((3, 3)))
    assert FitOptions(linear_solver="cg").matrix_free(3) and not FitOptions().matrix_free(256)
    with pytest.raises(FitError, match="params: identify forms the dense 432 x 432 Gram matrix"):
        identify(scene, target, "m", ("texture",), method="raster")


def test_a_batch_of_texture_targets_loops_over_one_matrix_free_solve(known, tmp_path):
    """fit_batch with texels: the vmapped dense LM is skipped (432 unknowns), each target is fitted
    by the same compiled matrix-free solve and recovers its own texture."""

    texels, scene, target = known
    other = np.ascontiguousarray(texels[::-1, ::-1])
    np.save(tmp_path / "other.npy", other)
    d = scene.to_dict()
    d["materials"]["m"]["texture"] = str(tmp_path / "other.npy")

    results = fit_batch(scene, [target, render(Scene.from_dict(d))], "m", ("texture",), init={"texture": 0.5})
    assert [r.result for r in results] == ["successful", "successful"]
    assert np.abs(results[0].texture - texels).max() < 1e-5
    assert np.abs(results[1].texture - other).max() < 1e-5


@pytest.mark.parametrize("params, kwargs", [
    (("texture",), {"smoothness": 0.3, "loss": "huber"}),  # one gain per residual (pixel i = point i)
    (("texture", "ks", "n"), {"init": {"texture": 0.5, "ks": [0.2, 0.25, 0.3], "n": 12.0}}),  # + formed columns
    (("texture", "n"), {"spp": 4}),  # pixels composed from 4 samples: the linearised composition
])
def test_the_affine_texel_products_equal_autodiff(known, params, kwargs):
    """A texel fit's Jacobian products (taps times the shading's partials: `texel_linearisation`, and
    the derivative of `Problem.residuals` every solver linearises) equal jax.linearize's of the whole
    model's residuals, in float64."""
    _, scene, target = known
    kwargs = {"init": {"texture": 0.5}, **kwargs}
    setup = Setup(scene, target, "m", params, **kwargs)
    problem = setup.problem
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        x = jax.numpy.asarray(setup.x0 + rng.uniform(-0.05, 0.05, setup.x0.shape))
        exact = np.flatnonzero(np.concatenate([np.full(p.size, p.shape is None) for p in problem.layout]))
        r, jvp, vjp, columns = linearisation(lambda y, p: p.residuals(y, p.point_texels(p.layout.values(y))), exact,
                                             x, problem)  # the whole model, no custom derivative
        v, u = rng.normal(size=x.shape), rng.normal(size=r.shape)
        for fast in (texel_linearisation(x, problem), linearisation(lambda y, p: p.residuals(y), exact, x, problem)):
            assert r.dtype == np.float64 and np.abs(fast[0] - r).max() <= 1e-14 * np.abs(r).max()
            for ours, theirs in [(fast[1](v), jvp(v)), (fast[2](u), vjp(u))]:
                assert np.abs(ours - theirs).max() <= 1e-12 * np.abs(theirs).max()
            assert (columns is None) == (fast[3] is None) == (exact.size == 0)
            if columns is not None:
                assert np.abs(fast[3] - columns).max() <= 1e-12 * np.abs(columns).max()


def noisy_texel_setup(tmp_path, shape, filter, params, sigma=0.02, seed=11, size=40, spp=1):
    """(Setup, truth (H_t, W_t, 3)): a random texture on the quad, its render plus seeded noise of
    `sigma`, the right quarter of the image masked out (the texels only it shows: unseen)."""
    truth = np.random.default_rng(seed).uniform(0.2, 0.8, shape + (3,)).astype(np.float32)
    np.save(tmp_path / "truth.npy", truth)
    scene = quad_scene(tmp_path / "truth.npy", size=size, filter=filter).with_overrides(render={"spp": spp})
    target = render(scene) + np.random.default_rng(seed + 1).normal(0.0, sigma, (size, size, 3)).astype(np.float32)
    mask = np.ones((size, size), bool)
    mask[:, 3 * size // 4:] = False
    init = {"texture": 0.5, "ks": [0.2] * 3, "kd": [0.8] * 3}
    return Setup(scene, target, "m", params, masks=mask, init={k: init[k] for k in params if k in init}), truth


def assert_same_stderr(dense, free, rtol):
    """The matrix-free fit's standard errors equal the dense fit's: inf at the same entries, within
    `rtol` elsewhere -- or two roundings of the value's precision (a texture's are float32)."""
    for key, want in dense.stderr.items():
        tol = max(rtol, 2 * np.finfo(np.asarray(free.stderr[key]).dtype).eps)
        want, got = np.asarray(want, np.float64), np.asarray(free.stderr[key], np.float64)
        np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
        assert not np.isnan(want).any()
        np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], rtol=tol)
    assert free.poorly_determined == dense.poorly_determined


@pytest.mark.parametrize("filter", ["nearest", "bilinear"])
@pytest.mark.parametrize("params", [("texture",), ("texture", "ks")])
def test_matrix_free_standard_errors_equal_the_dense_ones(tmp_path, filter, params):
    """The same noisy fit solved densely and matrix-free (the sparse Jacobian by column compression):
    the same standard errors to rtol 1e-8 (measured: ks <= 8.4e-12; the float32 texels' equal), inf
    for the unseen texels in both."""
    setup, _ = noisy_texel_setup(tmp_path, (8, 8), filter, params)
    dense, free = solve(setup, linear_solver="dense"), solve(setup, linear_solver="cg")
    assert dense.converged and free.converged
    assert_same_stderr(dense, free, rtol=1e-8)
    assert np.isfinite(free.stderr["texture"]).mean() > 0.7
    unseen = ~free.visible
    assert unseen.any() and np.isinf(free.stderr["texture"][unseen]).all()
    assert "texture" in free.poorly_determined


def test_with_a_smoothness_prior_the_standard_errors_are_the_pixels_alone(tmp_path):
    """With `smoothness`, dense and matrix-free fits leave the prior's rows out of J^T J alike: the
    same standard errors (rtol 1e-8), inf for the unseen texels although the prior fills them."""
    setup, _ = noisy_texel_setup(tmp_path, (8, 8), "nearest", ("texture", "ks"))
    setup = Setup(setup.scene, setup.views[0].image, "m", ("texture", "ks"), masks=setup.views[0].mask,
                  init={"texture": 0.5, "ks": [0.2] * 3}, smoothness=0.1)
    dense, free = solve(setup, linear_solver="dense"), solve(setup, linear_solver="cg")
    assert_same_stderr(dense, free, rtol=1e-8)
    unseen = ~free.visible
    assert unseen.any() and np.isinf(free.stderr["texture"][unseen]).all()
    assert np.abs(free.texture[unseen] - 0.5).max() > 0.05  # filled by the prior from the seen neighbours


def test_standard_errors_by_blocks_equal_the_dense_ones(tmp_path, monkeypatch):
    """With PACKED_MAX lowered below a channel's texels, the matrix-free fit inverts J^T J per
    connected block -- each channel's seen texels with its ks (`inverse_diagonal`: banded, ks by
    Schur complement), each unseen texel alone -- to the dense fit's standard errors (rtol 1e-8), up
    to a SPARSE_STATS_MAX of a channel's predicted block (`sparse_jacobian.stats_blocks`: the 120
    texels its pixels read and ks; at the solution 108 of them have nonzero columns). Below it the
    seen entries get nan without a Jacobian product (the unseen texels, single blocks, stay inf),
    the fit's loss, noise and chi-square unchanged, and only what is unseen is flagged."""
    setup, _ = noisy_texel_setup(tmp_path, (12, 12), "bilinear", ("texture", "ks"))
    dense = solve(setup, linear_solver="dense")
    monkeypatch.setattr(stats, "PACKED_MAX", 16)
    assert_same_stderr(dense, solve(setup, linear_solver="cg"), rtol=1e-8)
    monkeypatch.setattr(stats, "SPARSE_STATS_MAX", 121)  # a channel's block predicted: 120 texels read, its ks
    assert_same_stderr(dense, solve(setup, linear_solver="cg"), rtol=1e-8)
    monkeypatch.setattr(stats, "SPARSE_STATS_MAX", 120)
    full = solve(setup, linear_solver="cg")
    monkeypatch.setattr(jacobian, "_products", refuse)  # predicted too large: no Jacobian formed
    capped = solve(setup, linear_solver="cg")
    assert np.isnan(capped.stderr["ks"]).all() and capped.poorly_determined == ["texture"]
    err = capped.stderr["texture"]
    assert np.isinf(err[~capped.visible]).all() and np.isnan(err[capped.visible]).all()
    assert (capped.loss, capped.sigma, capped.chi2) == (full.loss, full.sigma, full.chi2)


def refuse(*args):
    raise AssertionError("the sparse Jacobian was formed")


def test_texel_blocks_over_the_limit_skip_the_jacobian(tmp_path, monkeypatch):
    """Without scalars a bilinear texture's predicted blocks are a channel's connected texels its
    pixels read (120 here) and each unseen texel alone: with SPARSE_STATS_MAX 119 the seen texels
    get nan without a Jacobian product, the unseen ones inf, and the loss and noise stay those of a
    fit with the numbers; with 120 the standard errors are the dense fit's."""
    setup, _ = noisy_texel_setup(tmp_path, (12, 12), "bilinear", ("texture",))
    monkeypatch.setattr(stats, "PACKED_MAX", 16)
    monkeypatch.setattr(stats, "SPARSE_STATS_MAX", 120)
    full = solve(setup, linear_solver="cg")
    assert_same_stderr(solve(setup, linear_solver="dense"), full, rtol=1e-8)
    monkeypatch.setattr(stats, "SPARSE_STATS_MAX", 119)
    monkeypatch.setattr(jacobian, "_products", refuse)
    capped = solve(setup, linear_solver="cg")
    err = capped.stderr["texture"]
    assert np.isinf(err[~capped.visible]).all() and np.isnan(err[capped.visible]).all()
    assert (capped.loss, capped.sigma, capped.chi2) == (full.loss, full.sigma, full.chi2)


def test_the_sparse_jacobian_leaves_out_the_texels_of_blocks_over_the_limit(tmp_path):
    """A 16 x 16 bilinear texture seen in 8 x 8 pixels: each pixel's 2 x 2 taps apart from the
    others', blocks of 1, 2 and 4 texels a channel (2, 16 and 30 of them). With the limit 3 the
    texels of the blocks of 4 are skipped -- empty columns -- and every other column equals
    jax.jacfwd's (1e-12 relative), as do the residuals."""
    setup, _ = noisy_texel_setup(tmp_path, (16, 16), "bilinear", ("texture",), size=8)
    with jax.enable_x64(True):
        values = np.asarray(setup.layout.flatten(setup.initial)) * np.random.default_rng(3).uniform(0.9, 1.1, 768)
        jac, r, skipped = jacobian.sparse_jacobian(setup.problem, values, limit=3)
        want = np.asarray(jax.jacfwd(setup.problem.weighted)(jax.numpy.asarray(values)))
        plain = np.asarray(setup.problem.weighted(jax.numpy.asarray(values)))
    assert skipped.sum() == 3 * 4 * 30 and skipped.reshape(-1, 3).all(axis=1).sum() == 4 * 30
    assert jac[:, skipped].nnz == 0 and np.abs(want[:, skipped]).max() > 0
    assert np.abs(jac.toarray()[:, ~skipped] - want[:, ~skipped]).max() <= 1e-12 * np.abs(want).max()
    assert np.abs(want[:, ~skipped]).max() > 0 and np.abs(r - plain).max() <= 1e-12


def test_texel_standard_errors_are_calibrated(tmp_path):
    """A 16 x 16 texture (768 entries: matrix-free) under noise sigma 0.02: the z-scores
    (fitted - true) / stderr of the seen texels have an RMS near 1 (measured 0.93 over 624; 0.91-1.00
    over 4 noise seeds before the dof left unseen texels out)."""
    setup, truth = noisy_texel_setup(tmp_path, (16, 16), "bilinear", ("texture",), size=48)
    result = solve(setup)
    assert result.converged and result.n_params == 768
    seen = np.isfinite(result.stderr["texture"])
    assert seen.sum() >= 200 and np.array_equal(seen.all(axis=-1), result.visible)
    z = (result.texture - truth)[seen] / result.stderr["texture"][seen]
    assert 0.8 < np.sqrt(np.mean(z ** 2)) < 1.25


@pytest.mark.parametrize("filter, spp", [("nearest", 1), ("bilinear", 1), ("bilinear", 4)])
def test_the_sparse_jacobian_equals_jacfwd(tmp_path, filter, spp):
    """The column-compressed J of the plain weighted residuals (texels, ks and n beside them, n in
    log coordinates) equals jax.jacfwd of `Problem.weighted` through the whole shading model, to
    1e-12 relative in float64 (measured 2.2e-16 absolute, entries up to 1.27); an unseen texel's
    column is empty."""
    setup, _ = noisy_texel_setup(tmp_path, (6, 6), filter, ("texture", "ks", "n"), size=24, spp=spp)
    with jax.enable_x64(True):
        values = np.asarray(setup.layout.flatten(setup.initial)) * np.random.default_rng(3).uniform(0.9, 1.1, 112)
        jac, r, skipped = sparse_jacobian(setup.problem, values)
        want = np.asarray(jax.jacfwd(setup.problem.weighted)(jax.numpy.asarray(values)))
    assert jac.shape == want.shape == (r.size, 112) and r.dtype == np.float64 and not skipped.any()
    assert np.abs(jac.toarray() - want).max() <= 1e-12 * np.abs(want).max()
    assert jac.nnz < want.size / 10  # (measured: 2.7-5.2 % of the entries)
    unseen = np.abs(want).max(axis=0) == 0  # nearest: the masked quarter's texels (bilinear taps reach them)
    assert unseen.any() == (filter == "nearest") and jac[:, unseen].nnz == 0


@pytest.mark.parametrize("smoothness, pulled", [(0.001, False), (1.0, True)])
def test_a_smoothness_prior_reports_how_far_it_pulls_the_seen_texels(tmp_path, smoothness, pulled):
    """A random 8 x 8 texture under noise 0.02 (nearest: the image is linear in the texels), fitted
    without and with a smoothness prior. `prior_pull` is the prior's move of the values from where
    the pixels alone put them, in their standard errors: max |T_data - T_prior| / stderr over the
    seen texels, to 1e-3 relative (exact for a linear problem but for the float32 texels and the
    solver's tolerance: 1e-4 measured at the weak prior). A weak prior moves them by less
    than one standard error (not flagged); a strong one by many: the texture is poorly determined
    and the table says PRIOR PULL -- their stderr (the pixels') do not cover that bias. chi2 is the
    data term's in both (the prior's residuals are not the images')."""
    base, _ = noisy_texel_setup(tmp_path, (8, 8), "nearest", ("texture",))
    data = solve(base)
    setup = Setup(base.scene, base.views[0].image, "m", ("texture",), masks=base.views[0].mask,
                  init={"texture": 0.5}, smoothness=smoothness)
    prior = solve(setup)
    assert data.prior_pull == 0.0 and prior.converged
    err = prior.stderr["texture"]
    seen = np.isfinite(err)
    moved = np.abs(data.texture.astype(np.float64) - prior.texture)[seen] / err[seen]
    assert prior.prior_pull == pytest.approx(moved.max(), rel=1e-3)
    assert (prior.prior_pull > 1.0) is pulled and ("PRIOR PULL" in prior.table()) is pulled
    sse = float(np.sum(np.square(prior.residuals[0])))
    dof = 3 * int(base.views[0].used.sum()) - 3 * int(np.count_nonzero(prior.visible))
    assert prior.chi2 == pytest.approx(sse / dof / prior.sigma ** 2, rel=1e-4)
