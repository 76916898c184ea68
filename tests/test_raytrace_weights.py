"""The ray tree's weights where the lecture's formula leaves a choice: total internal reflection
without Fresnel weighting (the refracted share kt goes to the reflected ray, as POV-Ray traces it),
checked against a POV-Ray render kept in tests/data/pov (`experiments/pov_references.py` renders it
again), and the recorded ray tree re-forming the same weights in JAX, values and derivatives; and
transparent shadows through many surfaces (kt per crossing, up to the cap, then blocked), both ways
of casting shadow rays against the closed form."""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflab import Scene, render, render_frame
from difflab.fit import MaterialTable
from difflab.fit.raytree import tree_image, tree_to_jax
from difflab.lighting.jax_model import lights_to_jax
from difflab.renderers.trace import MAX_SHADOW_CROSSINGS

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


# -- transparent shadows through many surfaces -------------------------------------------------------------

LIGHT_DIR = np.array([1.0, 0.12, 0.0]) / np.linalg.norm([1.0, 0.12, 0.0])
LIGHT_AT = 30.0 * LIGHT_DIR


def sphere_stack(n: int, radius: float, fov: float, around_light: bool, shell: str = "g") -> Scene:
    """n clear spheres (kt 0.95, ior 1, kd 0) 2.25 radii apart in a row from near the origin toward a
    point light 30 units away (elevation 6.8 degrees), and with `around_light` one more (radius 0.2) around the
    light, of material `shell` ("g" clear, "o" opaque), over a floor y = 0 seen from above, depth 1: a
    floor point whose shadow ray passes the row crosses 2 surfaces per sphere of the row (and 1 of the light's)."""
    centres = [(3.0 * radius + 2.25 * radius * k) * LIGHT_DIR for k in range(n)]  # apart, as the surfaces
    objects = [{"type": "sphere", "center": c.tolist(), "radius": radius, "material": "g"} for c in centres]
    if around_light:
        objects.append({"type": "sphere", "center": LIGHT_AT.tolist(), "radius": 0.2, "material": shell})
    objects.append({"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "f"})
    return Scene.from_dict({
        "camera": {"eye": [-1.5, 2.5, 2.5], "target": [radius, 0, 0], "fov_y": fov, "width": 48,
                   "height": 36, "far": 20},
        "lights": [{"type": "point", "position": LIGHT_AT.tolist(), "intensity": 1}],
        "materials": {"g": {"kd": 0, "kt": 0.95, "ior": 1.0}, "f": {"kd": 0.8}, "o": {"kd": 0}},
        "objects": objects, "render": {"method": "raytrace", "max_depth": 1}})


def crossings_to_light(points: np.ndarray, scene: Scene) -> np.ndarray:
    """Per floor point (N, 3), the sphere surfaces the segment to the light crosses (float64 closed
    form), and whether any sphere's surface passes within 0.01 of the segment's ends or the segment
    within 0.01 of tangent to it: the shadow ray starts `compile_scene`'s offset epsilon (~6e-4
    here, ~5e-3 with the light's sphere in the scene's box) above the floor, which decides those."""
    count = np.zeros(len(points), int)
    unclear = np.zeros(len(points), bool)
    for obj in scene.objects[:-1]:
        d = LIGHT_AT - points
        length = np.linalg.norm(d, axis=1)
        d /= length[:, None]
        oc = np.asarray(obj.center) - points
        h = np.sum(oc * d, axis=1)
        disc = obj.radius ** 2 - (np.sum(oc * oc, axis=1) - h * h)
        root = np.sqrt(np.maximum(disc, 0.0))
        for t in (h - root, h + root):
            count += (disc > 0) & (t > 0) & (t < length)
            miss = np.sqrt(np.maximum(obj.radius ** 2 - disc, 0.0))  # the segment's distance to the centre
            unclear |= (np.abs(miss - obj.radius) < 0.01) | (np.abs(t) < 0.01) | (np.abs(t - length) < 0.01)
    return count, unclear


@pytest.mark.parametrize("n, radius, fov, around_light", [(7, 0.2, 30, False), (8, 0.2, 30, False),
                                                        (8, 0.2, 30, True), (127, 0.05, 12, True),
                                                        (128, 0.05, 12, False)])
def test_transparent_shadow_through_many_spheres_is_kt_per_crossing(n, radius, fov, around_light):
    """Every floor sample's shadow-ray visibility is 0.95^c, c the surfaces the ray crosses (closed
    form; 14, 16, 17, 255, 256 at most), up to c = 255 (trace.MAX_SHADOW_CROSSINGS); a ray crossing
    more counts as blocked (0) and is counted in stats["shadow_rays_cut"] -- in this scene the only
    shadow rays of visibility 0. The BVH's shadow rays and the light buffer's alike. 8 spheres (16
    crossings) gave 0 where 0.95^16 = 0.044 (the cap was 16, and the light buffer gave 0.0401)."""
    scene = sphere_stack(n, radius, fov, around_light)
    for light_buffer in (False, True):
        frame = render_frame(scene, light_buffer=light_buffer, threads=2)
        tree = frame.ray_tree
        floor = (tree.material == 1) & (tree.parent == -1)
        count, unclear = crossings_to_light(tree.position[floor].astype(np.float64), scene)
        assert count[~unclear].max() == 2 * n + around_light and count.min() == int(around_light)
        want = np.where(count <= MAX_SHADOW_CROSSINGS, 0.95 ** count, 0.0)
        got = tree.visibility[floor, 0]
        np.testing.assert_allclose(got[~unclear], want[~unclear], rtol=2e-5, atol=1e-30)
        cut = frame.stats["shadow_rays_cut"]
        assert cut == int(np.sum(tree.visibility == 0.0)) and (cut > 0) == (2 * n + around_light == 256)
        seen = (got > 0) & ~unclear
        assert np.all(tree.crossings[floor, 0, 0][seen] == count[seen])  # what the fit re-evaluates


def test_a_shadow_ray_blocked_beyond_its_255th_crossing_is_not_cut_on_either_path():
    """128 clear spheres in the row (256 crossings) and an opaque shell around the light: every
    shadow ray is blocked (visibility 0) whether or not it met 256 transparent surfaces first, and
    none is cut -- a ray counts as cut only where it would otherwise reach the light past the 255th
    crossing -- on the BVH's path and the light buffer's alike. The BVH's counted 256-crossing rays as
    cut (the light buffer, which sees the opaque shell among its candidates, did not)."""
    scene = sphere_stack(128, 0.05, 12, True, shell="o")
    for light_buffer in (False, True):
        frame = render_frame(scene, light_buffer=light_buffer, threads=2)
        tree = frame.ray_tree
        floor = (tree.material == 1) & (tree.parent == -1)
        count, unclear = crossings_to_light(tree.position[floor].astype(np.float64), scene)
        assert (count[~unclear] >= 2 * 128 + 1).sum() > 20  # rays that meet 256 clear surfaces, then the shell
        np.testing.assert_array_equal(tree.visibility[floor, 0], 0.0)
        assert frame.stats["shadow_rays_cut"] == 0, light_buffer
