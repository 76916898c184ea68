"""An OBJ with `vt` but no `vn`: its vertices are split at the uv seam (one per (v, vt)), yet the
smooth normals are those of the unsplit surface -- averaged over every face at a position
(`TriMesh.welds`), not over one side of the seam."""

import numpy as np
import pytest

import difflab
from difflab.geometry import load_mesh
from difflab.geometry.obj_text import read_obj

N_LAT, N_LON = 8, 16


TRIMESH = "#\tread by trimesh (numpy's reader leaves a file with a tab to it)"


def sphere_obj(*, uvs: bool, quads: bool = False, trimesh: bool = False) -> str:
    """A unit uv sphere, each position written once (the seam merged), uvs with u = 0 and u = 1
    columns at the seam (so the seam's positions are split by uv). `quads`: the rings' cells as
    quads, else triangles (numpy reads either); `trimesh`: with a TRIMESH comment."""
    v = [(np.sin(np.pi * i / N_LAT) * np.cos(2 * np.pi * j / N_LON), np.cos(np.pi * i / N_LAT),
          np.sin(np.pi * i / N_LAT) * np.sin(2 * np.pi * j / N_LON)) for i in range(1, N_LAT) for j in range(N_LON)]
    top, bottom = len(v), len(v) + 1
    v += [(0.0, 1.0, 0.0), (0.0, -1.0, 0.0)]
    vt = [(j / N_LON, 1 - i / N_LAT) for i in range(1, N_LAT) for j in range(N_LON + 1)] + [(0.5, 1.0), (0.5, 0.0)]

    def corner(i, j):  # (v, vt) of ring i (1..N_LAT-1), column j (0..N_LON)
        return (i - 1) * N_LON + j % N_LON, (i - 1) * (N_LON + 1) + j

    faces = []
    for j in range(N_LON):
        faces.append([(top, len(vt) - 2), corner(1, j + 1), corner(1, j)])
        faces.append([(bottom, len(vt) - 1), corner(N_LAT - 1, j), corner(N_LAT - 1, j + 1)])
    for i in range(1, N_LAT - 1):
        for j in range(N_LON):
            a, b, c, d = corner(i, j), corner(i, j + 1), corner(i + 1, j + 1), corner(i + 1, j)
            faces += [[a, b, c, d]] if quads else [[a, b, c], [a, c, d]]
    lines = [TRIMESH] if trimesh else []
    lines += [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v]
    if uvs:
        lines += [f"vt {a:.17g} {b:.17g}" for a, b in vt]
    lines += ["f " + " ".join(f"{p + 1}/{t + 1}" if uvs else f"{p + 1}" for p, t in face) for face in faces]
    return "\n".join(lines) + "\n"


READERS = {"numpy triangles": {}, "numpy quads": {"quads": True}, "trimesh quads": {"quads": True, "trimesh": True}}


def angles_to_radial(mesh, normals):
    radial = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip((normals * radial).sum(1), -1.0, 1.0)))


@pytest.mark.parametrize("reader", sorted(READERS))
def test_seam_vertices_get_the_normal_of_the_unsplit_sphere(tmp_path, reader):
    """Without welding, a seam vertex averaged one side's faces: 11.78 deg off radial at this size
    (the others 4.13, the facets' own error). Now every vertex, seam or not, is within the others' bound, and a seam
    position's copies get the same normal."""
    path = tmp_path / "seam.obj"
    path.write_text(sphere_obj(uvs=True, **READERS[reader]))
    assert (read_obj(path.read_bytes()).arrays is None) == reader.startswith("trimesh")
    mesh = load_mesh(path)
    assert mesh.normals is None and mesh.uvs is not None
    seam = (np.abs(mesh.vertices[:, 2]) < 1e-12) & (mesh.vertices[:, 0] > 0)
    assert seam.sum() == 2 * (N_LAT - 1) and mesh.n_vertices == (N_LAT - 1) * N_LON + 2 + N_LAT - 1  # seam split in two
    normals = mesh.smooth_normals()
    error = angles_to_radial(mesh, normals)
    assert error[~seam].max() < 4.2 and error[seam].max() <= error[~seam].max() + 1e-9
    seam_rows = np.flatnonzero(seam)
    order = np.lexsort(mesh.vertices[seam_rows].T)
    pairs = normals[seam_rows[order]].reshape(-1, 2, 3)  # each seam position's two copies
    np.testing.assert_array_equal(pairs[:, 0], pairs[:, 1])
    unsplit = tmp_path / "unsplit.obj"
    unsplit.write_text(sphere_obj(uvs=False, **READERS[reader]))
    plain = load_mesh(unsplit)
    assert plain.welds is None
    np.testing.assert_allclose(angles_to_radial(plain, plain.smooth_normals()).max(), error.max(), atol=1e-9)


