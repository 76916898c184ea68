"""The analytic spheres' and planes' raster triangles are built when something first rasterizes a
compiled scene (`CompiledScene.raster`), once per tessellation (Phong shading's, flat and Gouraud's),
and never for ray tracing."""

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from conftest import scene_dict
from difflab import compile_scene, render, render_frame
from difflab.errors import RenderError
from difflab._warp import wp
from difflab.renderers import compile as compile_module
from difflab.renderers.compile import RASTER_ROOM, RASTER_SOUP, scene_parts
from difflab.renderers.soup import SOUP_DTYPES, triangle_soup
from difflab.geometry import uv_sphere
from difflab.renderers.camera import camera_frame, pixel_size_at
from difflab.renderers import tessellate as tessellate_module
from difflab.renderers.tessellate import (MAX_SPHERE_SEGMENTS, MIN_SPHERE_SEGMENTS, PHONG_SPHERE_SEGMENTS, SAGITTA,
                                          AnalyticParts, plane_grid, sphere_segments)
from difflab.scene import Scene, Sphere

CAMERA = {"eye": [0.0, 2.0, 5.0], "target": [0, 0, -2], "fov_y": 45, "width": 32, "height": 24}
SPHERES = [{"type": "sphere", "center": [x, 0.35, -z], "radius": 0.3, "material": m}
           for x, m in zip((-1.2, -0.4, 0.4, 1.2), ("glass", "mirror", "glass", "mirror")) for z in (0.0, 1.5, 3.0)]
BOX = {"type": "mesh", "builtin": "box", "material": "red", "transform": {"translate": [0, 0.4, 1.2], "scale": 0.5}}
FLOOR = {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}
MATERIALS = {"glass": {"kd": [0.05, 0.05, 0.05], "ks": [0.5, 0.5, 0.5], "n": 60, "kr": 0.1, "kt": 0.8, "ior": 1.5},
             "mirror": {"kd": [0.1, 0.1, 0.1], "ks": [0.6, 0.6, 0.6], "n": 40, "kr": 0.8},
             "red": {"ka": [0.2, 0, 0], "kd": [0.7, 0.1, 0.1]},
             "floor": {"kd": [0.6, 0.6, 0.6], "checker": {"size": 0.5, "kd2": [0.1, 0.1, 0.1]}}}
#: A Whitted scene: a grid of glass and mirror spheres over a checkered floor, and a box (a mesh).
WHITTED = scene_dict(SPHERES + [BOX, FLOOR], MATERIALS, camera=CAMERA, ambient=(0.1, 0.1, 0.1),
                     lights=[{"type": "point", "position": [2, 4, 3]}], render={"max_depth": 3})


@pytest.fixture
def tessellations(monkeypatch):
    """The analytic tessellations built, by `phong` (each call slowed a little, so threads overlap in it)."""
    calls = []
    tessellate = AnalyticParts.tessellate

    def counted(self, n_before, phong):
        calls.append(phong)
        time.sleep(0.05)
        return tessellate(self, n_before, phong)

    monkeypatch.setattr(AnalyticParts, "tessellate", counted)
    return calls


def test_ray_tracing_builds_no_tessellation_and_its_image_does_not_depend_on_it(tessellations):
    compiled = compile_scene(WHITTED)
    mesh_faces = compiled.n_mesh_faces
    assert mesh_faces > 0 and compiled.faces.shape[0] == mesh_faces  # the box's triangles alone
    assert compiled.vertices.shape[0] == compiled.n_mesh_vertices and compiled.arrays["faces"].shape[0] == mesh_faces
    traced = render_frame(compiled, method="raytrace")  # BVH, item buffer, ray tree
    lit = render(compiled, method="raytrace", light_buffer=True, item_buffer=False)
    assert traced.stats["item_buffer"] and traced.stats["total_rays"] > 32 * 24 * 2
    assert tessellations == [] and not any(RASTER_SOUP in key for key in compiled.built if isinstance(key, tuple))
    # a scene rasterized first (its BVH built beside the whole soup, for shadow rays) traces the same image
    first = compile_scene(WHITTED)
    render(first, method="raster")
    assert tessellations == [True] and first.raster().faces.shape[0] == 4608 > 5 * mesh_faces
    assert np.array_equal(render(first, method="raytrace"), traced.image)
    assert np.array_equal(render(first, method="raytrace", light_buffer=True, item_buffer=False), lit)
    assert np.array_equal(lit, traced.image)


