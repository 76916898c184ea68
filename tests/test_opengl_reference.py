"""Optional: the rasterizer against OpenGL's fixed-function pipeline (Mesa's OSMesa, software GL).

With Blinn specular, per-vertex lighting, a local viewer, no light ambient and (kc, kl, kq)
attenuation, difflab's Gouraud shading is the GL 2.x lighting equation, so a 256x256 sphere must
match Mesa's render to PSNR >= 40 dB (8-bit output). Flat shading given one normal per face must
reach 30 dB: OpenGL lights a flat face at its last (provoking) vertex, difflab at its centroid.
Runs when PyOpenGL and libOSMesa are installed (`apt-get install libosmesa6; pip install PyOpenGL`).
"""

import os

import numpy as np
import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
GL = pytest.importorskip("OpenGL.GL", reason="PyOpenGL is not installed")
try:
    from OpenGL import osmesa
    osmesa.OSMesaCreateContextExt  # noqa: B018 - raises when libOSMesa is missing
except (ImportError, AttributeError, Exception) as exc:  # pragma: no cover - depends on the machine
    pytest.skip(f"OSMesa is not available ({exc})", allow_module_level=True)

from difflab import Scene, render
from difflab.renderers.camera import projection_matrix, view_matrix
from difflab.renderers.compile import object_mesh

SIZE = 256
SCENE = {
    "camera": {"eye": [0.4, 0.8, 3.2], "target": [0, 0, 0], "fov_y": 45, "width": SIZE, "height": SIZE,
               "near": 0.5, "far": 20},
    "ambient": [0.15, 0.12, 0.1],
    "lights": [
        {"type": "point", "position": [2.0, 3.0, 2.5], "intensity": [0.9, 0.85, 0.8], "attenuation": [0.6, 0.15, 0.03]},
        {"type": "directional", "direction": [-1.0, 0.2, -0.6], "intensity": [0.3, 0.35, 0.5]},
    ],
    "materials": {"m": {"ka": [0.3, 0.2, 0.2], "kd": [0.7, 0.35, 0.2], "ks": [0.6, 0.6, 0.6], "n": 24}},
    "objects": [{"type": "mesh", "builtin": "sphere", "resolution": 16, "material": "m"}],
    "render": {"shadows": False, "specular": "blinn"},
}


def opengl_render(scene: Scene, mesh, flat: bool) -> np.ndarray:
    """Render `mesh` with the fixed-function pipeline; returns (H, W, 3) in [0, 1], row 0 at the top."""
    width, height = scene.camera.width, scene.camera.height
    ctx = osmesa.OSMesaCreateContextExt(osmesa.OSMESA_RGBA, 24, 0, 0, None)
    buffer = (GL.GLubyte * (width * height * 4))()
    assert osmesa.OSMesaMakeCurrent(ctx, buffer, GL.GL_UNSIGNED_BYTE, width, height)
    try:
        GL.glViewport(0, 0, width, height)
        GL.glClearColor(0, 0, 0, 1)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glMatrixMode(GL.GL_PROJECTION)
        GL.glLoadMatrixd(projection_matrix(scene.camera).T.ravel())
        GL.glMatrixMode(GL.GL_MODELVIEW)
        GL.glLoadMatrixd(view_matrix(scene.camera).T.ravel())
        GL.glEnable(GL.GL_LIGHTING)
        GL.glLightModelfv(GL.GL_LIGHT_MODEL_AMBIENT, [*scene.ambient, 1.0])
        GL.glLightModeli(GL.GL_LIGHT_MODEL_LOCAL_VIEWER, 1)
        for k, light in enumerate(scene.lights):
            gl_light = GL.GL_LIGHT0 + k
            GL.glEnable(gl_light)
            GL.glLightfv(gl_light, GL.GL_AMBIENT, [0, 0, 0, 1])
            GL.glLightfv(gl_light, GL.GL_DIFFUSE, [*light.intensity, 1])
            GL.glLightfv(gl_light, GL.GL_SPECULAR, [*light.intensity, 1])
            if light.type == "point":
                GL.glLightfv(gl_light, GL.GL_POSITION, [*light.position, 1.0])  # through the view matrix
                kc, kl, kq = light.attenuation
                GL.glLightf(gl_light, GL.GL_CONSTANT_ATTENUATION, kc)
                GL.glLightf(gl_light, GL.GL_LINEAR_ATTENUATION, kl)
                GL.glLightf(gl_light, GL.GL_QUADRATIC_ATTENUATION, kq)
            else:
                GL.glLightfv(gl_light, GL.GL_POSITION, [*(-np.asarray(light.direction)), 0.0])
        material = scene.materials["m"]
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_AMBIENT, [*material.ka, 1])
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_DIFFUSE, [*material.kd, 1])
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_SPECULAR, [*material.ks, 1])
        GL.glMaterialf(GL.GL_FRONT_AND_BACK, GL.GL_SHININESS, material.n)
        GL.glShadeModel(GL.GL_FLAT if flat else GL.GL_SMOOTH)
        GL.glBegin(GL.GL_TRIANGLES)
        for face in mesh.faces:
            for v in face:
                GL.glNormal3dv(mesh.normals[v])
                GL.glVertex3dv(mesh.vertices[v])
        GL.glEnd()
        GL.glFinish()
        pixels = np.frombuffer(buffer, dtype=np.uint8).reshape(height, width, 4)[::-1, :, :3]
        return pixels.astype(np.float64) / 255.0
    finally:
        osmesa.OSMesaDestroyContext(ctx)


def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


@pytest.mark.parametrize("shading, smooth, threshold", [("gouraud", True, 40.0), ("flat", False, 30.0)])
def test_matches_mesa_fixed_function(shading, smooth, threshold):
    d = {**SCENE, "objects": [{**SCENE["objects"][0], "smooth": smooth}]}
    scene = Scene.from_dict(d)
    mesh = object_mesh(scene.objects[0])
    reference = opengl_render(scene, mesh, flat=not smooth)
    ours = render(scene, shading=shading, clamp_vertex_colors=True)
    ours8 = np.round(np.clip(ours, 0, 1) * 255) / 255
    assert reference.max() > 0.5  # not a black image
    value = psnr(ours8, reference)
    print(f"{shading}: PSNR {value:.1f} dB against Mesa")
    assert value >= threshold