@pytest.mark.parametrize("reader", sorted(READERS))
def test_phong_render_with_vt_equals_the_render_without(tmp_path, reader):
    """The same surface with and without `vt` (no texture) shades alike: max |difference| under
    1e-5 (float32 rounding of normals summed in another order). Before, 3033 of the 6912 values
    (48 x 48 x 3) differed, by up to 0.485, on the faces along the seam. The mesh is scaled and moved (the welds survive
    the transform)."""
    images = []
    for uvs in (True, False):
        path = tmp_path / f"sphere_{uvs}.obj"
        path.write_text(sphere_obj(uvs=uvs, **READERS[reader]))
        images.append(difflab.render({
            "camera": {"eye": [3, 0.5, 0], "target": [0, 0.5, 0], "fov_y": 40, "width": 48, "height": 48},
            "ambient": [0, 0, 0], "lights": [{"type": "directional", "direction": [-1, 0, 0.4]}],
            "materials": {"m": {"kd": [0.8, 0.8, 0.8], "ks": [0.5, 0.5, 0.5], "n": 40}},
            "objects": [{"type": "mesh", "file": str(path), "material": "m",
                         "transform": {"translate": [0, 0.5, 0], "scale": [1, 1.2, 1]}}],
            "render": {"method": "raster", "shading": "phong"}}))
    assert images[0].max() > 0.5  # the sphere is lit, its seam (x > 0, z = 0) faces the camera
    np.testing.assert_allclose(images[0], images[1], rtol=0, atol=1e-5)


def cube_obj(*, quads: bool, mixed_order: bool = False, trimesh: bool = False) -> str:
    """A 2-unit cube with its own 4 `v` lines per face (hard edges: the only way an OBJ without `vn`
    keeps them; each corner position is in three `v` lines), `vt`, no `vn`. `quads`: a quad per face,
    else two triangles. `mixed_order`: the faces as a triangle pair and a quad alternately (trimesh
    puts the quads' triangles after the others). `trimesh`: with a TRIMESH comment (else numpy reads
    the file)."""
    lines, faces = [], []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        for sign in (-1, 1):
            for u, v in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0, 0, 0]
                p[axis], p[a], p[b] = sign, u, v * sign
                lines.append("v %d %d %d" % tuple(p))
            i = [len(lines) - 3 + j for j in range(4)]
            quad = quads and (not mixed_order or len(faces) % 2 == 0)
            faces += [[(i[0], 1), (i[1], 2), (i[2], 3), (i[3], 4)]] if quad else \
                [[(i[0], 1), (i[1], 2), (i[2], 3)], [(i[0], 1), (i[2], 3), (i[3], 4)]]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1"]
    lines += ["f " + " ".join(f"{p}/{t}" for p, t in face) for face in faces]
    return "\n".join([TRIMESH] * trimesh + lines) + "\n"


