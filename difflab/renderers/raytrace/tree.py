"""The recorded ray tree, and its reference evaluator.

A ray-traced image is linear in what each tree node sees: every node adds its path weight times its
local colour (or the background). The geometry of the tree -- where rays go, what they hit, which
lights they see -- does not depend on ka, kd, ks, n, m, f0, kr, kt or the absorption, so the tree,
recorded once, lets the image be re-evaluated for new values of those (the JAX fitter mirrors
`evaluate_ray_tree`). The Fresnel factors depend on ior, and the directions on ior and the normals,
so ior is not re-evaluable.

Two caveats make the tree's *shape* depend on material values: a child ray exists only where its
weight kr F_r (or kt F_t) was > 0 when the tree was recorded, and Hall's adaptive control drops
children whose weight fell below its threshold. Record with kr / kt > 0 on every material whose kr /
kt is to be fitted, and with `adaptive_threshold` 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._warp import wp
from ...lighting.warp_model import LightW, MaterialW, ambient_term, light_term, \
    lights_to_warp, materials_to_warp, surface_material, textured_material
from ...vocabulary import SPECULAR_MODELS, TEXTURE_TARGET_IDS
from ..frame import box_downsample

wp.set_module_options({"enable_backward": False})

PRIMARY, REFLECTED, REFRACTED = 0, 1, 2  # a node's kind: how its parent spawned it

__all__ = ["PRIMARY", "REFLECTED", "REFRACTED", "RayTree", "evaluate_ray_tree", "node_visibility", "shade_nodes"]


@dataclass(frozen=True)
class RayTree:
    """Every node of every sample's ray tree, in flat arrays (N nodes, P lights, S samples).

    Samples: the sample grid is `grid_shape` = (rows, cols) = (H * spp_side, W * spp_side), sample
    s = row * cols + col; pixel (i, j) averages the spp_side x spp_side block of samples
    (`frame.box_downsample`). Sample s owns nodes `sample_offset[s] : sample_offset[s + 1]`
    (int64, length S + 1), in depth-first order, so a parent always precedes its children.

    Per node (int32 unless said):
      sample      its sample index s.
      parent      global index of the parent node, -1 for the primary ray (the root).
      kind        PRIMARY (0), REFLECTED (1) or REFRACTED (2): how the parent spawned it.
      depth       1 for the primary ray, parent's + 1 otherwise.
      material    material id of the surface hit (index into `material_names`); -1: the ray hit
                  nothing and the node sees the background.
      object      scene object index hit (-1: none); face: mesh triangle index hit (-1: none).
      cell        checker cell 0 / 1 at the hit (cell 1 swaps in ka2 / kd2).
      medium      material id of the object the ray travelled inside to get here (-1: outside);
      distance    (float32) how far it travelled (inf where it hit nothing). The path weight takes
                  exp(-alpha d) over it, alpha = absorption of `medium` (exactly 1 where alpha = 0).
      position, normal, view  (N, 3) float32: hit point, unit shading normal facing the incoming ray
                  (pointing inwards inside an object), unit direction back along the incoming ray.
      light_dir (N, P, 3), light_dist (N, P), visibility (N, P) float32: per light, the unit
                  direction to it, its distance (inf: directional) and the shadow-ray visibility.
      crossings   (N, P, M) uint8: how many surfaces of each material the light's shadow ray crossed
                  (transparent shadows); the visibility of an unblocked shadow ray is
                  prod_m kt_m ^ crossings[.., m], so it follows new kt values (0: blocked, stays 0).
      fresnel     F at the node (0 where Fresnel weighting is off or the surface is opaque).
      fresnel_r, fresnel_t  the factors the node's children's edges take: a REFLECTED child's edge
                  weight is kr * fresnel_r and a REFRACTED child's kt * fresnel_t (kr, kt of the
                  node's material): (1, 1) plain, (F, 1 - F) with Fresnel, (1, 0) under total
                  internal reflection.
      local       (N, 3) float32: the node's local colour as rendered (background for misses).
      texel       (N, 3) float32: the texture value a textured material took at the node (it multiplies
                  the coefficient named by the material's texture_target), else 0.

    Per sample: `sample_fog` (S,) float32 fog blend f of the primary hit (1 where none) and
    `fog_color` (3,): the sample is f * sum + (1 - f) * fog_color.

    Evaluation (`evaluate_ray_tree`): weight(root) = 1 * beer(root); weight(child) =
    weight(parent) * edge(child) * beer(child); the sample's sum is sum over its nodes of
    weight * (local or background).
    """

    image_shape: tuple
    grid_shape: tuple
    spp_side: int
    material_names: tuple
    specular: str
    fresnel_mode: str
    max_depth: int
    sample_offset: np.ndarray
    sample_fog: np.ndarray
    fog_color: np.ndarray
    sample: np.ndarray
    parent: np.ndarray
    kind: np.ndarray
    depth: np.ndarray
    material: np.ndarray
    object: np.ndarray
    face: np.ndarray
    cell: np.ndarray
    medium: np.ndarray
    distance: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    view: np.ndarray
    light_dir: np.ndarray
    light_dist: np.ndarray
    visibility: np.ndarray
    crossings: np.ndarray
    fresnel: np.ndarray
    fresnel_r: np.ndarray
    fresnel_t: np.ndarray
    local: np.ndarray
    texel: np.ndarray

    @property
    def n_nodes(self) -> int:
        return int(self.parent.shape[0])

    def primary(self) -> np.ndarray:
        """Global index of each sample's root node, (rows, cols)."""
        return self.sample_offset[:-1].reshape(self.grid_shape)


@wp.kernel
def shade_nodes_kernel(material: wp.array(dtype=wp.int32), cell: wp.array(dtype=wp.int32),
                       texture_target: wp.array(dtype=wp.int32), texel: wp.array(dtype=wp.vec3),
                       normal: wp.array(dtype=wp.vec3), view: wp.array(dtype=wp.vec3),
                       light_dir: wp.array2d(dtype=wp.vec3), light_dist: wp.array2d(dtype=float),
                       visibility: wp.array2d(dtype=float), lights: wp.array(dtype=LightW),
                       materials: wp.array(dtype=MaterialW), specular: int, ambient: wp.vec3, background: wp.vec3,
                       local: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    if material[k] < 0:
        local[k] = background
        return
    mat = surface_material(materials[material[k]], cell[k])
    if texture_target[material[k]] >= 0:
        mat = textured_material(mat, texture_target[material[k]], texel[k])
    total = ambient_term(mat, ambient)
    for q in range(lights.shape[0]):
        s = visibility[k, q]
        if s > 0.0:
            total = total + s * light_term(lights[q], mat, specular, normal[k], view[k], light_dir[k, q],
                                           light_dist[k, q])
    local[k] = total


def ordered_materials(tree: RayTree, materials) -> list:
    """Materials in the tree's id order, from a sequence or a name -> Material mapping."""
    if isinstance(materials, dict):
        return [materials[name] for name in tree.material_names]
    return list(materials)


def node_visibility(tree: RayTree, materials) -> np.ndarray:
    """(N, P) shadow-ray visibility under new kt: prod_m kt_m ^ crossings where the ray was not blocked."""
    crossed = tree.crossings.sum(axis=-1) > 0
    if not crossed.any():
        return tree.visibility
    kt = np.array([m.kt for m in ordered_materials(tree, materials)], np.float64)
    product = np.prod(kt ** tree.crossings.astype(np.float64), axis=-1)
    return np.where(crossed & (tree.visibility > 0), product, tree.visibility).astype(np.float32)


def texture_targets(materials) -> np.ndarray:
    """Per material: the TARGET_* id its image texture modulates, or -1 without a texture."""
    return np.array([TEXTURE_TARGET_IDS[m.texture_target] if m.texture is not None else -1 for m in materials],
                    np.int32)


def shade_nodes(tree: RayTree, materials, lights, ambient, background, device: str = "cpu") -> np.ndarray:
    """Local colour (N, 3) float32 of every node under new materials / lights / ambient: the one
    illumination model (its Warp half) evaluated on the recorded hit data, with the shadow rays'
    visibility re-evaluated for new kt (`node_visibility`); background for misses."""
    n = tree.n_nodes
    n_lights = len(lights)
    arr = lambda a, dtype: wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)  # noqa: E731
    light_dir = tree.light_dir if n_lights else np.zeros((n, 1, 3), np.float32)
    light_dist = tree.light_dist if n_lights else np.zeros((n, 1), np.float32)
    visibility = node_visibility(tree, materials) if n_lights else np.zeros((n, 1), np.float32)
    local = wp.zeros(max(n, 1), dtype=wp.vec3, device=device)
    if n:
        wp.launch(shade_nodes_kernel, dim=n, inputs=[
            arr(tree.material, wp.int32), arr(tree.cell, wp.int32), arr(texture_targets(ordered_materials(tree, materials)),
                                                                        wp.int32), arr(tree.texel, wp.vec3),
            arr(tree.normal, wp.vec3), arr(tree.view, wp.vec3),
            arr(light_dir, wp.vec3), arr(light_dist, float), arr(visibility, float), lights_to_warp(lights, device),
            materials_to_warp(ordered_materials(tree, materials), device), SPECULAR_MODELS[tree.specular],
            wp.vec3(*np.asarray(ambient, np.float32)), wp.vec3(*np.asarray(background, np.float32)), local],
            device=device)
    return local.numpy()[:n]


def path_weights(tree: RayTree, materials) -> np.ndarray:
    """(N, 3) float64 weight of every node: the product of edge weights and Beer factors from the root."""
    materials = ordered_materials(tree, materials)
    kr = np.array([m.kr for m in materials], np.float64)
    kt = np.array([m.kt for m in materials], np.float64)
    alpha = np.array([m.absorption for m in materials], np.float64).reshape(-1, 3)
    weight = np.ones((tree.n_nodes, 3))
    for level in range(1, tree.max_depth + 1):
        nodes = np.flatnonzero(tree.depth == level)
        if nodes.size == 0:
            break
        if level > 1:
            parent = tree.parent[nodes]
            parent_mat = tree.material[parent]
            edge = np.where(tree.kind[nodes] == REFLECTED, kr[parent_mat] * tree.fresnel_r[parent],
                            kt[parent_mat] * tree.fresnel_t[parent])
            weight[nodes] = weight[parent] * edge[:, None]
        inside = nodes[tree.medium[nodes] >= 0]
        if inside.size:
            a = alpha[tree.medium[inside]]
            d = tree.distance[inside].astype(np.float64)[:, None]
            with np.errstate(invalid="ignore", over="ignore"):
                weight[inside] *= np.where(a > 0.0, np.exp(-a * d), 1.0)
    return weight


def evaluate_ray_tree(tree: RayTree, materials, lights, ambient, background, *, local=None,
                      device: str = "cpu") -> np.ndarray:
    """Re-evaluate the ray-traced image from its recorded tree: (H, W, 3) float32 linear RGB.

    Arguments:
        tree: the `RayTree` of a ray-traced `Frame`.
        materials: scene `Material`s in the tree's id order (or a name -> Material mapping);
            ka, kd, ks, n, m, f0, kr, kt and absorption may differ from the recorded ones.
        lights: the scene's `Light`s (same count and positions; intensities / attenuation may differ).
        ambient, background: RGB.
        local: optional (N, 3) local colours to use instead of shading the nodes (e.g. `tree.local`).

    Returns: the image, equal to the Warp render with those values (within float32 rounding) as long
    as the tree's shape is unchanged (see the module docstring).
    """
    if local is None:
        local = shade_nodes(tree, materials, lights, ambient, background, device)
    local = np.asarray(local, np.float64).copy()
    local[tree.material < 0] = np.asarray(background, np.float64)
    radiance = path_weights(tree, materials) * local
    n_samples = tree.sample_offset.shape[0] - 1
    total = np.stack([np.bincount(tree.sample, weights=radiance[:, c], minlength=n_samples) for c in range(3)], -1)
    fog = tree.sample_fog.astype(np.float64)[:, None]
    samples = fog * total + (1.0 - fog) * np.asarray(tree.fog_color, np.float64)
    samples = samples.astype(np.float32).reshape(*tree.grid_shape, 3)
    return box_downsample(samples, tree.spp_side)
