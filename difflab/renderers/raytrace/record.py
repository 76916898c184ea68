"""Recording the ray tree: the flat device arrays the walk writes, and their numpy `RayTree`.

The recording pass runs the same walk as the image pass, with every sample's nodes written at the
sample's offset (`TreeW.offset`, from the node counts of the image pass, so the arrays are sized
exactly). See `tree.RayTree` for the meaning of every field. The texture fields (uv, texel) take
memory only in scenes with an image texture (`has_textures`); elsewhere they are one element, never
written.
"""

from __future__ import annotations

import numpy as np

from ..._warp import wp

from ...guards import check_tree
from ...lighting.warp_model import fog_params
from ..intersect import HIT_TRIANGLE, HitW
from .nesting import medium_of
from .surface import RayW, SplitW, SurfaceW
from .tree import RayTree

wp.set_module_options({"enable_backward": False})


@wp.struct
class TreeW:
    """Flat per-node outputs of the recording pass (N nodes, P lights); see tree.RayTree."""

    offset: wp.array2d(dtype=wp.int32)  # per sample: index of its first node
    sample: wp.array(dtype=wp.int32)
    parent: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)
    depth: wp.array(dtype=wp.int32)
    material: wp.array(dtype=wp.int32)
    object: wp.array(dtype=wp.int32)
    face: wp.array(dtype=wp.int32)
    cell: wp.array(dtype=wp.int32)
    medium: wp.array(dtype=wp.int32)
    distance: wp.array(dtype=float)
    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    view: wp.array(dtype=wp.vec3)
    local: wp.array(dtype=wp.vec3)
    texel: wp.array(dtype=wp.vec3)  # the texture value the node's material took (textured materials)
    uv: wp.array(dtype=wp.vec2)  # where it read its texture (textured materials)
    fresnel: wp.array(dtype=float)
    fresnel_r: wp.array(dtype=float)
    fresnel_t: wp.array(dtype=float)
    tir_share: wp.array(dtype=float)
    light_dir: wp.array2d(dtype=wp.vec3)
    light_dist: wp.array2d(dtype=float)
    visibility: wp.array2d(dtype=float)
    crossings: wp.array3d(dtype=wp.int32)  # (node, light, material): transparent crossings of the shadow ray


@wp.struct
class LightRecW:
    """`TreeW`'s per-light arrays on their own: what `kernels.shade_hit` writes, cheap to pass."""

    light_dir: wp.array2d(dtype=wp.vec3)
    light_dist: wp.array2d(dtype=float)
    visibility: wp.array2d(dtype=float)
    crossings: wp.array3d(dtype=wp.int32)


@wp.func
def light_arrays(tree: TreeW):
    rec = LightRecW()
    rec.light_dir = tree.light_dir
    rec.light_dist = tree.light_dist
    rec.visibility = tree.visibility
    rec.crossings = tree.crossings
    return rec


@wp.func
def record_ray(tree: TreeW, base: int, node: int, sample: int, ray: RayW, hit: HitW, distance: float):
    """Node `base + node`: the ray itself and what it hit (material -1: nothing)."""
    k = base + node
    tree.sample[k] = sample
    tree.parent[k] = -1
    if ray.parent >= 0:
        tree.parent[k] = base + ray.parent
    tree.kind[k] = ray.kind
    tree.depth[k] = ray.depth
    tree.medium[k] = medium_of(ray.media)
    tree.distance[k] = distance
    tree.material[k] = hit.material
    tree.object[k] = hit.object
    tree.face[k] = -1
    if hit.kind == HIT_TRIANGLE:
        tree.face[k] = hit.index


@wp.func
def record_light(rec: LightRecW, k: int, q: int, l: wp.vec3, distance: float, visibility: float):
    """Light q as node k saw it."""
    rec.light_dir[k, q] = l
    rec.light_dist[k, q] = distance
    rec.visibility[k, q] = visibility


@wp.func
def record_surface(tree: TreeW, k: int, surf: SurfaceW, local: wp.vec3, split: SplitW):
    """The surface at node k, its local colour and its Fresnel split."""
    tree.cell[k] = surf.cell
    tree.position[k] = surf.p
    tree.normal[k] = surf.normal
    tree.view[k] = surf.view
    tree.local[k] = local
    if surf.mat.texture >= 0:  # (the texture arrays hold every node only in scenes with textures)
        tree.texel[k] = surf.texel
        tree.uv[k] = surf.uv
    tree.fresnel[k] = split.fresnel
    tree.fresnel_r[k] = split.f_r
    tree.fresnel_t[k] = split.f_t
    tree.tir_share[k] = split.tir_share


