"""The guards the renderers call at their boundary (Warp-free): price a render before allocating it,
name the object and file of a mesh that cannot be rendered, and refuse to return non-finite pixels.

    check_render(scene, record_tree)      before compiling: memory and ray budgets (`limits`)
    check_threads(threads)                the CPU worker count a caller asks for
    object_errors(index, obj)             around building an object's mesh: errors name the object
    check_world_mesh(mesh, index, obj)    after transforming it: coordinates within +-MAX_COORD
    check_mesh_uvs(mesh, index, obj, material)  a textured material's mesh has uvs
    check_image(image, scene, bad, textures)  before returning: no NaN / inf, with the likely cause named
"""

from __future__ import annotations

import contextlib

import numpy as np

from . import limits
from .errors import MeshError, RenderError, SceneError


def tree_shape(scene) -> tuple[int, float, float]:
    """(branching, weight, spread) of the scene's ray trees (`limits.ray_tree_nodes`), the most over
    all materials: rays one hit can spawn (a reflected ray where kr > 0, a refracted one where
    kt > 0), the largest factor one spawned ray's weight carries, and the largest sum of a hit's
    children's factors. With Fresnel weighting the children take kr F and kt (1 - F): at most
    max(kr, kt) each and together. Without it they take kr and kt, and under total internal
    reflection (possible where kt > 0 and ior != 1) the reflected ray alone takes kr + kt."""
    materials = list(scene.materials.values())
    plain = scene.render.fresnel == "none"
    branching = max([int(m.kr > 0) + int(m.kt > 0) for m in materials], default=0)
    weight = max([m.kr + m.kt if plain and m.kt > 0 and m.ior != 1 else max(m.kr, m.kt) for m in materials],
                 default=0.0)
    spread = max([m.kr + m.kt if plain else max(m.kr, m.kt) for m in materials], default=0.0)
    return branching, weight, spread


def ray_budget_hint(scene, shape: tuple[int, float, float], n_lights: int) -> str:
    """What can bring a refused render's ray count down: max_depth, kr / kt, spp and the image size
    where they would, and -- only where a threshold <= 1 brings the bound within the budget -- the
    smallest adaptive_threshold of 1, 2, 5 x 10^-k that does (none can where a ray keeps its whole
    weight at a bounce, kr + kt >= 1 under total internal reflection without Fresnel)."""
    settings = scene.render
    levers = [name for name, useful in (("max_depth", settings.max_depth > 1), ("kr / kt", shape[0] > 0),
                                        ("spp", settings.spp > 1), ("the image size", True)) if useful]
    hint = "lower " + (", ".join(levers[:-1]) + " or " if len(levers) > 1 else "") + levers[-1]
    samples = scene.camera.width * scene.camera.height * settings.spp
    budget = limits.ray_budget()
    for exponent in range(-6, 1):
        for mantissa in (1, 2, 5):
            threshold = mantissa * 10.0 ** exponent
            if threshold > max(settings.adaptive_threshold, 0.0) and threshold <= 1.0 and samples * (1 + n_lights) * \
                    limits.ray_tree_nodes(settings.max_depth, shape[0], shape[1], threshold, shape[2]) <= budget:
                return f"{hint}, or raise render.adaptive_threshold (Hall's control) to {threshold:g}"
    return hint


def check_render(scene, record_tree: bool = True) -> None:
    """Refuse, before anything is allocated, a render of `scene` (its camera and render settings)
    over the memory budget or (ray tracing) the ray budget; RenderError says what to lower."""
    camera, settings = scene.camera, scene.render
    samples = camera.width * camera.height * settings.spp
    n_lights = len(scene.lights)
    what = f"render: {camera.width} x {camera.height} pixels at spp {settings.spp} ({settings.method})"
    if settings.method == "raster":
        limits.require_memory(limits.raster_frame_bytes(samples, samples, n_lights, 0), what, RenderError,
                              "lower the image size or spp")
        return
    shape = tree_shape(scene)
    nodes = limits.ray_tree_nodes(settings.max_depth, shape[0], shape[1], settings.adaptive_threshold, shape[2])
    limits.check_rays(samples, nodes, n_lights, f"{what} at max_depth {settings.max_depth}", RenderError,
                      ray_budget_hint(scene, shape, n_lights))
    textured = any(mat.texture is not None for mat in scene.materials.values())
    limits.require_memory(limits.raytrace_bytes(samples, samples, n_lights, record_tree, textured), what, RenderError,
                          "lower the image size or spp")


def check_threads(threads):
    """`threads` (CPU workers of a render) as given: None (all cores) or a positive integer."""
    if threads is None or (isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1):
        return threads
    raise RenderError(f"threads: expected a positive integer or None, got {limits.shorten(threads)}")


