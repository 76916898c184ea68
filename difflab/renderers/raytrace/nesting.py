"""Nested media: the transparent objects around a ray, and the index ratio at the surfaces it meets.

Each ray carries the transparent (kt > 0) objects it is inside, innermost first (`MediaW`, up to
MEDIA_DEPTH of them, on the walk's stack with the ray: Warp has no recursion). It travels in the
innermost one's medium (`medium_of`), absorbing by that material's absorption, and refracts at a
surface by eta = n_outside / n_inside (the ratio `optics.refract` and `optics.fresnel` take), the
indices read from that list (`crossing`), as POV-Ray's interior stack and pbrt's medium
interfaces trace glass in water:

    entering an object (hitting the side its stored normal points to):  eta = n_out / ior
    leaving a transparent object:                                        eta = ior / n_out
    either side of an opaque one (kt = 0, no inside):                    eta = n_out / ior

n_out being the index of the object's outside -- of the innermost object around the ray other than
it (`outside`), 1 (air) for none. The refracted ray's list gains the object entered, innermost
(`entered`), or loses the object left, wherever it is in the list (overlapping objects are left in
any order); a reflected ray keeps its parent's. Two rules keep a list that missed a crossing
consistent, and a scene without nesting traced as with one medium per ray: a ray that enters an
object already in its list moves it innermost, and one that leaves an object not in its list
leaves the innermost one (a slab of two planes facing out is entered through one and left through
the other; an open mesh's back side counts as its inside). A ray entering an object with
MEDIA_DEPTH objects already around it forgets the outermost: after leaving the inner ones it takes
that one's inside for air (index 1, no absorption).

Touching objects: of two coincident surfaces a ray would cross only the first it meets (the next
ray starts an offset past it). Where the scene has two or more transparent objects
(`SceneW.probe_coincident`), a refracting hit looks for one transparent surface of another object
within the offset (`coincident`) and crosses it too, as one interface (`crossing`); the eye's walk
(`medium.media_at`) does the same.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ..intersect import HIT_NONE, HitW, SceneGeomW, analytic_hit, finish_hit, ray_triangle, triangle_hit
from ..trace import SPAWN_GRAZING

wp.set_module_options({"enable_backward": False})

MEDIA_DEPTH = 4  # transparent objects a ray keeps track of around it (module doc)
IdsW = wp.types.vector(length=MEDIA_DEPTH, dtype=wp.int32)


@wp.struct
class MediaW:
    """The transparent objects around a ray, innermost first: their scene object ids and material
    ids (entries from `count` on are -1)."""

    objects: IdsW
    materials: IdsW
    count: int


@wp.func
def no_media():
    """A ray in no medium (air)."""
    media = MediaW()
    media.objects = IdsW(-1)
    media.materials = IdsW(-1)
    media.count = 0
    return media


@wp.func
def medium_of(media: MediaW):
    """The material id of the medium a ray travels in (its innermost object's), -1: none."""
    if media.count > 0:
        return media.materials[0]
    return -1


@wp.func
def medium_ior(materials: wp.array(dtype=MaterialW), media: MediaW):
    """The refractive index of the medium a ray travels in, 1 outside every object."""
    if media.count > 0:
        return materials[media.materials[0]].ior
    return 1.0


@wp.func
def outward(media: MediaW, obj: int, material: int):
    """`media` with object `obj` (of `material`) added outside all of them (as a walk from a point
    meets the objects around it, `medium.media_at`); unchanged when full."""
    if media.count == MEDIA_DEPTH:
        return media
    objects = media.objects
    materials = media.materials
    objects[media.count] = obj
    materials[media.count] = material
    out = MediaW()
    out.objects = objects
    out.materials = materials
    out.count = media.count + 1
    return out


@wp.func
def entered(media: MediaW, obj: int, material: int):
    """`media` (not holding `obj`) with object `obj` (of `material`) added innermost; the outermost
    forgotten when full (module doc)."""
    objects = IdsW(-1)
    materials = IdsW(-1)
    objects[0] = obj
    materials[0] = material
    for k in range(MEDIA_DEPTH - 1):
        objects[k + 1] = media.objects[k]
        materials[k + 1] = media.materials[k]
    out = MediaW()
    out.objects = objects
    out.materials = materials
    out.count = wp.min(media.count + 1, MEDIA_DEPTH)
    return out


@wp.func
def outside(media: MediaW, obj: int, leaving: int):
    """What lies outside object `obj` at a surface a ray inside `media` crosses: `media` without
    `obj`; where it is not among them, `media` as they are, or without the innermost when `leaving`
    (module doc)."""
    drop = int(-1)
    for k in range(MEDIA_DEPTH):
        if drop < 0 and k < media.count and media.objects[k] == obj:
            drop = k
    if drop < 0 and leaving == 1:
        drop = 0
    objects = IdsW(-1)
    materials = IdsW(-1)
    count = int(0)
    for k in range(MEDIA_DEPTH):
        if k < media.count and k != drop:
            objects[count] = media.objects[k]
            materials[count] = media.materials[k]
            count = count + 1
    out = MediaW()
    out.objects = objects
    out.materials = materials
    out.count = count
    return out


@wp.func
def refracted_media(media: MediaW, obj: int, material: int, entering: int):
    """What a ray refracted through a surface of transparent object `obj` travels in."""
    if entering == 1:
        return entered(outside(media, obj, 0), obj, material)
    return outside(media, obj, 1)


@wp.func
def coincident(geom: SceneGeomW, obj: int, p: wp.vec3, d: wp.vec3, step: float):
    """The first surface of an object other than `obj` that the segment from p - step d to
    p + step d crosses, or a miss: spheres and planes as `closest_hit` finds them; triangles among
    those whose bounds meet the segment's (`wp.mesh_query_aabb`: the BVH's nearest hit may be a face
    of `obj` itself, coincident with the one sought)."""
    origin = p - step * d
    found = finish_hit(geom, analytic_hit(geom, origin, d, 0.0, 2.0 * step, obj), origin, d)
    if geom.mesh != wp.uint64(0):
        mesh = wp.mesh_get(geom.mesh)
        query = wp.mesh_query_aabb(geom.mesh, wp.min(origin, p + step * d), wp.max(origin, p + step * d))
        face = int(0)
        while wp.mesh_query_aabb_next(query, face):
            if geom.face_object[face] != obj:
                a = mesh.points[mesh.indices[3 * face]]
                b = mesh.points[mesh.indices[3 * face + 1]]
                c = mesh.points[mesh.indices[3 * face + 2]]
                t, b1, b2 = ray_triangle(origin, d, a, b, c)
                if t > 0.0 and t < found.t and b1 >= 0.0 and b2 >= 0.0 and b1 + b2 <= 1.0:
                    found = triangle_hit(geom, face, t, 1.0 - b1 - b2, b1, wp.cross(b - a, c - a), origin, d)
    return found


@wp.func
def crossing(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), media: MediaW, hit: HitW, entering: int,
             d: wp.vec3, p: wp.vec3, offset: float, probe: int):
    """(eta, beyond) at `hit` (not a miss; at point p, rays leaving it start `offset` off it) of a ray
    along unit `d` inside `media`, `entering` it or not: eta = n_outside / n_inside (module doc) and
    what a ray refracted there travels in. With `probe`, a transparent surface of another object
    within the offset of p on either side (coincident with this one: touching objects) is crossed
    with it, as one interface: beyond is what lies past both, and eta = n_from / n(beyond)."""
    mat = materials[hit.material]
    if mat.kt <= 0.0:
        return medium_ior(materials, outside(media, hit.object, 0)) / mat.ior, media
    beyond = refracted_media(media, hit.object, hit.material, entering)
    n_from = mat.ior
    n_to = mat.ior
    if entering == 1:
        n_from = medium_ior(materials, outside(media, hit.object, 0))
    else:
        n_to = medium_ior(materials, beyond)
    if probe == 1:
        other = coincident(geom, hit.object, p, d, offset / wp.max(wp.abs(wp.dot(d, hit.normal)), SPAWN_GRAZING))
        if other.kind != HIT_NONE and materials[other.material].kt > 0.0:
            beyond = refracted_media(beyond, other.object, other.material, int(wp.dot(d, other.normal) < 0.0))
            n_to = medium_ior(materials, beyond)
    return n_from / n_to, beyond


def media_struct(pairs) -> MediaW:
    """A `MediaW` from Python: `pairs` of (object id, material id), innermost first (`medium.camera_media`)."""
    objects, materials = [-1] * MEDIA_DEPTH, [-1] * MEDIA_DEPTH
    for k, (obj, material) in enumerate(pairs):
        objects[k], materials[k] = int(obj), int(material)
    media = MediaW()
    media.objects = IdsW(*objects)
    media.materials = IdsW(*materials)
    media.count = len(pairs)
    return media