def has_textures(scene) -> bool:
    """Whether some material of `scene` has an image texture (the tree then records uv and texels)."""
    return any(mat.texture is not None for mat in scene.materials.values())


def empty_tree(shape: tuple[int, int], n_nodes: int, n_lights: int, device: str, n_materials: int = 0,
               textured: bool = False) -> TreeW:
    """Device arrays for n_nodes nodes (at least one element each, so that Warp accepts them);
    `crossings` has a material axis of n_materials (1 when not recorded); texel and uv hold every
    node only when `textured`."""
    n, p = max(n_nodes, 1), max(n_lights, 1)
    tree = TreeW()
    tree.offset = wp.zeros(shape, dtype=wp.int32, device=device)
    for name in ("sample", "parent", "kind", "depth", "material", "object", "face", "cell", "medium"):
        setattr(tree, name, wp.zeros(n, dtype=wp.int32, device=device))
    for name in ("distance", "fresnel", "fresnel_r", "fresnel_t", "tir_share"):
        setattr(tree, name, wp.zeros(n, dtype=float, device=device))
    for name in ("position", "normal", "view", "local"):
        setattr(tree, name, wp.zeros(n, dtype=wp.vec3, device=device))
    tree.texel = wp.zeros(n if textured else 1, dtype=wp.vec3, device=device)
    tree.uv = wp.zeros(n if textured else 1, dtype=wp.vec2, device=device)
    tree.light_dir = wp.zeros((n, p), dtype=wp.vec3, device=device)
    tree.light_dist = wp.zeros((n, p), dtype=float, device=device)
    tree.visibility = wp.zeros((n, p), dtype=float, device=device)
    tree.crossings = wp.zeros((n, p, n_materials) if n_materials else (1, 1, 1), dtype=wp.int32, device=device)
    return tree


def sized_tree(counts: np.ndarray, n_lights: int, n_materials: int, device: str,
               textured: bool = False) -> tuple[TreeW, np.ndarray]:
    """A `TreeW` sized for per-sample node `counts` (rows, cols), and the (S + 1,) int64 offsets
    (`textured`: as `empty_tree`)."""
    offsets = np.zeros(counts.size + 1, np.int64)
    np.cumsum(counts.ravel(), out=offsets[1:])
    n_nodes = int(offsets[-1])
    check_tree(n_nodes, n_lights, n_lights * n_materials, textured)
    tree = empty_tree(counts.shape, n_nodes, n_lights, device, n_materials, textured)
    tree.offset = wp.array(offsets[:-1].reshape(counts.shape).astype(np.int32), dtype=wp.int32, device=device)
    return tree, offsets


def tree_to_numpy(wp_tree: TreeW, offsets: np.ndarray, n_lights: int, fog, scene, settings, grid,
                  crossings: bool) -> RayTree:
    """The recorded `TreeW` as a numpy `RayTree` (`fog`: the per-sample fog blend, on `grid`)."""
    n_nodes = int(offsets[-1])

    def get(name):
        return getattr(wp_tree, name).numpy()[:n_nodes]

    if crossings:
        crossed = get("crossings")[:, :n_lights].astype(np.uint8)  # at most MAX_SHADOW_CROSSINGS each
    else:
        crossed = np.zeros((n_nodes, n_lights, len(scene.materials)), np.uint8)
    if has_textures(scene):
        texture = {"texel": get("texel"), "uv": get("uv")}
    else:
        texture = {"texel": np.zeros((0, 3), np.float32), "uv": np.zeros((0, 2), np.float32)}
    side = grid[0] // scene.camera.height
    return RayTree(
        image_shape=(scene.camera.height, scene.camera.width), grid_shape=tuple(grid), spp_side=side,
        material_names=tuple(scene.material_names), specular=settings.specular, fresnel_mode=settings.fresnel,
        max_depth=int(settings.max_depth), sample_offset=offsets, sample_fog=fog.ravel().astype(np.float32),
        fog_color=np.asarray(fog_params(scene.fog)[1], np.float32),
        **{name: get(name) for name in ("sample", "parent", "kind", "depth", "material", "object", "face", "cell",
                                        "medium", "distance", "position", "normal", "view", "fresnel", "fresnel_r",
                                        "fresnel_t", "tir_share", "local")}, **texture,
        light_dir=get("light_dir")[:, :n_lights], light_dist=get("light_dist")[:, :n_lights],
        visibility=get("visibility")[:, :n_lights], crossings=crossed,
    )
