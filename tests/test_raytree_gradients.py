"""The ray-tree fit's derivatives against the renderer: for every parameter `fit_scene` fits (ka, kd,
ks, n of each material, kr, kt and the absorption of the glass), d(model pixel)/d(value), as the
solvers get it from JAX through the recorded tree, equals the central finite difference of two Warp
renders with that value moved by +-h (the tree's shape cannot change: adaptive control is off and
kr, kt stay > 0)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflab import Scene, load_scene, render_frame
from difflab.demos import scene_path
from difflab.fit import SceneSetup

W, H = 32, 24
MATERIALS = ("glass", "orange", "floor")
PARAMS = ("ka", "kd", "ks", "n", "glass.kr", "glass.kt", "glass.absorption")  # (kr, kt: the glass alone traces them)
# Grey coefficients (one value per coefficient, per_channel=False): moving the fitted grey value
# moves the material exactly as the fit does. ka, kd > 0 on the glass so that every term is seen.
GREY = {"glass": {"ka": 0.05, "kd": 0.08, "ks": 0.6, "n": 60.0, "kr": 0.6, "kt": 0.8, "absorption": 0.3},
        "orange": {"ka": 0.1, "kd": 0.6, "ks": 0.4, "n": 40.0},
        "floor": {"ka": 0.2, "kd": 0.7, "ks": 0.3, "n": 3.0}}


def scene_with(values: dict) -> Scene:
    """The glass scene at 32x24, depth 4, no adaptive cut-off, with grey material values
    {"material.kind": value} over GREY."""
    d = load_scene(scene_path("glass_sphere")).to_dict()
    d["camera"].update(width=W, height=H)
    d["render"].update(max_depth=4, adaptive_threshold=0.0)
    for name, fields in GREY.items():
        for kind, value in fields.items():
            value = values.get(f"{name}.{kind}", value)
            d["materials"][name][kind] = [value] * 3 if kind in ("ka", "kd", "ks", "absorption") else value
    return Scene.from_dict(d)


@pytest.fixture(scope="module")
def jacobian():
    """(setup, pixels used by the fit, d image / d value per parameter key as (U, 3) arrays)."""
    scene = scene_with({})
    target = render_frame(scene).image
    setup = SceneSetup(scene, [target], materials=MATERIALS, params=PARAMS, per_channel=False, max_depth=4)
    with jax.enable_x64(True):
        values = jnp.asarray(setup.layout.flatten(setup.initial))
        columns = np.asarray(jax.jacfwd(lambda v: setup.problem.images(v)[0])(values))  # (U, 3, p)
        jac = {p.key: columns[..., i] for i, p in enumerate(setup.layout)}  # grey: one entry each
    pixels = np.flatnonzero(setup.views[0].used)
    return setup, pixels, jac


def test_every_parameter_of_the_fit_is_covered(jacobian):
    setup, pixels, jac = jacobian
    want = {f"{m}.{k}" for m in MATERIALS for k in ("ka", "kd", "ks", "n")} | {"glass.kr", "glass.kt", "glass.absorption"}
    assert set(jac) == set(setup.initial) == want
    assert pixels.size > 0.7 * W * H  # the rows of sky above the floor show no fitted material


@pytest.mark.parametrize("key", [f"{m}.{k}" for m in MATERIALS for k in ("ka", "kd", "ks", "n")]
                         + ["glass.kr", "glass.kt", "glass.absorption"])
def test_gradient_equals_warp_central_differences(jacobian, key):
    setup, pixels, jac = jacobian
    value = float(np.asarray(setup.initial[key]).ravel()[0])
    h = 1e-3 * value if key.endswith(".n") else 5e-3  # n: relative step (the lobe is sharp); others: linear or smooth
    renders = [render_frame(scene_with({key: value + s * h})).image.reshape(-1, 3)[pixels].astype(np.float64)
               for s in (1, -1)]
    fd = (renders[0] - renders[1]) / (2 * h)
    got = jac[key]
    # visible: a 10 % change of the value moves some pixel by more than 1e-3 (n's lobes are small)
    assert np.abs(fd).max() * 0.1 * (value if key.endswith(".n") else 1.0) > 1e-3, "not visible in the image"
    # atol: Warp's float32 rounding (~6e-8 per pixel value) divided by 2h; rtol: h^2 terms of the n lobes
    np.testing.assert_allclose(got, fd, rtol=2e-3, atol=2e-5 if not key.endswith(".n") else 2e-4,
                               err_msg=f"d image / d {key}")
