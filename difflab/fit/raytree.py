"""The ray-traced image in JAX from a recorded ray tree: differentiable in every material's ka, kd, ks,
n (m, f0), kr, kt, absorption and texels, with the tree -- where every ray goes and what it hits -- fixed.

The Whitted ray tracer records every node of every sample's tree (`renderers.raytrace.tree.RayTree`). A
sample is the weighted sum of its nodes' local colours:

    sample = f * sum_nodes weight(node) * local(node) + (1 - f) * fog_color
    weight(root)  = beer(root)
    weight(child) = weight(parent) * edge(child) * beer(child)
    edge = kr[parent's material] * fresnel_r[parent] + kt[parent's material] * tir_share[parent]
                                                       (a reflected child; tir_share > 0 only under
                                                        total internal reflection without Fresnel)
         | kt[parent's material] * fresnel_t[parent]   (a refracted child)
    beer = exp(-absorption[medium] * distance)          (1 outside any medium)
    local = the one illumination model (`lighting.jax_model.shade`; a texture modulates its target)
            with the shadow rays' visibility prod_m kt_m ^ crossings_m; background where nothing was hit
    texel = the recorded texture value, or -- where the node's material has fitted texels -- the
            filter's taps at the node's recorded uv (`texels.point_texels`, as the G-buffer's samples)

formed here and nowhere else (the renderer records the tree; `evaluate_tree` re-forms its image).
Nodes are put in level order (by depth, then sample, then their recorded order), so each level's
weights are one gather from the level above and no scatter is needed on the way down; a level's
radiance goes to its samples with one sorted segment sum.

What the tree fixes: ior (the Fresnel factors and the refracted directions depend on it), the
geometry, the lights' positions, and the tree's *shape* -- a child exists only where its weight was
> 0 when recorded (kr, kt > 0) and Hall's adaptive control did not cut it. Record with kr / kt > 0 on
every material whose kr / kt is evaluated here, and with adaptive_threshold 0.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import LightsJ, lights_to_jax, safe_pow, shade, sum_axis, textured_surface
from ..lighting.warp_model import SPECULAR_MODELS
from ..renderers.raytrace.tree import REFLECTED
from .materials import MaterialTable
from .shading import PointsJ
from .texels import pixel_texels, point_texels

__all__ = ["TreeModel", "TreeJ", "tree_to_jax", "tree_pixels", "tree_image", "evaluate_tree",
           "tree_influence"]


class TreeJ(eqx.Module):
    """A ray tree (or the part of it that U pixels need) as JAX arrays, nodes in level order.

    points: every node's shading inputs (`PointsJ`; material -1 where the ray hit nothing).
    texel: (N, 3) the recorded texture value at each node (modulating its material's texture
        target), or None when no node has one.
    taps, tap_weight: (N, K) each node's filter taps into the fitted texels (`texels.TexelSource`;
        rows -1 where the node reads none: its recorded texel stays), or None when none is fitted.
    crossings: (N, P, M) how many surfaces of each material each shadow ray crossed (transparent
        shadows), or None when no shadow ray crossed any.
    parent_local: (N,) index of the node's parent within the level above (0 for roots).
    edge_material, edge_fresnel, edge_reflected: (N,) the parent's material id, the Fresnel factor of
        the edge (fresnel_r or fresnel_t of the parent) and whether the edge is a reflection.
    edge_tir: (N,) the factor of the parent's kt in a reflected edge (the parent's tir_share; 0 for a
        refracted one), or None where no edge has one.
    medium: (N,) material id the ray travelled inside (-1: none); distance (N,) (0 where infinite);
        escaped (N,) bool: the ray inside a medium hit nothing (infinite distance).
    sample: (N,) the node's sample, 0..S-1 (S = U * samples_per_pixel, pixel-major).
    fog: (S,) fog blend of each sample; fog_color (3,).
    levels: static (start, stop) of each depth's nodes. samples_per_pixel, specular, fog_on: static.
    """

    points: PointsJ
    texel: jnp.ndarray | None
    taps: jnp.ndarray | None
    tap_weight: jnp.ndarray | None
    crossings: jnp.ndarray | None
    parent_local: jnp.ndarray
    edge_material: jnp.ndarray
    edge_fresnel: jnp.ndarray
    edge_reflected: jnp.ndarray
    edge_tir: jnp.ndarray | None
    medium: jnp.ndarray
    distance: jnp.ndarray
    escaped: jnp.ndarray
    sample: jnp.ndarray
    fog: jnp.ndarray
    fog_color: jnp.ndarray
    levels: tuple = eqx.field(static=True)
    samples_per_pixel: int = eqx.field(static=True)
    specular: int = eqx.field(static=True)
    fog_on: bool = eqx.field(static=True)

    @property
    def n_nodes(self) -> int:
        return int(self.sample.shape[0])


def tree_pixels(tree) -> np.ndarray:
    """(H, W, S_pp) sample index of each pixel's samples (S_pp = spp_side^2), pixel-major."""
    side = int(tree.spp_side)
    h, w = tree.image_shape
    rows, cols = tree.grid_shape
    grid = np.arange(rows * cols).reshape(h, side, w, side)
    return grid.transpose(0, 2, 1, 3).reshape(h, w, side * side)


