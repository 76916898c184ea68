"""Plain, validated scene data and its JSON form (no Warp, no JAX).

Every record is a frozen dataclass validated on construction; `Scene.from_dict` / `load_scene` raise
`difflab.errors.SceneError` with a message that starts with the field path, e.g.
`objects[2].radius: must be > 0, got -1`. Unknown keys, wrong types, bools as numbers, NaN/inf,
negative coefficients, zero-length directions, missing files and undefined materials are errors.
Colours (ka, kd, ks, absorption, ka2, kd2, intensity, ambient, background, fog colour) and a mesh's
scale may be one number meaning (x, x, x); `to_dict` always writes triples, lists and absolute paths.

Defaults (omitted keys; "required" has none):

- scene: camera and objects required; ambient (0,0,0), background (0,0,0), lights [], materials {},
  fog null, render {} (all defaults below).
- camera: eye, target required; up (0,1,0), fov_y 40 (degrees, vertical), width 320, height 240
  (width*height <= 64 megapixels), projection "perspective", near 0.1, far 100, ortho_height 2.
- light: type required ("point" | "directional" | "spot"); position (point, spot), direction
  (directional, spot; stored unit length) as the type needs; intensity (1,1,1), attenuation (1,0,0)
  = (kc, kl, kq), cutoff_deg 180 (no cone; a spot needs 0 < cutoff_deg <= 90), exponent 0.
- material: ka (0,0,0), kd (0.8,0.8,0.8), ks (0,0,0), n 1, kr 0, kt 0, ior 1, absorption (0,0,0),
  m 0.3, f0 0.04, checker null, texture null, filter "bilinear", wrap "repeat", texture_target "kd".
- checker: size 1, ka2 (0,0,0), kd2 (0.1,0.1,0.1).
- objects: "type" required. sphere: center, radius, material required. plane: point, normal, material
  required. mesh: material and exactly one of file / builtin; resolution 8, smooth true, transform {}.
- transform: translate (0,0,0), rotate_deg (0,0,0) (X then Y then Z), scale (1,1,1), matrix null.
- fog: mode required ("linear" | "exp" | "exp2"); color (0.5,0.5,0.5), start 0, end 1, density 1.
- render: method "raster", shading "phong", specular "phong", shadows true, max_depth 5, spp 1,
  fresnel "none", transparent_shadows true, clamp_vertex_colors false, interpolation "perspective",
  cull_backfaces false, adaptive_threshold 0, sampling "grid".
"""

from .material import TEXTURE_FILTERS, TEXTURE_TARGETS, TEXTURE_WRAPS, Checker, Material
from .objects import BUILTIN_MESHES, Mesh, Plane, SceneObject, Sphere, Transform
from .scene import Scene, load_scene, save_scene
from .view import MAX_PIXELS, Camera, Fog, Light, RenderSettings

__all__ = [
    "BUILTIN_MESHES", "MAX_PIXELS", "TEXTURE_FILTERS", "TEXTURE_TARGETS", "TEXTURE_WRAPS",
    "Camera", "Checker", "Fog", "Light", "Material", "Mesh", "Plane", "RenderSettings", "Scene",
    "SceneObject", "Sphere", "Transform", "load_scene", "save_scene",
]