@pytest.mark.parametrize("layout", ["triangles", "quads", "mixed", "mixed, trimesh"])
def test_a_hard_edged_cube_without_normals_keeps_its_face_normals(tmp_path, layout):
    """The welds come from the file's `v` lines on every path, never from equal positions: each
    vertex's smooth normal is its face's normal (0 deg apart, to rounding) however the faces are
    written. Before, trimesh's reading (quads) welded the three `v` lines at each corner by position:
    54.74 deg, the cube shaded as a blob."""
    path = tmp_path / "cube.obj"
    path.write_text(cube_obj(quads=layout != "triangles", mixed_order=layout.startswith("mixed"),
                             trimesh=layout.endswith("trimesh")))
    assert (read_obj(path.read_bytes()).arrays is None) == layout.endswith("trimesh")
    mesh = load_mesh(path)
    assert mesh.normals is None and mesh.uvs is not None and mesh.n_vertices == 24 and mesh.n_faces == 12
    assert mesh.welds is None or len(np.unique(mesh.welds)) == 24
    edges = mesh.vertices[mesh.faces[:, 1:]] - mesh.vertices[mesh.faces[:, :1]]
    face_normal = np.cross(edges[:, 0], edges[:, 1])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    np.testing.assert_allclose(mesh.smooth_normals()[mesh.faces], np.repeat(face_normal[:, None], 3, 1), atol=1e-12)


def normals_by_position(mesh) -> tuple[np.ndarray, np.ndarray]:
    """The distinct vertex positions (sorted) and the smooth normal of each (of its first copy)."""
    positions, first = np.unique(mesh.vertices, axis=0, return_index=True)
    return positions, mesh.smooth_normals()[first]


def test_a_repeated_face_keeps_the_welds_of_a_trimesh_read(tmp_path):
    """A quad sphere (TRIMESH) with its last quad written twice (trimesh reads it): the two
    copies' triangles are at the same positions and name the same `v` lines, so pairing them either
    way is right and the mesh is welded (before: no welds at all, seam normals 11.78 deg off radial). Its normals are
    those of the triangle file with the quad's two triangles repeated (numpy reads it) at every
    position. The quad repeated through new `v` lines at the same positions is ambiguous: no welds."""
    quads, triangles = sphere_obj(uvs=True, quads=True, trimesh=True), sphere_obj(uvs=True, quads=False)
    last_quad = [line for line in quads.splitlines() if line.startswith("f ")][-1]
    last_two = [line for line in triangles.splitlines() if line.startswith("f ")][-2:]
    (tmp_path / "quads.obj").write_text(quads + last_quad + "\n")
    (tmp_path / "triangles.obj").write_text(triangles + "\n".join(last_two) + "\n")
    read_by_trimesh, read_by_numpy = load_mesh(tmp_path / "quads.obj"), load_mesh(tmp_path / "triangles.obj")
    assert read_by_trimesh.welds is not None and read_by_numpy.welds is not None
    assert read_by_trimesh.n_faces == read_by_numpy.n_faces == 2 * N_LON * (N_LAT - 1) + 2
    positions, normals = normals_by_position(read_by_trimesh)
    numpy_positions, numpy_normals = normals_by_position(read_by_numpy)
    np.testing.assert_array_equal(positions, numpy_positions)
    np.testing.assert_allclose(normals, numpy_normals, rtol=0, atol=1e-12)
    assert angles_to_radial(read_by_trimesh, read_by_trimesh.smooth_normals()).max() < 7.1  # 7.04 (11.78 unwelded)
    corners = [int(c.split("/")[0]) for c in last_quad.split()[1:]]
    vertex_lines = [line for line in quads.splitlines() if line.startswith("v ")]
    copies = "".join(vertex_lines[c - 1] + "\n" for c in corners)
    copied_quad = "f " + " ".join(f"{len(vertex_lines) + k + 1}/{c.split('/')[1]}"
                                  for k, c in enumerate(last_quad.split()[1:]))
    (tmp_path / "copies.obj").write_text(quads + copies + copied_quad + "\n")
    assert load_mesh(tmp_path / "copies.obj").welds is None