def tree_influence(tree, material_ids, crossing_ids=()) -> np.ndarray:
    """(H, W) bool: pixels whose colour depends on the materials `material_ids` (some node of one of
    their samples hit one of them, or travelled inside one -- its medium, whose absorption it takes:
    a camera inside a transparent object starts its primary rays there without hitting it) or on
    the kt of `crossing_ids` (a shadow ray crossed one)."""
    ids = np.asarray(list(material_ids), np.int64)
    touched = np.isin(tree.material, ids) | np.isin(tree.medium, ids)
    crossing_ids = list(crossing_ids)
    if crossing_ids and tree.crossings.size:
        touched |= (tree.crossings[..., crossing_ids] > 0).any(axis=(1, 2))
    n_samples = tree.sample_offset.shape[0] - 1
    per_sample = np.zeros(n_samples, bool)
    per_sample[tree.sample[touched]] = True
    return per_sample[tree_pixels(tree)].any(axis=-1)


def tree_to_jax(tree, pixels=None, dtype=jnp.float32, texels=None) -> TreeJ:
    """The nodes that `pixels` need, in level order, as a `TreeJ`.

    Arguments:
        tree: a `renderers.raytrace.tree.RayTree`.
        pixels: (U,) flat pixel indices (row * width + column); default: every pixel, in order.
        dtype: float dtype of the arrays (float64 needs x64 enabled).
        texels: a `texels.TexelSource` of the fitted textures (their taps at the nodes' uv), or None.
    Returns:
        a `TreeJ` whose `tree_image` is (U, 3), the pixels in the order given.
    """
    h, w = tree.image_shape
    pixels = np.arange(h * w) if pixels is None else np.asarray(pixels, np.int64).reshape(-1)
    per_pixel = tree_pixels(tree).reshape(h * w, -1)[pixels]  # (U, S_pp) old sample ids
    n_samples = tree.sample_offset.shape[0] - 1
    new_sample = np.full(n_samples, -1, np.int64)
    new_sample[per_pixel.reshape(-1)] = np.arange(per_pixel.size)

    keep = np.flatnonzero(new_sample[tree.sample] >= 0)
    order = keep[np.lexsort((keep, new_sample[tree.sample[keep]], tree.depth[keep]))]  # depth, sample, DFS
    depth = tree.depth[order]
    levels, start = [], 0
    for level in range(1, int(depth.max(initial=0)) + 1):
        stop = int(np.searchsorted(depth, level, side="right"))
        levels.append((start, stop))
        start = stop
    position = np.full(tree.n_nodes, -1, np.int64)  # old node -> position within its level
    for a, b in levels:
        position[order[a:b]] = np.arange(b - a)

    parent = tree.parent[order]
    has_parent = parent >= 0
    safe_parent = np.where(has_parent, parent, 0)
    parent_local = np.where(has_parent, position[safe_parent], 0)
    kind = tree.kind[order]
    edge_material = np.where(has_parent, np.maximum(tree.material[safe_parent], 0), 0)
    edge_fresnel = np.where(kind == REFLECTED, tree.fresnel_r[safe_parent], tree.fresnel_t[safe_parent])
    edge_tir = np.where(has_parent & (kind == REFLECTED), tree.tir_share[safe_parent], 0.0)
    distance = tree.distance[order].astype(np.float64)
    finite = np.isfinite(distance)

    def f(x):
        return jnp.asarray(np.asarray(x, np.float64), dtype=dtype)

    dist = tree.light_dist[order].astype(np.float64)
    points = PointsJ(normal=f(tree.normal[order]), view=f(tree.view[order]),
                     material=jnp.asarray(tree.material[order], jnp.int32),
                     cell=jnp.asarray(tree.cell[order], jnp.int32), light_dir=f(tree.light_dir[order]),
                     light_dist=f(np.where(np.isfinite(dist), dist, np.inf)),
                     visibility=f(tree.visibility[order]))
    crossings = tree.crossings[order]
    texel = tree.texel[order] if np.any(tree.texel) else None  # (0, 3) without textures
    taps = tap_weight = None
    if texels is not None:
        rows, weight = texels.taps_at(tree.material[order], tree.uv[order])
        taps, tap_weight = jnp.asarray(rows), f(weight)
    fog = tree.sample_fog[per_pixel.reshape(-1)]
    return TreeJ(
        points=points, texel=None if texel is None else f(texel), taps=taps, tap_weight=tap_weight,
        crossings=f(crossings) if crossings.any() else None,
        parent_local=jnp.asarray(parent_local, jnp.int32), edge_material=jnp.asarray(edge_material, jnp.int32),
        edge_fresnel=f(edge_fresnel), edge_reflected=jnp.asarray(kind == REFLECTED),
        edge_tir=f(edge_tir) if edge_tir.any() else None,
        medium=jnp.asarray(tree.medium[order], jnp.int32), distance=f(np.where(finite, distance, 0.0)),
        escaped=jnp.asarray(~finite), sample=jnp.asarray(new_sample[tree.sample[order]], jnp.int32),
        fog=f(fog), fog_color=f(tree.fog_color), levels=tuple(levels), samples_per_pixel=int(per_pixel.shape[1]),
        specular=SPECULAR_MODELS[tree.specular], fog_on=bool(np.any(fog != 1.0)),
    )


