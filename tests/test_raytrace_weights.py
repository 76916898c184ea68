"""The ray tree's weights where the lecture's formula leaves a choice: total internal reflection
without Fresnel weighting (the refracted share kt goes to the reflected ray, as POV-Ray traces it),
checked against a POV-Ray render kept in tests/data/pov (`experiments/pov_references.py` renders it
again), and the recorded ray tree re-forming the same weights in JAX, values and derivatives."""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from difflab import Scene, render, render_frame
from difflab.fit import MaterialTable
from difflab.fit.raytree import tree_image, tree_to_jax
from difflab.lighting.jax_model import lights_to_jax

POV = Path(__file__).parent / "data" / "pov"


def tir_box(**glass) -> Scene:
    """The docs' example glass (kt 0.9, kr 0, ior 1.5, fresnel "none") as a cube over a checker
    floor, 48 x 36, depth 10: rays entering its top leave through no side (TIR) on many paths."""
    d = json.loads((POV / "tir_box.scene.json").read_text())
    d["materials"]["glass"].update(glass)
    return Scene.from_dict(d)


def test_glass_cube_under_total_internal_reflection_matches_pov_ray():
    """difflab against POV-Ray 3.7 (`tir_box.pov`, no anti-aliasing): 37.2 dB, 14 pixels off by more
    than 0.05, all on the cube's silhouette (pixel-centre sampling of an edge); giving the TIR ray the
    weight kr = 0 instead left black bands (20.5 dB, 127 pixels)."""
    want = np.load(POV / "tir_box.npy")
    got = render(tir_box(), method="raytrace")
    psnr = 10 * np.log10(1.0 / np.mean((got - want) ** 2))
    off = np.abs(got - want).max(axis=-1) > 0.05
    assert psnr > 35.0 and off.sum() <= 16, (psnr, np.argwhere(off).tolist())


def test_tree_reforms_the_tir_share_for_new_kr_kt():
    """The tree recorded at (kr, kt) = (0.1, 0.9) and re-evaluated at (0.3, 0.6) equals Warp's
    render at (0.3, 0.6) -- a TIR node's reflected child takes kr + kt (`RayTree.tir_share`) -- and
    its derivatives in the glass's kr and kt equal central differences of Warp renders (h = 5e-3)."""
    tree = render_frame(tir_box(kr=0.1), threads=2).ray_tree
    assert np.any(tree.tir_share == 1.0) and set(np.unique(tree.tir_share)) <= {0.0, 1.0}
    scene = tir_box(kr=0.3, kt=0.6)
    glass = scene.material_names.index("glass")
    with jax.enable_x64(True):
        tree_j = tree_to_jax(tree, dtype=jnp.float64)
        table = MaterialTable.from_scene(list(scene.materials.values()), jnp.float64)
        lights = lights_to_jax(tuple(scene.lights), jnp.float64)

        def image(values):
            mats = table._replace(kr=table.kr.at[glass].set(values[0]), kt=table.kt.at[glass].set(values[1]))
            return tree_image(tree_j, mats, lights, jnp.asarray(scene.ambient), jnp.asarray(scene.background))

        values = jnp.asarray([0.3, 0.6])
        np.testing.assert_allclose(np.asarray(image(values)).reshape(36, 48, 3), render(scene, method="raytrace"),
                                   atol=1e-5)
        jac = np.asarray(jax.jacfwd(image)(values))  # (U, 3, 2)
    h = 5e-3
    for k, key in enumerate(("kr", "kt")):
        plus, minus = (render(tir_box(**{"kr": 0.3, "kt": 0.6, key: [0.3, 0.6][k] + s * h}), method="raytrace")
                       for s in (1, -1))
        fd = ((plus.astype(np.float64) - minus) / (2 * h)).reshape(-1, 3)
        assert np.abs(fd).max() > 0.1
        np.testing.assert_allclose(jac[..., k], fd, rtol=2e-3, atol=2e-5, err_msg=f"d image / d {key}")
