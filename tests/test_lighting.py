"""The illumination model: analytic values, Warp/JAX parity on random inputs, finite gradients."""

import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import warp as wp

from difflab.lighting import jax_model as jm
from difflab.lighting import warp_model as wm
from difflab.renderers.launch import init
from difflab.vocabulary import BLINN, PHONG, SPECULAR_MODELS, TORRANCE

init()
MODELS = SPECULAR_MODELS


def make_light(kind, position=(0, 0, 0), direction=(0, -1, 0), intensity=(1, 1, 1), attenuation=(1, 0, 0),
               cutoff_deg=180.0, exponent=0.0):
    return SimpleNamespace(type=kind, position=position, direction=direction, intensity=intensity,
                           attenuation=attenuation, cutoff_deg=cutoff_deg, exponent=exponent)


@wp.kernel(enable_backward=False)
def eval_model_kernel(
    lights: wp.array(dtype=wm.LightW),
    mats: wp.array(dtype=wm.MaterialW),
    p: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    model: int,
    out_l: wp.array(dtype=wp.vec3),
    out_d: wp.array(dtype=float),
    out_falloff: wp.array(dtype=float),
    out_spec: wp.array(dtype=float),
    out_term: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    light = lights[i]
    mat = mats[i]
    l, d = wm.light_vector(light, p[i])
    out_l[i] = l
    out_d[i] = d
    out_falloff[i] = wm.light_falloff(light, l, d)
    out_spec[i] = wm.specular_factor(model, normal[i], v[i], l, mat.n, mat.m, mat.f0)
    out_term[i] = wm.light_term(light, mat, model, normal[i], v[i], l, d)


def random_unit(rng, count):
    x = rng.normal(size=(count, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def random_inputs(seed, count=10_000):
    """Random lights, materials and geometry, with zero-length and back-facing cases mixed in."""
    rng = np.random.default_rng(seed)
    kinds = rng.choice(["point", "directional", "spot"], size=count)
    positions = rng.uniform(-3, 3, size=(count, 3))
    p = rng.uniform(-1, 1, size=(count, 3))
    p[::97] = positions[::97]  # the point sits on the light: zero-length L
    lights = [
        make_light(str(k), position=tuple(positions[i]), direction=tuple(random_unit(rng, 1)[0]),
                   intensity=tuple(rng.uniform(0, 2, 3)), attenuation=tuple(rng.uniform(0, 1, 3) + [0.2, 0, 0]),
                   cutoff_deg=float(rng.uniform(5, 90)), exponent=float(rng.choice([0.0, rng.uniform(0, 50)])))
        for i, k in enumerate(kinds)
    ]
    normal = random_unit(rng, count)
    v = random_unit(rng, count)
    v[::89] = 0.0  # degenerate view vector
    mats = []
    for i in range(count):
        mats.append(SimpleNamespace(
            ka=tuple(rng.uniform(0, 1, 3)), kd=tuple(rng.uniform(0, 1, 3)), ks=tuple(rng.uniform(0, 1, 3)),
            n=float(rng.choice([0.0, rng.uniform(0, 200)])), m=float(rng.uniform(0.05, 1.0)),
            f0=float(rng.uniform(0, 1)), kr=0.0, kt=0.0, ior=1.0, absorption=(0, 0, 0), checker=None))
    return lights, mats, p, normal, v


def warp_eval(lights, mats, p, normal, v, model):
    count = len(p)
    outs = [wp.zeros(count, dtype=t) for t in (wp.vec3, float, float, float, wp.vec3)]
    wp.launch(eval_model_kernel, dim=count,
              inputs=[wm.lights_to_warp(lights, "cpu"), wm.materials_to_warp(mats, "cpu"),
                      wp.array(p, dtype=wp.vec3), wp.array(normal, dtype=wp.vec3), wp.array(v, dtype=wp.vec3),
                      model, *outs])
    return [o.numpy() for o in outs]


def jax_material(mats):
    return jm.MaterialJ(*(jnp.asarray(np.array([getattr(m, f) for m in mats], np.float32)) for f in jm.MaterialJ._fields))


@pytest.mark.parametrize("model", MODELS)
def test_warp_and_jax_models_agree_on_random_inputs(model):
    lights, mats, p, normal, v = random_inputs(seed=MODELS[model])
    w_l, w_d, w_falloff, w_spec, w_term = warp_eval(lights, mats, p, normal, v, MODELS[model])
    lj = jm.lights_to_jax(lights)
    mat = jax_material(mats)
    j_l, j_d = jm.light_vector(lj, jnp.asarray(p, jnp.float32))
    j_falloff = jm.light_falloff(lj, j_l, j_d)
    j_spec = jm.specular_factor(MODELS[model], jnp.asarray(normal, jnp.float32), jnp.asarray(v, jnp.float32),
                                j_l, mat.n, mat.m, mat.f0)
    j_term = jm.light_term(lj, mat, MODELS[model], jnp.asarray(normal, jnp.float32), jnp.asarray(v, jnp.float32),
                           j_l, j_d)
    # float32 on both sides, summed in different orders: an ulp of cos becomes n ulps of cos^n, so the
    # specular terms get a relative tolerance of 4 n eps on top of 1e-5 (n = 170: 8e-5)
    n_ulps = 1e-5 + 4.0 * np.finfo(np.float32).eps * np.array([m.n for m in mats])
    for name, a, b, rtol in [("l", w_l, j_l, 1e-5), ("d", w_d, j_d, 1e-5), ("falloff", w_falloff, j_falloff, 1e-5),
                             ("spec", w_spec, j_spec, n_ulps), ("term", w_term, j_term, n_ulps[:, None])]:
        b = np.asarray(b)
        assert np.all(np.isfinite(b) | np.isinf(a)), name
        finite = np.isfinite(a) & np.isfinite(b)
        assert np.array_equal(a[~finite], b[~finite]), name
        rtol = np.broadcast_to(rtol, a.shape)[finite]
        excess = np.abs(a[finite] - b[finite]) - (1e-5 + rtol * np.abs(b[finite]))
        assert np.all(excess <= 0.0), f"{name}: worst excess {excess.max():.3g}"


@pytest.mark.parametrize("kinds", [("point",), ("directional",), ("spot",), ("point", "directional"),
                                   ("point", "spot"), ("directional", "spot"), ("point", "directional", "spot")])
def test_falloff_for_known_kinds_is_the_general_one(kinds):
    """`light_falloff` / `light_geometry` told which kinds the lights have leave the other kinds' terms
    out: the values are bit for bit the general ones (eager and compiled), spot cones included."""
    lights, _, p, normal, v = random_inputs(seed=len(kinds), count=600)
    chosen = [light for light in lights if light.type in kinds][:8]
    ids = tuple(sorted(jm.LIGHT_TYPES[k] for k in kinds))
    assert {light.type for light in chosen} == set(kinds)
    lj = jm.lights_to_jax(chosen)
    l, d = jm.light_vector(lj, jnp.asarray(p, jnp.float32)[:, None, :])  # (N, P, 3), (N, P)
    general = jm.light_falloff(lj, l, d)
    if "spot" in kinds:  # outside and inside a cone
        assert bool(jnp.any(general == 0.0)) and bool(jnp.any(general > 0.0))
    assert np.array_equal(np.asarray(jm.light_falloff(lj, l, d, ids)), np.asarray(general))
    geometry = jax.jit(lambda n, v, l, d, s, known: jm.light_geometry(PHONG, n, v, lj, l, d, s, known),
                       static_argnums=5)
    args = (jnp.asarray(normal, jnp.float32), jnp.asarray(v, jnp.float32), l, d, jnp.ones(d.shape))
    for got, want in zip(jax.tree_util.tree_leaves(geometry(*args, ids)), jax.tree_util.tree_leaves(geometry(*args, None))):
        assert np.array_equal(np.asarray(got), np.asarray(want))


def lambert_phong_reference(theta_deg, view_deg, ka, kd, ks, n, ia, il):
    """The textbook value for a directional light at theta and a viewer at view_deg, in one plane."""
    t, a = math.radians(theta_deg), math.radians(view_deg)
    normal, l, v = np.array([0, 0, 1.0]), np.array([math.sin(t), 0, math.cos(t)]), np.array([math.sin(a), 0, math.cos(a)])
    r = 2 * normal * normal.dot(l) - l
    if normal.dot(l) <= 0:
        return ka * ia
    return ka * ia + il * (kd * normal.dot(l) + ks * max(r.dot(v), 0.0) ** n)


@pytest.mark.parametrize("theta, view", [(0, 0), (60, -60), (25, -10), (60, 30), (100, 0)])
def test_single_light_matches_textbook_formula(theta, view):
    t, a = math.radians(theta), math.radians(view)
    light = make_light("directional", direction=(-math.sin(t), 0.0, -math.cos(t)), intensity=(0.9, 0.9, 0.9))
    mat = jm.MaterialJ(ka=jnp.full(3, 0.2), kd=jnp.full(3, 0.5), ks=jnp.full(3, 0.4), n=jnp.asarray(20.0),
                       m=jnp.asarray(0.3), f0=jnp.asarray(0.04))
    normal = jnp.array([0.0, 0.0, 1.0])
    v = jnp.array([math.sin(a), 0.0, math.cos(a)])
    lights = jm.lights_to_jax([light])
    l, d = jm.light_vector(lights, jnp.zeros(3))
    got = jm.shade(mat, PHONG, normal, v, lights, l, d, jnp.ones(1), jnp.full(3, 0.5))
    want = lambert_phong_reference(theta, view, 0.2, 0.5, 0.4, 20.0, 0.5, 0.9)
    np.testing.assert_allclose(np.asarray(got), np.full(3, want), atol=1e-6)


def test_attenuation_spot_and_blinn_closed_forms():
    light = make_light("spot", position=(0, 0, 2), direction=(0, 0, -1), attenuation=(1.0, 0.5, 0.25),
                       cutoff_deg=30, exponent=4)
    lights = jm.lights_to_jax([light])
    for x, expect_inside in [(0.0, True), (0.5, True), (2.0, False)]:
        p = jnp.array([x, 0.0, 0.0])
        l, d = jm.light_vector(lights, p)
        dist = math.hypot(x, 2.0)
        cos_axis = 2.0 / dist
        want = (cos_axis ** 4 if expect_inside else 0.0) / (1 + 0.5 * dist + 0.25 * dist * dist)
        np.testing.assert_allclose(float(jm.light_falloff(lights, l, d)[0]), want, rtol=1e-6)
    # Blinn: H halfway between L and V.
    normal = jnp.array([0.0, 0.0, 1.0])
    l = jnp.array([math.sin(0.4), 0.0, math.cos(0.4)])
    v = jnp.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(float(jm.specular_factor(BLINN, normal, v, l, 10.0, 0.3, 0.04)), math.cos(0.2) ** 10,
                               rtol=1e-6)


def test_torrance_is_fresnel_times_beckmann_over_four_n_dot_v():
    normal = jnp.array([0.0, 0.0, 1.0])
    l = jnp.array([math.sin(0.5), 0.0, math.cos(0.5)])
    v = jnp.array([-math.sin(0.3), 0.0, math.cos(0.3)])
    h = (np.asarray(l) + np.asarray(v)) / np.linalg.norm(np.asarray(l) + np.asarray(v))
    m, f0 = 0.35, 0.1
    c = h[2]
    beckmann = math.exp(-(1 - c * c) / (c * c) / m ** 2) / (math.pi * m * m * c ** 4)
    fresnel = f0 + (1 - f0) * (1 - float(np.dot(np.asarray(v), h))) ** 5
    want = fresnel * beckmann / (4 * math.cos(0.3))
    got = float(jm.specular_factor(TORRANCE, normal, v, l, 1.0, m, f0))
    np.testing.assert_allclose(got, want, rtol=1e-6)


@pytest.fixture
def x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


@pytest.mark.parametrize("model", MODELS)
def test_gradients_match_finite_differences(model, x64):
    from jax.test_util import check_grads

    lights = jm.lights_to_jax([make_light("point", position=(1.0, 2.0, 3.0), attenuation=(1.0, 0.1, 0.01)),
                               make_light("directional", direction=(0.3, -1.0, -0.2), intensity=(0.5, 0.4, 0.3))],
                              dtype=jnp.float64)
    rng = np.random.default_rng(0)
    normal = jnp.asarray(random_unit(rng, 16))
    normal = normal * jnp.sign(normal[:, 2:3])
    v = jnp.asarray(random_unit(rng, 16))
    v = v * jnp.sign(v[:, 2:3])
    p = jnp.asarray(rng.uniform(-1, 1, (16, 3)))
    l, d = jm.light_vector(lights, p[:, None, :])
    visibility = jnp.ones((16, 2))

    def image(ka, kd, ks, n, m, f0):
        mat = jm.MaterialJ(ka, kd, ks, n, m, f0)
        return jm.shade(mat, MODELS[model], normal, v, lights, l, d, visibility, jnp.array([0.1, 0.2, 0.3]))

    args = (jnp.array([0.1, 0.2, 0.3]), jnp.array([0.5, 0.4, 0.3]), jnp.array([0.3, 0.3, 0.6]), jnp.asarray(12.0),
            jnp.asarray(0.4), jnp.asarray(0.2))
    check_grads(image, args, order=1, modes=["rev"], atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("model", MODELS)
def test_gradient_in_n_is_finite_where_the_lobe_vanishes(model):
    """R.V <= 0, N.L <= 0, a zero view vector, n -> 0 and n = 1000 must not put NaN into a solver."""
    normal = jnp.array([[0.0, 0.0, 1.0]] * 5)
    l = jnp.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.6, 0.0, 0.8], [0.6, 0.0, 0.8]])
    v = jnp.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-0.6, 0.0, 0.8]])

    def total(n, m, f0):
        return jnp.sum(jm.specular_factor(MODELS[model], normal, v, l, n, m, f0))

    for n in [0.0, 1e-8, 1.0, 1000.0]:
        grads = jax.grad(total, argnums=(0, 1, 2))(jnp.asarray(n), jnp.asarray(0.3), jnp.asarray(0.04))
        assert all(np.isfinite(float(g)) for g in grads), (n, grads)