def node_visibility(tree: TreeJ, kt):
    """(N, P) shadow-ray visibility under kt: prod_m kt_m ^ crossings_m where the recorded ray was
    unblocked and crossed something (its recorded value elsewhere). Finite gradients at kt = 0."""
    vis = tree.points.visibility
    if tree.crossings is None:
        return vis
    crossed = jnp.sum(tree.crossings, axis=-1) > 0
    product = jnp.prod(safe_pow(kt, tree.crossings), axis=-1)
    return jnp.where(crossed & (vis > 0.0), product, vis)


def node_texels(tree: TreeJ, texels):
    """(N, 3) each node's texture value: its taps' weighted sum of the stacked fitted `texels`
    (T, 3) where it reads them, else the recorded value (None: no node is textured)."""
    if tree.taps is None:
        return tree.texel
    return point_texels(texels, tree.taps, tree.tap_weight, 1.0 if tree.texel is None else tree.texel)


def local_colors(tree: TreeJ, mats: MaterialTable, lights: LightsJ, ambient, background, texel=None):
    """(N, 3) local colour of every node: the illumination model (`jax_model.shade`) with the node's
    material (`jax_model.surface_material`; a texture modulating its target coefficient: `texel`
    (N, 3), default `node_texels(tree, mats.texels)`) and the shadow rays' visibility under the
    current kt; background where the ray hit nothing."""
    p = tree.points
    has_material = p.material >= 0
    mat_id = jnp.where(has_material, p.material, 0)
    mat = textured_surface(mats, mat_id, p.cell, node_texels(tree, mats.texels) if texel is None else texel)
    color = shade(mat, tree.specular, p.normal, p.view, lights, p.light_dir, p.light_dist,
                  node_visibility(tree, mats.kt), ambient)
    return jnp.where(has_material[:, None], color, background)


def node_factors(tree: TreeJ, mats: MaterialTable):
    """(N, 3) per node: edge weight from its parent (1 for roots) times its Beer factor."""
    edge = jnp.where(tree.edge_reflected, mats.kr[tree.edge_material], mats.kt[tree.edge_material])
    edge = edge * tree.edge_fresnel
    if tree.edge_tir is not None:  # total internal reflection: the refracted share kt joins the reflection
        edge = edge + mats.kt[tree.edge_material] * tree.edge_tir
    start = tree.levels[0][1] if tree.levels else 0
    edge = edge.at[:start].set(1.0)  # roots have no edge
    inside = tree.medium >= 0
    alpha = mats.absorption[jnp.where(inside, tree.medium, 0)]
    # A ray that escaped a medium has infinite length: Beer gives 0 where alpha > 0 (1 where alpha = 0),
    # with the gradient kept finite by never forming alpha * inf.
    beer = jnp.where(tree.escaped[:, None], jnp.where(alpha > 0.0, 0.0, 1.0),
                     jnp.exp(-alpha * tree.distance[:, None]))
    beer = jnp.where(inside[:, None], beer, 1.0)
    return edge[:, None] * beer


