"""The normal equations by parts (closed-form J^T J for single-point G-buffer pixels) against the
dense forward-mode ones, and the solver on each: the same numbers, the same steps."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, target_of

from difflab import compile_scene
from difflab.fit import Setup, fit_material
from difflab.fit import lm, moments
from difflab.fit.normal_equations import by_parts, by_parts_applies, dense, linearise

BRIGHT = [{"type": "point", "position": [2, 3, 3], "intensity": [2.5, 2.5, 2.5], "attenuation": [1, 0, 0]},
          {"type": "directional", "direction": [-1, -1, -0.5], "intensity": [0.3, 0.2, 0.5]}]


def residuals(x, problem):
    return problem.residuals(x)


def _both(setup, scale=0.8):
    """(by parts, dense) linearisations at the start's values scaled by `scale` (log entries too)."""
    with jax.enable_x64(True):
        x = jnp.asarray(setup.layout.x_of(setup.layout.flatten(setup.initial) * scale))
        fast = jax.jit(by_parts)(setup.problem, x)
        slow = jax.jit(partial(dense, residuals))(x, setup.problem)
    return [np.asarray(a) for a in fast], [np.asarray(a) for a in slow]


@pytest.mark.parametrize("shading,specular,materials,params,per_channel,ceiling", [
    ("phong", "phong", ("red", "floor"), ("ka", "kd", "ks", "n"), True, None),  # two materials, checker cells
    ("phong", "blinn", ("red",), ("kd", "ks", "n"), False, None),  # grey values
    ("flat", "torrance", ("red",), ("ks", "m", "f0"), True, None),
    ("phong", "phong", ("red",), ("ka", "kd", "ks", "n"), True, 1.0),  # clipped highlight: censored rows
])
def test_by_parts_equals_dense(shading, specular, materials, params, per_channel, ceiling):
    scene = make_scene(size=20, shading=shading, specular=specular, lights=BRIGHT)
    target = np.minimum(target_of(scene), ceiling) if ceiling else target_of(scene)
    setup = Setup(scene, [target], list(materials), params, per_channel=per_channel, ceiling=ceiling or False)
    assert by_parts_applies(setup.problem)
    if ceiling:
        assert setup.censored > 0
    if "floor" in materials:
        assert set(np.asarray(setup.problem.views[0].model.cell).tolist()) == {0, 1}  # both checker cells in view
    (r, a, g), (r_d, a_d, g_d) = _both(setup)
    np.testing.assert_allclose(r, r_d, rtol=0, atol=1e-14)
    np.testing.assert_allclose(a, a_d, rtol=0, atol=1e-11 * np.abs(a_d).max())
    np.testing.assert_allclose(g, g_d, rtol=0, atol=1e-11 * np.abs(g_d).max())
    assert np.abs(g_d).max() > 0


