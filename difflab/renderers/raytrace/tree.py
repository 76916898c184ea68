"""The recorded ray tree: every node of every sample's ray tree, as the Whitted ray tracer traced it.

A ray-traced image is linear in what each tree node sees: every node adds its path weight times its
local colour (or the background). The geometry of the tree -- where rays go, what they hit, which
lights they see -- does not depend on ka, kd, ks, n, m, f0, kr, kt or the absorption, so the tree,
recorded once, lets the image be re-evaluated for new values of those: `difflab.fit.evaluate_tree`
forms it (the one place the tree's image is formed, in JAX, differentiably). The Fresnel factors
depend on ior, and the directions on ior and the normals, so ior is not re-evaluable.

Two caveats make the tree's *shape* depend on material values: a child ray exists only where its
weight kr F_r + kt T (or kt F_t) was > 0 when the tree was recorded, and Hall's adaptive control drops
children whose weight fell below its threshold. Record with kr / kt > 0 on every material whose kr /
kt is to be fitted, and with `adaptive_threshold` 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PRIMARY, REFLECTED, REFRACTED = 0, 1, 2  # a node's kind: how its parent spawned it

__all__ = ["PRIMARY", "REFLECTED", "REFRACTED", "RayTree"]


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
      medium      material id of the medium the ray travelled in to get here: the innermost
                  transparent object around it (`nesting`: media nest), -1 outside every one;
      distance    (float32) how far it travelled in it (inf where it hit nothing; a primary ray: from
                  the eye, or from the last surface before the near plane, `medium.primary_medium`).
                  The path weight takes exp(-alpha d) over it, alpha = absorption of `medium`
                  (exactly 1 where alpha = 0).
      position, normal, view  (N, 3) float32: hit point, unit shading normal facing the incoming ray
                  (pointing inwards inside an object), unit direction back along the incoming ray.
      light_dir (N, P, 3), light_dist (N, P), visibility (N, P) float32: per light, the unit
                  direction to it, its distance (inf: directional) and the shadow-ray visibility.
      crossings   (N, P, M) uint8: how many surfaces of each material the light's shadow ray crossed
                  (transparent shadows); the visibility of an unblocked shadow ray is
                  prod_m kt_m ^ crossings[.., m], so it follows new kt values (0: blocked, stays 0).
      fresnel     F at the node (0 where Fresnel weighting is off; 1 under total internal reflection).
      fresnel_r, fresnel_t, tir_share  the factors the node's children's edges take: a REFLECTED
                  child's edge weight is kr * fresnel_r + kt * tir_share and a REFRACTED child's
                  kt * fresnel_t (kr, kt of the node's material): (1, 1, 0) plain, (F, 1 - F, 0) with
                  Fresnel (at every surface, opaque or not), and under total internal reflection
                  (1, 0, 1) plain, (1, 0, 0) with Fresnel -- the refracted ray's share, kt or
                  kt (1 - F) = 0, goes to the reflected ray.
      local       (N, 3) float32: the node's local colour as rendered (background for misses).
      texel       (N, 3) float32: the texture value a textured material took at the node (it multiplies
                  the coefficient named by the material's texture_target), else 0.
      uv          (N, 2) float32: the texture coordinates it was read at (`surface.hit_texel`), else 0;
                  with the material's texture, filter and wrap they locate the nearest / bilinear taps
                  whose texels a fit varies (`difflab.fit.texels`; the footprint of the mip-mapped
                  filters is not recorded). texel and uv are (0, 3) / (0, 2) in a scene without image
                  textures (no memory spent on them).

    Per sample: `sample_fog` (S,) float32 fog blend f of the primary hit (1 where none) and
    `fog_color` (3,): the sample is f * sum + (1 - f) * fog_color.

    Evaluation (`difflab.fit.raytree.tree_image`): weight(root) = 1 * beer(root); weight(child) =
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
    tir_share: np.ndarray
    local: np.ndarray
    texel: np.ndarray
    uv: np.ndarray

    @property
    def n_nodes(self) -> int:
        return int(self.parent.shape[0])

    def primary(self) -> np.ndarray:
        """Global index of each sample's root node, (rows, cols)."""
        return self.sample_offset[:-1].reshape(self.grid_shape)