def test_zero_length_vectors_give_zero_not_nan():
    assert np.all(np.asarray(jm.normalize(jnp.zeros(3))) == 0.0)
    g = jax.grad(lambda x: jnp.sum(jm.normalize(x)))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(g)))
    assert float(jm.safe_pow(jnp.asarray(0.0), jnp.asarray(0.0))) == 1.0
    assert float(jm.safe_pow(jnp.asarray(0.0), jnp.asarray(2.0))) == 0.0


@pytest.mark.parametrize("rows", [1, 3, jm.SELECT_ROWS, jm.SELECT_ROWS + 1])
def test_table_rows_by_selects_equal_the_gather(rows):
    """Short tables are read by a chain of selects, long ones by a gather: both give column[index]."""
    rng = np.random.default_rng(rows)
    for shape in ((rows,), (rows, 3)):
        column = jnp.asarray(rng.normal(size=shape))
        index = jnp.asarray(rng.integers(0, rows, size=(7, 5)))
        np.testing.assert_array_equal(np.asarray(jm.table_row(column, index)), np.asarray(column)[np.asarray(index)])



def test_the_readme_names_exactly_the_functions_both_halves_share():
    """README: "The terms both compute have the same function names: ..." lists exactly the public
    functions defined in both files, and the Warp-only ones it names are in the Warp file alone (it
    said every function had a JAX twin; checker_cell and fog_blend have none)."""
    import inspect
    import re
    from pathlib import Path

    text = " ".join((Path(__file__).parents[1] / "README.md").read_text().split())
    listed = re.search(r"The terms both compute have the same function names: (.*?); `tests/", text).group(1)

    def functions(module):
        return {name for name, value in vars(module).items() if not name.startswith("_") and callable(value)
                and getattr(value, "__module__", "") == module.__name__ and not inspect.isclass(value)}

    shared = functions(wm) & functions(jm)
    assert set(re.findall(r"`(\w+)`", listed)) == shared
    warp_only = re.search(r"Only the Warp file has (.*?) besides", text).group(1)
    assert set(re.findall(r"`(\w+)`", warp_only)) <= functions(wm) - functions(jm)
