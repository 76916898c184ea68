"""Properties (hypothesis, derandomized): the model is finite, non-negative and monotone in its
coefficients; the order of a mesh's triangles does not change an opaque image."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import scene_dict
from difflab import render
from difflab.geometry import teapot
from difflab.lighting import jax_model as jm

CI = settings(derandomize=True, max_examples=60, deadline=None)
unit = st.floats(0.0, 1.0)
coefficient = st.floats(0.0, 2.0)


def directions(draw, count):
    x = np.array(draw(st.lists(st.floats(-1, 1), min_size=3 * count, max_size=3 * count))).reshape(count, 3)
    return x  # may be zero-length on purpose


@st.composite
def shading_inputs(draw):
    count = 4
    lights = jm.LightsJ(
        kind=jnp.array(draw(st.lists(st.sampled_from([0, 1, 2]), min_size=2, max_size=2))),
        position=jnp.array(directions(draw, 2)) * 3,
        direction=jm.normalize(jnp.array(directions(draw, 2)) + jnp.array([0.0, -1e-3, 0.0])),
        intensity=jnp.array(draw(st.lists(coefficient, min_size=6, max_size=6))).reshape(2, 3),
        attenuation=jnp.array(draw(st.lists(unit, min_size=6, max_size=6))).reshape(2, 3) + jnp.array([0.1, 0, 0]),
        cos_cutoff=jnp.array(draw(st.lists(st.floats(0.0, 1.0), min_size=2, max_size=2))),
        exponent=jnp.array(draw(st.lists(st.floats(0.0, 100.0), min_size=2, max_size=2))),
    )
    p = jnp.array(directions(draw, count))
    normal = jm.normalize(jnp.array(directions(draw, count)))
    v = jm.normalize(jnp.array(directions(draw, count)))
    l, d = jm.light_vector(lights, p[:, None, :])
    visibility = jnp.array(draw(st.lists(unit, min_size=2 * count, max_size=2 * count))).reshape(count, 2)
    return lights, normal, v, l, d, visibility


_shade = jax.jit(jm.shade, static_argnums=1)  # one compile per model: every example has the same shapes


def shade(inputs, ka, kd, ks, n, model):
    lights, normal, v, l, d, visibility = inputs
    mat = jm.MaterialJ(jnp.full(3, ka), jnp.full(3, kd), jnp.full(3, ks), jnp.asarray(n), jnp.asarray(0.3),
                       jnp.asarray(0.04))
    return np.asarray(_shade(mat, model, normal, v, lights, l, d, visibility, jnp.full(3, 0.2)))


@CI
@given(shading_inputs(), coefficient, coefficient, coefficient, st.floats(0.0, 1000.0), st.sampled_from([0, 1, 2]),
       st.floats(0.0, 1.0))
def test_shading_is_finite_non_negative_and_monotone(inputs, ka, kd, ks, n, model, extra):
    base = shade(inputs, ka, kd, ks, n, model)
    assert np.all(np.isfinite(base)) and np.all(base >= 0.0)
    assert np.all(shade(inputs, ka, kd + extra, ks, n, model) >= base - 1e-6)
    assert np.all(shade(inputs, ka, kd, ks + extra, n, model) >= base - 1e-6)


MESH = teapot(3)


@settings(derandomize=True, max_examples=4, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_triangle_order_does_not_change_an_opaque_image(tmp_path_factory, seed):
    folder = tmp_path_factory.mktemp("order")
    order = np.random.default_rng(seed).permutation(MESH.n_faces)
    images = []
    for name, faces in [("plain", MESH.faces), ("shuffled", MESH.faces[order])]:
        path = folder / f"{name}.obj"
        path.write_text("\n".join([f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in MESH.vertices] +
                                  ["f " + " ".join(str(i + 1) for i in f) for f in faces]) + "\n")
        scene = scene_dict([{"type": "mesh", "file": str(path), "material": "m", "transform": {"scale": 0.45}}],
                           {"m": {"ka": [0.1] * 3, "kd": [0.6, 0.4, 0.3], "ks": [0.4] * 3, "n": 16}},
                           lights=[{"type": "point", "position": [3, 4, 5]}], ambient=(0.2, 0.2, 0.2),
                           camera={"eye": [1, 2, 5], "target": [0, 0.6, 0], "width": 40, "height": 40})
        images.append(render(scene, shading="phong"))
    assert np.array_equal(images[0], images[1])