def tree_image(tree: TreeJ, mats: MaterialTable, lights: LightsJ, ambient, background, local=None, texel=None):
    """The pixels (U, 3) of the tree for these materials (linear RGB, as the Warp ray tracer forms them).

    Arguments:
        tree: a `TreeJ` (from `tree_to_jax`).
        mats: a `MaterialTable`; lights: the view's `LightsJ`; ambient, background: (3,).
        local: optional (N, 3) node colours to use instead of shading the nodes.
        texel: optional (N, 3) node texture values (`local_colors`).
    """
    if local is None:
        local = local_colors(tree, mats, lights, ambient, background, texel)
    factors = node_factors(tree, mats)
    n_samples = tree.fog.shape[0]
    total = jnp.zeros((n_samples, 3), factors.dtype)
    weight = None
    for level, (a, b) in enumerate(tree.levels):
        f = factors[a:b]
        weight = f if level == 0 else weight[tree.parent_local[a:b]] * f
        radiance = weight * local[a:b]
        if level == 0:  # exactly one root per sample, in sample order
            total = total + radiance
        else:
            total = total + jax.ops.segment_sum(radiance, tree.sample[a:b], n_samples, indices_are_sorted=True)
    if tree.fog_on:
        fog = tree.fog[:, None]
        total = fog * total + (1.0 - fog) * tree.fog_color
    return sum_axis(total.reshape(-1, tree.samples_per_pixel, 3), 1) / tree.samples_per_pixel


class TreeModel(eqx.Module):
    """The ray-tree image model of U pixels: their part of the recorded tree (with the nodes' taps
    into fitted texels) and the view's background. `pixels` is the (U, 3) image for given
    materials, lights and ambient."""

    tree: TreeJ
    background: jnp.ndarray

    @classmethod
    def build(cls, tree, pixels, background, dtype, texels=None) -> TreeModel:
        """`texels`: a `texels.TexelSource` for the fitted textures, or None."""
        return cls(tree=tree_to_jax(tree, pixels, dtype, texels), background=jnp.asarray(background, dtype))

    def point_texels(self, texels):
        """(N, 3) each node's texture value from the stacked `texels` (`node_texels`)."""
        return node_texels(self.tree, texels)

    def texel_reads(self) -> tuple[np.ndarray, np.ndarray]:
        """(pixel, texel) int64 pairs (M,): the stacked fitted texels each of the U pixels reads --
        the taps of every node of its samples' trees."""
        pixel = np.asarray(self.tree.sample, np.int64) // self.tree.samples_per_pixel
        return pixel_texels(pixel, np.arange(pixel.size), self.tree.taps)

    def pixels(self, table: MaterialTable, lights: LightsJ, ambient, texel=None):
        """`texel` (N, 3): the nodes' texture values (default: `point_texels(table.texels)`)."""
        return tree_image(self.tree, table, lights, ambient, self.background, texel=texel)


@jax.jit
def _evaluate_jit(tree, mats, lights, ambient, background):
    return tree_image(tree, mats, lights, ambient, background)


def evaluate_tree(tree, materials, lights, ambient, background, *, dtype=jnp.float32):
    """The ray-traced image (H, W, 3) re-formed in JAX from its recorded tree (all pixels).

    Arguments:
        tree: a `RayTree` (`render_frame(scene, method="raytrace").ray_tree`) or a `TreeJ` of every pixel.
        materials: a `MaterialTable`, scene `Material`s in material-id order (`scene.materials.values()`),
            or a name -> `Material` mapping (`scene.materials`).
        lights: `LightsJ` or scene `Light`s (only intensity, attenuation and spot settings are read:
            directions, distances and visibility are the tree's).
        ambient, background: (3,) RGB.
        dtype: float dtype for the arrays built here (jnp.float64 needs x64 enabled).
    Returns:
        a JAX array (H, W, 3), equal to `Frame.image` (to float32 rounding) for the recorded values.
    """
    shape = tree.image_shape if not isinstance(tree, TreeJ) else None
    tree_j = tree if isinstance(tree, TreeJ) else tree_to_jax(tree, dtype=dtype)
    if isinstance(materials, dict):  # name -> Material
        materials = [materials[name] for name in tree.material_names]
    mats = materials if isinstance(materials, MaterialTable) else MaterialTable.from_scene(materials, dtype)
    lights = lights if isinstance(lights, LightsJ) else lights_to_jax(tuple(lights), dtype)
    image = _evaluate_jit(tree_j, mats, lights, jnp.asarray(ambient, dtype), jnp.asarray(background, dtype))
    return image.reshape(*shape, 3) if shape is not None else image