def eager_soup(scene, phong: bool = False) -> dict:
    """The one soup of all the scene's triangles as `compile_scene` built it before the tessellation
    was made lazy (commit 82029e4^): `triangle_soup` of the mesh objects', then each sphere's uv
    sphere (`sphere_segments` longitudes for the sample rows; Phong's or the smooth shadings') and
    each plane's grid, in scene order -- built here from the primitives, not by
    `AnalyticParts.tessellate`."""
    mesh_parts, analytic = scene_parts(scene)
    rows = scene.camera.height * scene.render.spp_side
    parts = []
    for obj, material, index in analytic:
        if isinstance(obj, Sphere):
            n_lon = int(sphere_segments([obj.center], [obj.radius], scene.camera, rows, phong)[0])
            parts.append((uv_sphere(obj.radius, obj.center, max(2, n_lon // 2), n_lon), material, index))
        else:
            parts.append((plane_grid(obj, scene.camera), material, index))
    return triangle_soup(mesh_parts + parts)


def test_a_raster_copy_is_kept_for_its_scene_and_with_scene_of_the_own_scene_is_itself(tessellations):
    """`raster()` keeps its copy for the last scene asked for (a fit's frames ask again and again),
    one per tessellation, its shading's (by default the scene's: Phong here); a copy under another
    scene is that scene's, with the same soup; `with_scene` of a compiled scene's own scene is the
    compiled scene."""
    compiled = compile_scene(WHITTED)
    assert compiled.with_scene(compiled.scene) is compiled
    soup = compiled.raster()
    assert compiled.raster() is soup and soup.raster() is soup and soup.scene is compiled.scene
    assert compiled.raster("phong") is soup and tessellations == [True]
    other = compiled.with_scene(compiled.scene.with_overrides(render={"shadows": False}))
    assert other is not compiled and other.raster().scene is other.scene and other.raster().arrays is soup.arrays
    flat = compiled.with_scene(compiled.scene.with_overrides(render={"shading": "flat"}))
    smooth = flat.raster()
    assert smooth.scene is flat.scene
    assert smooth.arrays is compiled.raster("gouraud").arrays is soup.raster("flat").arrays
    assert smooth.faces.shape[0] > soup.faces.shape[0] and tessellations == [True, False]


def test_the_raster_soup_is_the_eager_one_built_once(tessellations):
    """The lazily built raster soups (Phong's, flat and Gouraud's) are bitwise the one soup of all
    the scene's triangles that compiling built before (`eager_soup`), and the raster image of a
    scene ray traced first is a freshly compiled scene's."""
    compiled = compile_scene(WHITTED)
    render(compiled, method="raytrace")
    image = render(compiled, method="raster", shading="phong")
    frame = render_frame(compiled, method="raster", shading="gouraud")  # the G-buffer, from the smooth soup
    assert tessellations == [True, False]
    _, analytic = scene_parts(compiled.scene)
    for shading, phong in (("phong", True), ("gouraud", False)):
        soup = compiled.raster(shading)
        assert soup.arrays is compiled.raster(shading).arrays  # kept, for copies too
        eager = eager_soup(compiled.scene, phong)
        for name in SOUP_DTYPES:
            assert getattr(soup, name).dtype == eager[name].dtype, name
            assert np.array_equal(getattr(soup, name), eager[name]), name
            assert soup.arrays[name].shape[0] == eager[name].shape[0], name
        np.testing.assert_array_equal(soup.faces[:soup.n_mesh_faces], compiled.faces)
    assert len(tessellations) == 2
    assert [index for _, _, index in analytic] == list(range(len(SPHERES))) + [len(SPHERES) + 1]
    assert frame.stats["triangles"] == eager["faces"].shape[0] == 195_456
    fresh = compile_scene(WHITTED)
    assert np.array_equal(render(fresh, method="raster", shading="phong"), image)
    assert np.array_equal(render(WHITTED, method="raster", shading="phong"), image)
    assert np.array_equal(render_frame(fresh, method="raster", shading="gouraud").gbuffer.face, frame.gbuffer.face)
    assert frame.gbuffer.mask.sum() > 0.5 * 32 * 24 and (frame.gbuffer.face[frame.gbuffer.mask] >= 0).all()


def test_threads_rasterizing_one_compiled_scene_build_it_once(tessellations):
    """Three threads start rasterizing a fresh compiled scene together: one builds the tessellation
    (the others wait), then the BVH of their shadow rays, once too (two built at once freed the
    first under the thread using it: a segmentation fault)."""
    reference = render(compile_scene(WHITTED), method="raster", threads=1)
    tessellations.clear()
    compiled = compile_scene(WHITTED)
    start = threading.Barrier(3)

    def draw(gbuffer):
        start.wait()
        if gbuffer:
            return render_frame(compiled, method="raster", threads=1).image
        return render(compiled, method="raster", threads=1)

    with ThreadPoolExecutor(max_workers=3) as pool:
        images = list(pool.map(draw, [False, True, False]))
    assert tessellations == [True]
    for image in images:
        assert np.array_equal(image, reference)


def test_a_scene_without_analytic_objects_rasterizes_its_own_triangles(tessellations):
    compiled = compile_scene(scene_dict([BOX], MATERIALS, camera=CAMERA, lights=[{"type": "directional",
                                                                                  "direction": [0, -1, -1]}]))
    assert compiled.raster() is compiled
    frame = render_frame(compiled)
    assert frame.stats["triangles"] == compiled.faces.shape[0] == compiled.n_mesh_faces
    assert frame.gbuffer.mask.sum() == (frame.gbuffer.object == 0).sum() > 10
    assert tessellations == [] and not any(RASTER_SOUP in key for key in compiled.built if isinstance(key, tuple))


def distinct_bytes(*soups) -> int:
    """Bytes of the distinct memory blocks behind the soups' triangle arrays (a view counts its base)."""
    blocks = {}
    for soup in soups:
        for name in SOUP_DTYPES:
            array = getattr(soup, name)
            base = array if array.base is None else array.base
            blocks[id(base)] = base.nbytes
    return sum(blocks.values())


#: A mesh of 6,240 triangles beside a plane (1,152 raster triangles) and a small sphere (16,128; under Phong
#: shading 224), shadows on.
BIG_MESH = scene_dict([{"type": "mesh", "builtin": "sphere", "resolution": 40, "material": "red"}, FLOOR,
                       {"type": "sphere", "center": [1.6, 0.3, 0], "radius": 0.3, "material": "mirror"}],
                      MATERIALS, camera=CAMERA, lights=[{"type": "point", "position": [2, 4, 3]}],
                      render={"shadows": True})


def test_the_mesh_triangles_are_held_once(tessellations):
    """The compiled scene's mesh fields are the first rows of the raster soup (compiling leaves room
    after them for the larger tessellation, flat and Gouraud's here; rasterizing writes it there):
    after a raster render (shadows: the BVH built too) the two share memory, the device arrays and
    the BVH's points are the same memory, and what is held is the raster soup's bytes alone: 1.188
    MiB here. Before, the raster soup was a concatenated copy: 1.505 MiB held
    (/tmp/rev/soup_twice.py: 63.5 MiB for a 31.8 MiB soup). The same scene drawn under Phong shading
    too copies the mesh rows into its own soup's arrays."""
    compiled = compile_scene(BIG_MESH)
    image = render(compiled, method="raster", shading="gouraud")
    soup = compiled.raster("gouraud")
    assert tessellations == [False] and soup.faces.shape[0] > compiled.n_mesh_faces == 6240
    for name in SOUP_DTYPES:
        mesh, raster = getattr(compiled, name), getattr(soup, name)
        rows = mesh.shape[0]
        assert np.shares_memory(mesh, raster) and np.array_equal(raster[:rows], mesh), name
        assert compiled.arrays[name].ptr == soup.arrays[name].ptr == raster.ctypes.data, name
    assert compiled.built["bvh"].points.ptr == soup.arrays["vertices"].ptr
    assert distinct_bytes(compiled, soup) == sum(getattr(soup, name).nbytes for name in SOUP_DTYPES)
    eager = eager_soup(compiled.scene)
    assert all(np.array_equal(getattr(soup, name), eager[name]) for name in SOUP_DTYPES)
    assert np.array_equal(render(compile_scene(BIG_MESH), method="raster", shading="gouraud"), image)
    tessellations.clear()
    phong = render(compiled, method="raster", shading="phong")
    soup = compiled.raster("phong")
    assert tessellations == [True] and soup.faces.shape[0] == 7616 and not np.shares_memory(soup.vertices,
                                                                                                  compiled.vertices)
    assert all(np.array_equal(getattr(soup, name), eager_soup(compiled.scene, True)[name]) for name in SOUP_DTYPES)
    assert np.array_equal(render(compile_scene(BIG_MESH), method="raster", shading="phong"), phong)


def test_a_scene_compiled_over_the_budget_copies_its_meshes_when_rasterized_under_it(monkeypatch, tessellations):
    """Compiled when its tessellation passes the memory budget, a scene leaves no room after its
    meshes (ray tracing it needs none); rasterized once the budget allows, its mesh rows are copied
    into new arrays with room: the same soup and image as a scene compiled under the budget. Phong's
    tessellation (4,608 triangles) is within it: rasterized the same way at once."""
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "20M")  # the box and one sphere pass, all 195,456 raster triangles not
    compiled = compile_scene(WHITTED)
    assert all(getattr(compiled, name).base is None or getattr(compiled, name).base.shape[0] ==
               getattr(compiled, name).shape[0] for name in SOUP_DTYPES)  # no room
    with pytest.raises(RenderError, match=r"raster triangles of the scene"):
        render(compiled, method="raster", shading="gouraud")
    phong = render(compiled, method="raster", shading="phong")
    monkeypatch.delenv("DIFFLAB_MEMORY_BUDGET")
    image = render(compiled, method="raster", shading="gouraud")
    for shading, phong_soup in (("gouraud", False), ("phong", True)):
        soup = compiled.raster(shading)
        eager = eager_soup(compiled.scene, phong_soup)
        assert all(np.array_equal(getattr(soup, name), eager[name]) for name in SOUP_DTYPES)
        assert not np.shares_memory(compiled.vertices, soup.vertices)  # the copy
    assert np.array_equal(render(compile_scene(WHITTED), method="raster", shading="gouraud"), image)
    assert np.array_equal(render(compile_scene(WHITTED), method="raster", shading="phong"), phong)


def test_a_device_apart_from_the_host_gets_the_mesh_rows_when_compiled_and_the_soup_when_rasterized(monkeypatch):
    """Where the device arrays are not the host's memory (a GPU's; here CPU copies stand in for
    them) compiling uploads the mesh rows alone -- not the room left for the tessellation, which a
    ray-traced scene never builds (box + 400 spheres at spp 4: a 324.8 MiB room uploaded before) --
    while the host keeps its room; the first rasterizing uploads the whole soup, the room's first
    rows: the device arrays equal the raster soup's, and the image is the one of device arrays that
    alias it."""
    image = render(compile_scene(BIG_MESH), method="raster", shading="phong")
    uploads = []

    def copied(soup, device):
        uploads.append({name: soup[name].shape[0] for name in SOUP_DTYPES})
        return {name: wp.array(np.ascontiguousarray(soup[name]), dtype=dtype, device=device, copy=True)
                for name, dtype in SOUP_DTYPES.items()}

    monkeypatch.setattr(compile_module, "host_aliased", lambda device: False)
    monkeypatch.setattr(compile_module, "device_soup", copied)
    compiled = compile_scene(BIG_MESH)
    mesh_rows = {name: getattr(compiled, name).shape[0] for name in SOUP_DTYPES}
    assert uploads == [mesh_rows] and mesh_rows["faces"] == compiled.n_mesh_faces == 6240
    room = compiled.built[RASTER_ROOM][0]
    assert room["faces"].shape[0] == 23_520 and compiled.built[RASTER_ROOM][1] is None  # Gouraud's, the larger
    assert compiled.arrays["vertices"].ptr != compiled.vertices.ctypes.data
    assert np.array_equal(render(compiled, method="raster", shading="phong"), image)
    soup = compiled.raster()
    assert uploads == [mesh_rows, {name: getattr(soup, name).shape[0] for name in SOUP_DTYPES}]
    assert soup.faces.shape[0] == 7616 and np.shares_memory(soup.faces, room["faces"])
    assert RASTER_ROOM not in compiled.built  # taken
    for name in SOUP_DTYPES:
        assert np.array_equal(soup.arrays[name].numpy().reshape(getattr(soup, name).shape), getattr(soup, name)), name
        assert np.array_equal(compiled.arrays[name].numpy().reshape(getattr(compiled, name).shape),
                              getattr(compiled, name)), name


@pytest.mark.parametrize("light_buffer", [False, True], ids=["bvh-shadows", "light-buffer"])
def test_ray_tracing_a_raster_copy_traces_the_meshes_alone(light_buffer):
    """`compiled.raster(shading)` (public) holds the tessellated spheres and plane after the meshes'
    triangles; the ray tracer traces its `meshes()`: the image equals the compiled scene's, bit for
    bit (before, with the light buffer 37 pixels differed by up to 0.087, and the item buffer drew
    195,456 faces instead of 768)."""
    compiled = compile_scene(WHITTED)
    copy = compiled.raster("gouraud")
    assert copy.faces.shape[0] == 195_456 and copy.meshes().faces.shape[0] == compiled.n_mesh_faces == 768
    for name in SOUP_DTYPES:
        assert copy.meshes().arrays[name].ptr == compiled.arrays[name].ptr, name
        assert np.array_equal(getattr(copy.meshes(), name), getattr(compiled, name)), name
    traced = render(copy, method="raytrace", light_buffer=light_buffer)  # the copy first: it builds the caches
    assert np.array_equal(traced, render(compile_scene(WHITTED), method="raytrace", light_buffer=light_buffer))
    assert np.array_equal(render(compiled, method="raytrace", light_buffer=light_buffer), traced)



def scalar_segments(center, radius, camera, height, sagitta=0.5, least=MIN_SPHERE_SEGMENTS) -> int:
    """`sphere_segments` of one sphere as it was written per sphere (commit d18105d), with the step's
    underflow guarded: the reference the vectorised count must equal (`sagitta` and the floor
    `least` Phong's for its tessellation)."""
    _, _, forward = camera_frame(camera)
    distance = float(np.dot(np.asarray(center) - np.asarray(camera.eye), forward)) - radius
    if camera.projection == "perspective" and distance <= camera.near:
        return MAX_SPHERE_SEGMENTS
    radius_px = radius / pixel_size_at(camera, max(distance, camera.near), height)
    if radius_px <= 0.5:
        return least
    step = 2.0 * math.acos(1.0 - sagitta / radius_px)
    if step == 0.0:
        return MAX_SPHERE_SEGMENTS
    return int(min(MAX_SPHERE_SEGMENTS, max(least, math.ceil(2.0 * math.pi / step))))


@pytest.mark.parametrize("phong", [False, True], ids=["smooth", "phong"])
@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_the_segment_counts_of_all_spheres_at_once_are_each_spheres(projection, phong):
    """400 random spheres -- in view, crossing the near plane, behind the camera, tiny (under half a
    sample), huge (the step 2 acos(1 - s / r_px) underflows to 0 past r_px ~ 4.5e15) -- get the
    counts the per-sphere formula gives, and every clamp is reached, for both tessellations (flat
    and Gouraud's the formula of d18105d unchanged)."""
    camera = Scene.from_dict(scene_dict([], MATERIALS, camera={**CAMERA, "projection": projection,
                                                               "ortho_height": 4.0, "near": 0.5})).camera
    rng = np.random.default_rng(7)
    eye = np.asarray(camera.eye)
    centers = np.concatenate([rng.uniform(-6, 6, (100, 3)) + [0, 0, -4],  # mostly in view
                              eye + rng.normal(0, 0.4, (100, 3)),  # at the eye: crossing the near plane
                              eye + [0, 0, 5] + rng.normal(0, 1, (100, 3)),  # behind the camera
                              rng.uniform(-1e12, 1e12, (100, 3))])
    radii = np.concatenate([10.0 ** rng.uniform(-4, 1, 100), rng.uniform(0.1, 1, 100),
                            10.0 ** rng.uniform(-3, 2, 100), 10.0 ** rng.uniform(-6, 17, 100)])
    huge = 10.0 ** rng.uniform(12, 15, 20)  # their near side 1 ahead of the eye: r_px to 6e18 (step 0 past 4.5e15)
    centers = np.concatenate([centers, eye + (huge + 1.0)[:, None] * camera_frame(camera)[2]])
    radii = np.concatenate([radii, huge])
    counts = sphere_segments(centers, radii, camera, 4800, phong)
    rule = (SAGITTA[True], PHONG_SPHERE_SEGMENTS) if phong else ()
    expected = [scalar_segments(c, r, camera, 4800, *rule) for c, r in zip(centers, radii)]
    assert counts.dtype == np.int64 and counts.tolist() == expected
    assert {PHONG_SPHERE_SEGMENTS if phong else MIN_SPHERE_SEGMENTS, MAX_SPHERE_SEGMENTS} < set(expected)
    assert sphere_segments(centers[:0], radii[:0], camera, 4800, phong).shape == (0,)


def test_a_sphere_too_large_for_a_segment_step_compiles_and_ray_traces():
    """An orthographic view 1e-5 tall of a sphere of radius 1e10: r_px = 1.6e16 rows, 1 - 0.5 / r_px
    rounds to 1 and the step to 0 -- compiling divided by it (ZeroDivisionError). Now MAX_SPHERE_SEGMENTS
    longitudes, and the ray-traced image is the sphere's lit face: kd 0.7 x cos 0 = 0.7 in red."""
    camera = {"eye": [0, 0, 2e10], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 1e-5,
              "width": 16, "height": 16, "near": 1e5, "far": 1e11}
    scene = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 1e10, "material": "red"}], MATERIALS,
                       camera=camera, lights=[{"type": "directional", "direction": [0, 0, -1]}])
    compiled = compile_scene(scene)
    sphere = compiled.scene.objects[0]
    for phong in (False, True):
        assert sphere_segments([sphere.center], [sphere.radius], compiled.scene.camera, 16,
                               phong).tolist() == [MAX_SPHERE_SEGMENTS]
    image = render(compiled, method="raytrace")
    np.testing.assert_allclose(image, np.broadcast_to([0.7, 0.1, 0.1], image.shape), rtol=1e-5)