def check_tree(n_nodes: int, n_lights: int, n_crossing_counts: int, textured: bool = False) -> None:
    """Refuse recording a ray tree of `n_nodes` (counted by the first pass) over the memory budget;
    `n_crossing_counts` = lights x materials per node when transparent shadow crossings are recorded;
    `textured`: the nodes record texels and uv."""
    limits.require_count(n_nodes, "record_tree: ray-tree nodes", RenderError)
    nbytes = limits.raytrace_bytes(0, n_nodes, n_lights, True, textured) + \
        n_nodes * n_crossing_counts * limits.TREE_CROSSING_BYTES
    limits.require_memory(nbytes, f"record_tree: a ray tree of {n_nodes} nodes", RenderError,
                          "lower the image size, spp, max_depth or kr / kt; difflab.render (and `difflab render`) "
                          "forms the image alone, recording no tree")


def _object_label(index: int, obj) -> str:
    file = getattr(obj, "file", None)
    return f"objects[{index}]" + (f" ({limits.short_path(file)})" if file else "")


@contextlib.contextmanager
def object_errors(index: int, obj):
    """Re-raise a MeshError from building object `index`'s mesh with the object (and its file) named."""
    try:
        yield
    except MeshError as exc:
        raise MeshError(f"{_object_label(index, obj)}: {exc}") from None


def check_world_mesh(mesh, index: int, obj) -> None:
    """MeshError naming the object, its file and transform if a world-space vertex is beyond +-MAX_COORD
    (float32 rendering would overflow)."""
    largest = float(np.max(np.abs(mesh.vertices), initial=0.0))
    if not largest <= limits.MAX_COORD:
        raise MeshError(f"{_object_label(index, obj)}.transform: vertices reach {largest:.3g} after the transform, "
                        f"beyond +-{limits.MAX_COORD:g} (float32 rendering overflows)")


def check_mesh_uvs(mesh, index: int, obj, material) -> None:
    """SceneError naming the object, its file and its material if the material has an image texture
    and the mesh no uvs. (OpenGL would sample every point at the default texture coordinate (0, 0),
    Mitsuba at the triangle's barycentrics: a texture that means nothing, so it is refused.)"""
    if material.texture is not None and mesh.uvs is None:
        raise SceneError(f"{_object_label(index, obj)}: material {obj.material!r} has a texture "
                         f"({limits.short_path(material.texture)}) but the mesh has no uvs (texture coordinates: "
                         "OBJ vt lines, `uvs` with `vertices`, or a builtin other than the teapot)")


def _numbers(value, path: str):
    """(path, number) for every number in a scene's JSON form."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _numbers(item, f"{path}.{key}" if path else str(key))
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{path}[{i}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, float(value)


def likely_causes(scene, count: int = 3, textures=None) -> str:
    """The `count` numbers of largest magnitude in the scene's materials, lights, ambient, background
    and fog, and the largest texel of each material's texture (`textures`: a `TextureStore`, its
    `paths` and `largest()`), as 'path = value' (where float32 shading overflows first), or the
    smallest non-zero attenuation (a light that divides by nearly zero)."""
    d = scene.to_dict()
    values = [(p, x) for key in ("materials", "lights", "ambient", "background", "fog")
              for p, x in _numbers(d.get(key), key)]
    if textures is not None:
        peak = dict(zip(textures.paths, textures.largest()))
        values += [(f"materials.{name}.texture ({limits.short_path(mat.texture)}) largest texel", peak[mat.texture])
                   for name, mat in scene.materials.items() if mat.texture in peak]
    ranked = sorted(values, key=lambda px: -abs(px[1]))[:count]
    shown = ", ".join(f"{p} = {x:.3g}" for p, x in ranked)
    tiny = [(p, x) for p, x in values if ".attenuation[" in p and 0 < x < 1e-20]
    return shown + ("".join(f", {p} = {x:.3g}" for p, x in tiny[:1]))


def nonfinite_pixels(pixels: np.ndarray) -> int:
    """Pixels with a non-finite channel. The least and the greatest value tell whether any is (a NaN
    is both, an infinity one: ~20 us for 256^2 RGB against ~160 us for a float64 sum); only then
    are they counted."""
    if not pixels.size or (np.isfinite(pixels.min()) and np.isfinite(pixels.max())):
        return 0
    return int(np.count_nonzero(~np.isfinite(pixels).all(axis=-1)))


def check_image(image: np.ndarray | None, scene, bad: int | None = None, textures=None) -> None:
    """RenderError if `image` has NaN or infinite values, with their count and the likely cause
    (`likely_causes`, texels of `textures` among them); `bad`: that count when the renderer has it
    already (else the image is scanned; None: a frame without image, `bad` given)."""
    bad = nonfinite_pixels(image) if bad is None else bad
    if bad:
        total = scene.camera.width * scene.camera.height if image is None else image.shape[0] * image.shape[1]
        raise RenderError(f"render: {bad} of {total} pixels are not finite (float32 "
                          f"overflow); the largest numbers in the scene: {likely_causes(scene, textures=textures)}")
