"""difflab.geometry: numpy triangle meshes (no Warp, no JAX).

- `TriMesh` (validated, immutable), `concatenate`, `weld`; `closed_outward` / `solid_pieces` (closed surfaces of solids, facing out)
- primitives: `uv_sphere` (`uv_sphere_size`: its counts), `quad`, `box`, `cylinder`; the Utah `teapot`
  (`teapot_control_points`, `teapot_patches`)
- normals: `face_normals`, `face_areas`, `vertex_normals` (area-weighted by default; vertices
  without a non-degenerate face get a zero normal), `degenerate_faces`
- transforms: `transform_matrix` (M = matrix @ T @ Rz @ Ry @ Rx @ S), `rotation_matrix`,
  `translation_matrix`, `scale_matrix`, `apply_to_points`, `apply_to_normals`; the viewing and
  projection matrices `look_at`, `perspective`, `orthographic` (OpenGL's) and `ndc_to_raster`
- files: `load_mesh` (OBJ, PLY via trimesh), `save_mesh` (OBJ)
- uv projection: `planar_uv`, `spherical_uv`, `cylindrical_uv`, `project_uvs`; `uv_frame` (a plane's
  texture frame, upright seen from its normal's side, as `scene.Plane`'s)
"""

from .closed import closed_outward, solid_pieces
from .loading import load_mesh, save_mesh
from .mesh import TriMesh, concatenate, weld
from .normals import degenerate_faces, face_areas, face_normals, vertex_normals
from .primitives import box, cylinder, quad, uv_sphere, uv_sphere_size
from .teapot import teapot, teapot_control_points, teapot_patches
from .uv_projection import cylindrical_uv, planar_uv, project_uvs, spherical_uv, uv_frame
from .transforms import (apply_to_normals, apply_to_points, look_at, ndc_to_raster, orthographic, perspective,
                         rotation_matrix, scale_matrix, transform_matrix, translation_matrix)

__all__ = [
    "TriMesh", "concatenate", "weld", "closed_outward", "solid_pieces",
    "uv_sphere", "uv_sphere_size", "quad", "box", "cylinder",
    "teapot", "teapot_control_points", "teapot_patches",
    "face_normals", "face_areas", "vertex_normals", "degenerate_faces",
    "transform_matrix", "rotation_matrix", "translation_matrix", "scale_matrix",
    "apply_to_points", "apply_to_normals", "look_at", "perspective", "orthographic", "ndc_to_raster",
    "load_mesh", "save_mesh",
    "planar_uv", "spherical_uv", "cylindrical_uv", "project_uvs", "uv_frame",
]