def lone_sphere(radius: float, size: int, eye=(0.0, 0.0, 5.0), up=(0, 1, 0), spp: int = 1) -> dict:
    """A sphere at the origin seen by an orthographic camera 2 units tall: `radius` x size / 2 samples."""
    camera = {"eye": list(eye), "target": [0, 0, 0], "up": list(up), "projection": "orthographic",
              "ortho_height": 2.0, "width": size, "height": size}
    return scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": radius, "material": "red"}], MATERIALS,
                      camera=camera, render={"shading": "phong", "spp": spp})


@pytest.mark.parametrize("spp, phong_segments", [(1, 60), (4, 85)])
def test_a_phong_sphere_gets_the_sagitta_rules_longitudes_and_gouraud_its_128(spp, phong_segments):
    """The 256^2 bench's size of sphere, radius 0.7 of an orthographic view 2 tall: r = 89.6 sample
    rows (179.2 at spp 4). Phong's tessellation: the fewest N with the polygon's sagitta
    r (1 - cos(pi / N)) under an eighth of a sample, N = ceil(pi / acos(1 - 0.125 / r)): 60 (85),
    N / 2 bands, 2 N (N / 2 - 1) triangles; flat and Gouraud's: the 128 floor (the half-sample rule
    asks for 30 / 43), 16,128 triangles, as before."""
    compiled = compile_scene(lone_sphere(0.7, 256, spp=spp))
    radius_px = 0.7 * 256 * math.isqrt(spp) / 2.0
    assert phong_segments == math.ceil(math.pi / math.acos(1.0 - 0.125 / radius_px))
    sagitta = radius_px * (1.0 - math.cos(math.pi / phong_segments))
    assert sagitta <= 0.125 < radius_px * (1.0 - math.cos(math.pi / (phong_segments - 1)))
    assert compiled.analytic.sphere_grids(True).tolist() == [[phong_segments // 2, phong_segments]]
    assert compiled.analytic.sphere_grids(False).tolist() == [[64, MIN_SPHERE_SEGMENTS]]
    assert compiled.raster("phong").faces.shape[0] == 2 * phong_segments * (phong_segments // 2 - 1)
    assert compiled.raster("gouraud").faces.shape[0] == compiled.raster("flat").faces.shape[0] == 16_128


def silhouette_misses(radius: float, size: int, azimuth: float, elevation: float) -> float:
    """How deep inside the true silhouette (samples) the raster Phong sphere misses a sample centre
    (0: none missed), seen from `azimuth` about the sphere's poles and `elevation` above its
    equator; AssertionError where it covers one outside the true circle."""
    eye = 5.0 * np.array([math.sin(azimuth) * math.cos(elevation), math.sin(elevation),
                          math.cos(azimuth) * math.cos(elevation)])
    up = (0, 0, -1) if elevation > 1.5 else (0, 1, 0)
    mask = render_frame(lone_sphere(radius, size, eye, up), method="raster").gbuffer.mask
    i, j = np.indices(mask.shape)
    distance = np.hypot(j + 0.5 - size / 2, i + 0.5 - size / 2)
    radius_px = radius * size / 2.0
    assert not (mask & (distance > radius_px + 1e-3)).any()  # the facets are inscribed
    return float((radius_px - distance)[~mask & (distance < radius_px)].max(initial=0.0))


def test_a_phong_spheres_silhouette_is_within_a_quarter_sample(monkeypatch):
    """A sphere 51.2 samples in radius (45 longitudes) from 16 views -- the silhouette along a
    meridian of vertices, through the middles of the facets (half a longitude step round), a
    quarter step, elevated, from above the pole -- misses no sample centre deeper than a quarter
    sample inside the true circle (0.225 at most) and covers none outside it. The rule holds the
    polygon's sagitta to an eighth of a sample because the facets are twice as deep as it: with a
    quarter (32 longitudes) a view through the facets' middles misses samples 0.40 inside."""
    n_lon = 45
    views = [(azimuth, elevation) for azimuth in (0.0, math.pi / n_lon, math.pi / (2 * n_lon), 0.3)
             for elevation in (0.0, 0.3, 1.0, math.pi / 2)]
    depths = [silhouette_misses(0.8, 128, *view) for view in views]
    assert 0.2 < max(depths) <= 0.25
    monkeypatch.setitem(SAGITTA, True, 0.25)
    assert silhouette_misses(0.8, 128, math.pi / 32, 1.0) > 0.35


SHADED = ("mask", "depth", "position", "normal", "uv", "material", "object", "face", "bary")


def test_one_compiled_scene_drawn_phong_gouraud_phong_is_three_fresh_compiles(tessellations):
    """A compiled scene (spheres, a plane, a mesh) rendered under Phong, then Gouraud, then Phong
    shading: each image and G-buffer is a freshly compiled scene's under that shading (the two
    tessellations built once each, never mixed), and `face` indexes the triangles of
    `raster(shading)`, of the object the G-buffer names."""
    compiled = compile_scene(WHITTED)
    for shading in ("phong", "gouraud", "phong"):
        frame = render_frame(compiled, method="raster", shading=shading)
        fresh = render_frame(compile_scene(WHITTED), method="raster", shading=shading)
        assert np.array_equal(frame.image, fresh.image), shading
        for name in SHADED:
            assert np.array_equal(getattr(frame.gbuffer, name), getattr(fresh.gbuffer, name)), (shading, name)
        drawn = compiled.raster(shading)
        assert frame.stats["triangles"] == drawn.faces.shape[0]
        mask, face = frame.gbuffer.mask, frame.gbuffer.face
        assert face[mask].max() < drawn.faces.shape[0]
        assert np.array_equal(drawn.face_object[face[mask]], frame.gbuffer.object[mask])
    assert tessellations.count(True) == 3 and tessellations.count(False) == 2  # compiled's two, fresh ones' three