@pytest.mark.parametrize("kwargs,fit_kwargs", [
    ({"shading": "gouraud"}, {}),  # a pixel mixes three vertex colours
    ({"spp": 4}, {}),  # a pixel is the mean of 4 samples
    ({"fog": {"mode": "linear", "color": [0.5, 0.5, 0.5], "start": 3, "end": 20}}, {}),
    ({}, {"loss": "huber"}),
    ({}, {"params": ("kd", "intensity")}),
])
def test_dense_where_by_parts_does_not_apply(kwargs, fit_kwargs):
    """Pixels that are not single points, robust losses and light intensities take the forward-mode
    normal equations, whose J^T r is the gradient of 0.5 |r|^2 and whose J^T J is J's from reverse
    mode (an independent path), symmetric positive semi-definite."""
    scene = make_scene(size=12, **kwargs)
    setup = Setup(scene, [target_of(scene)], "red", **{"params": ("kd", "ks", "n"), "init": {"kd": 0.3}, **fit_kwargs})
    assert not by_parts_applies(setup.problem)
    with jax.enable_x64(True):
        x = jnp.asarray(setup.x0)
        r, gram, grad = (np.asarray(v) for v in jax.jit(linearise)(x, setup.problem))
        expected = jax.grad(lambda y: 0.5 * jnp.sum(jnp.square(residuals(y, setup.problem))))(x)
        jac = np.asarray(jax.jacrev(residuals)(x, setup.problem)).reshape(r.size, -1)
    np.testing.assert_allclose(grad, np.asarray(expected), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(gram, jac.T @ jac, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(gram, gram.T, rtol=1e-12, atol=1e-12)
    assert np.linalg.eigvalsh(gram).min() >= -1e-9 * np.abs(gram).max()
    assert np.abs(grad).max() > 1e-3 * np.abs(r).max() > 0  # a start away from the target: a real gradient


@pytest.mark.parametrize("clipped", [False, True])
@pytest.mark.parametrize("truth", [TRUTH, {**TRUTH, "ks": [0.0, 0.0, 0.0]}])
def test_solver_by_parts_takes_the_dense_solvers_steps(truth, clipped):
    """Recovery from a 30 % perturbed start, and a matte target (ks truly 0): the box LM on the
    closed-form normal equations takes the same steps to the same point as on forward-mode ones;
    `solve_box` -- from the moments, or with a ceiling (`clipped`) on the closed form's fast steps
    (float32 columns) -- a near Gauss-Newton first step: the same values to the tolerance where the
    target determines them and the exact J^T J at its end; no more steps where the target determines
    every entry. A matte target determines ks only to its float32 rounding: ks lands on its bound 0
    or, where the rounding's projection on the specular columns is positive, at ~1e-8, where n
    (otherwise undetermined) fits the rounding through ks and lowers the loss ~1e-4 of itself over
    a few steps more; `solve_box`, from lambda 1e-6, follows that further than the box LM from
    1e-3 does (12 steps against 5 here; the box LM from 1e-6 takes the same 12), so there it
    guarantees a loss no higher, not fewer steps."""
    scene = make_scene(size=24, red=truth)
    start = perturbed({**truth, "ks": [0.5, 0.4, 0.3]})
    target = target_of(scene)
    setup = Setup(scene, [target], "red", init=start, ceiling=1.5 * float(target.max()) if clipped else None)
    assert by_parts_applies(setup.problem)  # (else both solves would be the dense one)
    assert moments.applies(setup.problem) != clipped
    solve = partial(lm.box_lm, max_steps=64, rtol=1e-8, atol=1e-10)
    with jax.enable_x64(True):
        lower, upper = (jnp.asarray(b) for b in setup.layout.bounds())
        x0 = jnp.asarray(setup.x0)
        exact = jax.jit(partial(solve, lm.squared(linearise)))(x0, lower, upper, setup.problem)
        slow = jax.jit(partial(solve, lm.squared(partial(dense, residuals))))(x0, lower, upper, setup.problem)
        fast = lm.solve_box(setup.problem, x0, lower, upper, 64, 1e-8, 1e-10)
        dense_at_fast = jax.jit(partial(dense, residuals))(fast[0], setup.problem)
    x, code, steps = (np.asarray(v) for v in exact[:3])
    assert lm.CODES[int(code)] == "successful" and int(steps) == int(slow[2]) and int(steps) <= 25
    np.testing.assert_allclose(x, np.asarray(slow[0]), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(exact[5]), np.asarray(slow[5]), rtol=1e-9, atol=1e-12)  # J^T J at x
    matte = max(truth["ks"]) == 0.0
    assert lm.CODES[int(fast[1])] == "successful"
    if matte:
        assert np.nanmin(np.asarray(fast[3])) <= np.nanmin(np.asarray(exact[3])) * (1 + 1e-6)
    else:
        assert int(fast[2]) <= int(steps)
    for found in (setup.values(x), setup.values(np.asarray(fast[0]))):
        for key in ("ka", "kd") + (("ks",) if matte else ("ks", "n")):  # a matte target says nothing of n
            atol = np.finfo(np.float32).eps if matte and key == "ks" else 1e-7  # (ks: 0 to the target's rounding)
            np.testing.assert_allclose(found[key], truth[key], rtol=1e-4, atol=atol)
    determined = np.concatenate([np.full(p.size, not (matte and p.kind in ("ks", "n"))) for p in setup.layout])
    np.testing.assert_allclose(np.asarray(fast[0])[determined], x[determined], rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(np.asarray(fast[5]), np.asarray(dense_at_fast[1]), rtol=1e-9, atol=1e-12)


def test_a_compiled_scene_fits_as_the_scene_does():
    """A CompiledScene renders the views with its camera and lights; a view with another camera
    is compiled for itself. The results equal those from the Scene."""
    scene = make_scene(size=16, red=TRUTH)
    target = target_of(scene)
    other = scene.camera.to_dict() | {"eye": [0.5, 1.4, 4.0]}
    moved = target_of(scene.with_overrides(camera=other))
    start = perturbed(TRUTH)
    for targets in ([target], [target, (moved, {"camera": other})]):
        plain = fit_material(scene, targets, "red", init=start, history=False)
        compiled = fit_material(compile_scene(scene), targets, "red", init=start, history=False)
        assert compiled.converged and compiled.steps == plain.steps
        for key in plain.params:
            np.testing.assert_array_equal(compiled.params[key], plain.params[key])


@pytest.mark.parametrize("where", ["start", "elsewhere"])
def test_box_lm_with_a_nonfinite_normal_matrix(where):
    """r = x - 1 with J^T J NaN at the start ("nonfinite" there, no step), or NaN above x = 0.95,
    short of the optimum 1 (those trial steps rejected: the solve ends at the cap 0.95)."""
    def linearise_nan(x, args):
        r = x - 1.0
        bad = jnp.all(x == 0.0) if where == "start" else jnp.any(x > 0.95)  # a cap the LM steps past
        a = jnp.where(bad, jnp.nan, 1.0) * jnp.eye(2)
        return r, a, jnp.where(bad, jnp.nan, 1.0) * r

    with jax.enable_x64(True):
        x, code, steps = jax.jit(partial(lm.box_lm, lm.squared(linearise_nan), max_steps=50, rtol=1e-8, atol=1e-10))(
            jnp.zeros(2), jnp.full(2, -5.0), jnp.full(2, 0.96), None)[:3]
    if where == "start":
        assert lm.CODES[int(code)] == "nonfinite" and int(steps) == 0
    else:
        assert lm.CODES[int(code)] == "successful" and np.all(np.asarray(x) <= 0.95)
        np.testing.assert_allclose(np.asarray(x), 0.95, atol=1e-6)


@pytest.mark.parametrize("shrink", [0.1, 0.5])
def test_a_rejected_step_is_cut_to_the_quadratics_fraction(shrink):
    """`lm.shrinking_damping`: the damped step (A + lambda' D) dx = -g, D = diag(A), is `shrink` times
    as long as lambda's in |D^(1/2) dx| -- on an ill-conditioned A (one direction 1e-6 of the
    others, where lambda = 1e-7 barely damps), with an entry held at its bound left out."""
    rng = np.random.default_rng(3)
    q = np.linalg.qr(rng.normal(size=(4, 4)))[0]
    a = q @ np.diag([1e-6, 0.5, 2.0, 3.0]) @ q.T
    g = rng.normal(size=4)
    g[3] = abs(g[3])  # entry 3 on its lower bound, pushed outward: held
    x, lower, upper = np.array([0.3, 0.2, 0.1, 0.0]), np.full(4, 0.0), np.full(4, 1.0)
    free = np.arange(4) < 3

    def length(lam):
        m = a[np.ix_(free, free)] + lam * np.diag(np.diag(a)[free])
        return np.linalg.norm(np.sqrt(np.diag(a)[free]) * np.linalg.solve(m, -g[free]))

    with jax.enable_x64(True):
        lam = float(lm.shrinking_damping(*map(jnp.asarray, (a, g, x, lower, upper)), 1e-7, shrink))
    assert lam > 1e-7
    np.testing.assert_allclose(length(lam), shrink * length(1e-7), rtol=1e-6)


def test_a_step_onto_a_bound_lands_on_it_exactly():
    """x + (clip(x + dx, lower, upper) - x) passes the bound by an ulp for 13 % of float32 starts;
    the accepted point is clipped: r = x - 100 from x0 = -11.016636 (one of them) with upper 11.7
    ends on 11.7 itself, held there."""
    def linearise(x, args):
        r = x - 100.0
        return r, jnp.eye(1, dtype=x.dtype), r

    x = jax.jit(partial(lm.box_lm, lm.squared(linearise), max_steps=20, rtol=1e-5, atol=1e-7))(
        jnp.asarray([-11.016636], jnp.float32), jnp.asarray([-12.0], jnp.float32), jnp.asarray([11.7], jnp.float32),
        None)[0]
    assert np.asarray(x)[0] == np.float32(11.7)
