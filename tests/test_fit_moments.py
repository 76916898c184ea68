"""The normal equations from column moments (`fit.moments`) against reverse mode, and the solves
on them against the solves on the closed-form normal equations they replace."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, target_of
from test_fit_normal_equations import BRIGHT, residuals

from difflab.fit import Setup, lm, moments
from difflab.fit.normal_equations import linearise


SPOT = [{"type": "spot", "position": [0, 4, 1], "direction": [0, -1, -0.2], "cutoff_deg": 30, "exponent": 8,
         "intensity": [2.0, 1.5, 1.0]}, *BRIGHT]


def _setup(shading="phong", specular="phong", materials=("red",), params=("ka", "kd", "ks", "n"), weighted=False,
           x64=True, lights=BRIGHT, **kwargs):
    """`weighted`: per-channel weights in [0, 2) ("zeros": a third of them exactly 0)."""
    scene = make_scene(size=20, shading=shading, specular=specular, lights=lights)
    target = target_of(scene)
    weights = None
    if weighted:
        rng = np.random.default_rng(1)
        weights = [rng.uniform(0.0, 2.0, target.shape) * (rng.random(target.shape) > (0.33 if weighted == "zeros"
                                                                                          else 0.0))]
    return Setup(scene, [target], list(materials), params, weights=weights, x64=x64, **kwargs)


CASES = [  # shading, specular, materials, params, weights, lights
    ("phong", "phong", ("red", "floor"), ("ka", "kd", "ks", "n"), False, BRIGHT),  # two materials, checker cells
    ("phong", "blinn", ("red",), ("kd", "ks", "n"), True, BRIGHT),  # per-channel weights
    ("flat", "torrance", ("red",), ("ks", "m", "f0"), False, BRIGHT),  # two nonlinear kinds
    ("phong", "phong", ("red", "floor"), ("kd", "n"), True, BRIGHT),  # n without ks: S's coefficient is a constant
    ("phong", "phong", ("red",), ("ka", "kd", "ks"), False, BRIGHT),  # nothing nonlinear fitted
    ("phong", "phong", ("red", "floor"), ("kd", "ks", "n"), "zeros", BRIGHT),  # weights exactly 0 at a third
    ("phong", "blinn", ("red",), ("ka",), False, SPOT),  # ka alone; a spot light beside a point and a directional one
]


@pytest.mark.parametrize("shading,specular,materials,params,weighted,lights", CASES)
def test_moments_equal_reverse_mode(shading, specular, materials, params, weighted, lights):
    """0.5 r^T r, J^T J and J^T r from the moments equal those of the residuals by reverse mode
    (J by jax.jacrev, the gradient by jax.grad), and the residuals formed from the kept rows equal
    `Problem.residuals`, at a point away from the solution (every value 0.8 of the truth's);
    r^T r to the rounding of the sums over |target|^2 it is the difference of."""
    setup = _setup(shading, specular, materials, params, weighted, lights=lights)
    assert moments.applies(setup.problem) and setup.problem.views[0].model.formation.direct
    with jax.enable_x64(True):
        x = jnp.asarray(setup.layout.x_of(setup.layout.flatten(setup.initial) * 0.8))
        prepared = jax.jit(moments.prepare)(setup.problem, setup.x0)  # prepared at the start, used elsewhere
        loss, gram, grad = (np.asarray(v) for v in jax.jit(moments.linearise)(prepared, x, setup.problem)[:3])
        r = setup.problem.view_residuals(jax.jit(moments.residuals)(prepared, x, setup.problem))
        r_plain = np.asarray(residuals(x, setup.problem))
        jac = np.asarray(jax.jacrev(residuals)(x, setup.problem))
        expected = np.asarray(jax.grad(lambda y: 0.5 * jnp.sum(jnp.square(residuals(y, setup.problem))))(x))
    np.testing.assert_allclose(r, setup.problem.view_residuals(r_plain), rtol=0, atol=1e-13)
    scale = 0.5 * np.sum(np.square(np.asarray(setup.problem.views[0].target)))  # what r^T r is a difference of
    np.testing.assert_allclose(loss, 0.5 * np.sum(r_plain ** 2), rtol=1e-11, atol=1e-14 * scale)
    np.testing.assert_allclose(gram, jac.T @ jac, rtol=1e-9, atol=1e-12 * np.abs(gram).max())
    np.testing.assert_allclose(grad, expected, rtol=1e-9, atol=1e-12 * np.abs(grad).max())
    assert np.abs(grad).max() > 1e-3 and loss > 0


def test_float32_moments_and_loss():
    """In float32 the loss is summed from the residuals (a difference of the moments' sums would
    lose the last steps' decrease to rounding): it equals 0.5 r^T r to float32 rounding, and
    J^T J, J^T r the float64 ones to 1e-5."""
    out = {}
    for x64 in (True, False):
        setup = _setup(materials=("red", "floor"), x64=x64)
        with jax.enable_x64(x64):
            x = jnp.asarray(setup.layout.x_of(setup.layout.flatten(setup.initial) * 0.8), setup.dtype)
            prepared = jax.jit(moments.prepare)(setup.problem, x)
            out[x64] = [np.asarray(v, np.float64) for v in jax.jit(moments.linearise)(prepared, x, setup.problem)[:3]]
            out[x64].append(0.5 * np.sum(np.asarray(residuals(x, setup.problem), np.float64) ** 2))
    (loss, gram, grad, plain), (loss32, gram32, grad32, plain32) = out[True], out[False]
    np.testing.assert_allclose(loss32, plain32, rtol=1e-6)
    np.testing.assert_allclose(loss32, loss, rtol=1e-5)
    np.testing.assert_allclose(gram32, gram, rtol=1e-5, atol=1e-5 * np.abs(gram).max())
    np.testing.assert_allclose(grad32, grad, rtol=1e-4, atol=1e-5 * np.abs(grad).max())


@pytest.mark.parametrize("kwargs", [{"ceiling": 1.0}, {"loss": "huber"}])
def test_moments_do_not_apply_to_clipped_targets_or_robust_losses(kwargs):
    """A clipped target (censored rows: the model's pixels are min(model, ceiling)) and a robust
    loss take the closed-form or the forward-mode normal equations instead."""
    scene = make_scene(size=20, lights=BRIGHT)
    target = target_of(scene)
    setup = Setup(scene, [np.minimum(target, 1.0) if "ceiling" in kwargs else target], "red", **kwargs)
    assert not moments.applies(setup.problem)


@pytest.mark.parametrize("materials", [("red",), ("red", "floor")])
def test_solve_from_moments_takes_the_closed_form_steps(materials):
    """From a 30 % perturbed start the box LM on the moments (`solve_box`) takes the steps that the
    box LM on the exact closed-form normal equations takes, to the same point (1e-10; but n of the
    matte floor, which the target does not determine) and J^T J, with
    the same losses on the way (to the rounding of r^T r from the sums: 1e-14 of |target|^2)."""
    scene = make_scene(size=24, red=TRUTH)
    start = {f"{m}.{k}": v for m in materials for k, v in perturbed({**TRUTH, "ks": [0.5, 0.4, 0.3]}).items()
             if m == "red" or k in ("ka", "kd")}
    setup = Setup(scene, [target_of(scene)], list(materials), init=start, x64=True)
    assert moments.applies(setup.problem)
    with jax.enable_x64(True):
        lower, upper = (jnp.asarray(b) for b in setup.layout.bounds())
        x0 = jnp.asarray(setup.x0)
        closed = jax.jit(partial(lm.box_lm, lm.squared(linearise), max_steps=64, rtol=1e-8, atol=1e-10,
                                 lambda0=lm.LAMBDA0_BY_PARTS))(x0, lower, upper, setup.problem)
        solved = lm.solve_box(setup.problem, x0, lower, upper, 64, 1e-8, 1e-10)
        r_at, gram_at = residuals(solved[0], setup.problem), linearise(solved[0], setup.problem)[1]
    assert lm.CODES[int(solved[1])] == "successful" and int(solved[2]) == int(closed[2])
    values = setup.values(np.asarray(closed[0]))
    matte = {p.index for p in setup.layout if p.kind == "ks" and np.max(values[p.key]) < 1e-6}  # (the floor)
    determined = np.concatenate([np.full(p.size, not (p.kind == "n" and p.index in matte)) for p in setup.layout])
    np.testing.assert_allclose(np.asarray(solved[0])[determined], np.asarray(closed[0])[determined], rtol=1e-10,
                               atol=1e-12)
    scale = 0.5 * np.sum(np.square(np.asarray(setup.problem.views[0].target)))  # (as above)
    np.testing.assert_allclose(np.asarray(solved[3])[:int(solved[2])], np.asarray(closed[3])[:int(closed[2])],
                               rtol=1e-9, atol=1e-14 * scale)
    np.testing.assert_allclose(setup.problem.view_residuals(solved[4]), setup.problem.view_residuals(r_at),
                               atol=1e-13)
    np.testing.assert_allclose(np.asarray(solved[5]), np.asarray(gram_at), rtol=1e-9, atol=1e-12)
    for key, value in TRUTH.items():
        np.testing.assert_allclose(setup.values(np.asarray(solved[0]))[f"red.{key}" if len(materials) > 1 else key],
                                   value, rtol=1e-4)  # (a float32 render is the target)


def test_batch_of_solves_from_moments():
    """`solve_box_batch` (vmap over starts and targets) gives each target the solve it gets alone."""
    scene = make_scene(size=16, red=TRUTH)
    other = make_scene(size=16, red={**TRUTH, "kd": [0.3, 0.4, 0.5], "n": 12.0})
    setup = Setup(scene, [target_of(scene)], "red", init=perturbed(TRUTH), x64=True)
    assert moments.applies(setup.problem)
    with jax.enable_x64(True):
        lower, upper = (jnp.asarray(b) for b in setup.layout.bounds())
        x0 = jnp.asarray(setup.x0)
        targets = jnp.stack([setup.problem.views[0].target,
                             jnp.asarray(target_of(other).reshape(-1, 3)[setup.views[0].pixels])])
        batch = lm.solve_box_batch(setup.problem, jnp.stack([x0, x0]), targets[:, None], lower, upper, 64, 1e-8,
                                   1e-10)
        for b in range(2):
            alone = lm.solve_box(setup.problem.with_targets([targets[b]]), x0, lower, upper, 64, 1e-8, 1e-10)
            assert int(batch[2][b]) == int(alone[2]) and lm.CODES[int(alone[1])] == "successful"
            np.testing.assert_allclose(np.asarray(batch[0][b]), np.asarray(alone[0]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(setup.values(np.asarray(batch[0][1]))["n"], 12.0, rtol=1e-4)  # (float32 targets)


def test_float32_recovery_sums_its_gradient_from_r():
    """A float32 fit of a noise-free 64 x 64 target recovers every value to 1e-5: its J^T r is summed
    from r (from the moments, a difference of sums as large as |target|^2, it was off by up to 8e-5
    here)."""
    scene = make_scene(size=64, red=TRUTH)
    setup = Setup(scene, [target_of(scene)], "red", init=perturbed(TRUTH), x64=False)
    assert moments.applies(setup.problem)
    lower, upper = (jnp.asarray(b, jnp.float32) for b in setup.layout.bounds())
    solved = lm.solve_box(setup.problem, jnp.asarray(setup.x0, jnp.float32), lower, upper, 64, 1e-5, 1e-7)
    assert lm.CODES[int(solved[1])] == "successful"
    found = setup.values(np.asarray(solved[0]))
    for key, value in TRUTH.items():
        np.testing.assert_allclose(found[key], value, rtol=1e-5)


def test_a_ceiling_no_target_value_reaches_is_solved_unclipped_where_the_model_ends_below_it(monkeypatch):
    """Targets with a ceiling that no value reaches (as an 8-bit file's 1.0 often is): the solve runs
    on the problem without ceilings -- on the column moments -- and, the model ending below the
    ceiling, is the clipped problem's solve (x to the solver's rtol, r and J^T J at it); where the
    model would end above a ceiling, the clipped problem is solved after it; a target value at the
    ceiling leaves the problem clipped."""
    from difflab.fit import solvers
    from difflab.fit.options import FitOptions

    top = float(target_of(make_scene(size=20, lights=BRIGHT)).max())
    setup = _setup(ceiling=1.25 * top)
    problem = setup.problem
    unclipped = problem.without_ceilings()
    assert not moments.applies(problem) and moments.applies(unclipped)
    assert unclipped.views[0].ceiling is None and problem.views[0].ceiling is not None
    solved, real = [], solvers._box_lm
    monkeypatch.setattr(solvers, "_box_lm", lambda p, *args: solved.append(p.views[0].ceiling is None) or
                        real(p, *args))
    options = FitOptions.make(None, progress=False)
    lower, upper = (np.asarray(b) for b in setup.layout.bounds())
    with jax.enable_x64(True):
        fast = solvers.run(problem, setup.x0, options)
        clipped = real(problem, setup.x0, lower, upper, options, None)
    assert solved == [True] and fast.result == clipped.result == "successful"
    np.testing.assert_allclose(fast.x, clipped.x, rtol=1e-7)
    np.testing.assert_allclose(fast.linearised[0], clipped.linearised[0], atol=1e-9)
    np.testing.assert_allclose(fast.linearised[1], clipped.linearised[1], rtol=1e-6)
    # the model's values decide: below the ceiling at every entry that counts, or not
    r = np.zeros(problem.views[0].target.size)  # flat, in the problem's order
    assert problem.below_ceilings(r)
    r[np.argmax(np.asarray(problem.views[0].target))] = 0.25 * top + 1e-12  # the brightest entry at the ceiling
    assert not problem.below_ceilings(r)
    monkeypatch.setattr(type(problem), "below_ceilings", lambda self, r: False)
    solved.clear()
    with jax.enable_x64(True):
        again = solvers.run(problem, setup.x0, options)
    assert solved == [True, False]
    np.testing.assert_array_equal(again.x, clipped.x)
    assert _setup(ceiling=top).problem.without_ceilings() is None  # the brightest target value at the ceiling
    assert _setup(ceiling=1.25 * top, loss="huber").problem.without_ceilings() is None  # r' = rho(r) hides the model
