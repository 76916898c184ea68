"""Mesa's llvmpipe through OSMesa (PyOpenGL), fixed-function lighting: the rasterizer's peer in the
benchmarks. One context per image size; the mesh is drawn from client-side vertex arrays with
glDrawElements (GL 2.x lighting with a local viewer and no light ambient is difflab's Gouraud + Blinn
model). `tests/test_opengl_reference.py` holds difflab's images to this renderer's.

    renderer = MesaRenderer(scene, mesh)   # needs PyOpenGL and libOSMesa: see `available`
    seconds, image = renderer.draw()
"""

from __future__ import annotations

import os
import time

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")


def available() -> str | None:
    """None when OSMesa can be used, else why not."""
    try:
        from OpenGL import GL, osmesa  # noqa: F401
        osmesa.OSMesaCreateContextExt  # noqa: B018 - raises when libOSMesa is missing
    except Exception as exc:  # pragma: no cover - depends on the machine
        return (f"OSMesa is not available ({exc}): the OpenGL reference needs libOSMesa "
                "(`apt-get install libosmesa6`) and PyOpenGL (in the test extra)")
    return None


class MesaRenderer:
    """A scene's first material, lights and camera on an OSMesa context; `mesh` drawn with them,
    smooth (per-vertex colours interpolated) or flat (GL_FLAT: each face lit at its provoking vertex)."""

    def __init__(self, scene, mesh, flat: bool = False):
        from OpenGL import GL, osmesa

        from difflab.renderers.camera import projection_matrix, view_matrix

        self.GL, self.osmesa = GL, osmesa
        self.width, self.height = scene.camera.width, scene.camera.height
        self.ctx = osmesa.OSMesaCreateContextExt(osmesa.OSMESA_RGBA, 24, 0, 0, None)
        self.buffer = (GL.GLubyte * (self.width * self.height * 4))()
        if not osmesa.OSMesaMakeCurrent(self.ctx, self.buffer, GL.GL_UNSIGNED_BYTE, self.width, self.height):
            raise RuntimeError("OSMesaMakeCurrent failed")
        GL.glViewport(0, 0, self.width, self.height)
        GL.glClearColor(*scene.background, 1)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glMatrixMode(GL.GL_PROJECTION)
        GL.glLoadMatrixd(projection_matrix(scene.camera).T.ravel())
        GL.glMatrixMode(GL.GL_MODELVIEW)
        GL.glLoadMatrixd(view_matrix(scene.camera).T.ravel())
        self.light(scene)
        material = next(iter(scene.materials.values()))
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_AMBIENT, [*material.ka, 1])
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_DIFFUSE, [*material.kd, 1])
        GL.glMaterialfv(GL.GL_FRONT_AND_BACK, GL.GL_SPECULAR, [*material.ks, 1])
        GL.glMaterialf(GL.GL_FRONT_AND_BACK, GL.GL_SHININESS, min(material.n, 128.0))
        GL.glShadeModel(GL.GL_FLAT if flat else GL.GL_SMOOTH)
        self.vertices = np.ascontiguousarray(mesh.vertices, np.float32)
        self.normals = np.ascontiguousarray(mesh.normals, np.float32)
        self.indices = np.ascontiguousarray(mesh.faces, np.uint32).ravel()
        GL.glEnableClientState(GL.GL_VERTEX_ARRAY)
        GL.glEnableClientState(GL.GL_NORMAL_ARRAY)
        GL.glVertexPointer(3, GL.GL_FLOAT, 0, self.vertices)
        GL.glNormalPointer(GL.GL_FLOAT, 0, self.normals)

    def light(self, scene) -> None:
        GL = self.GL
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

    def draw(self) -> tuple[float, np.ndarray]:
        """Clear, draw the mesh, glFinish: (seconds, (H, W, 3) image in [0, 1], row 0 at the top)."""
        GL = self.GL
        self.osmesa.OSMesaMakeCurrent(self.ctx, self.buffer, GL.GL_UNSIGNED_BYTE, self.width, self.height)
        start = time.perf_counter()
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glDrawElements(GL.GL_TRIANGLES, self.indices.size, GL.GL_UNSIGNED_INT, self.indices)
        GL.glFinish()
        seconds = time.perf_counter() - start
        pixels = np.frombuffer(self.buffer, dtype=np.uint8).reshape(self.height, self.width, 4)[::-1, :, :3]
        return seconds, pixels.astype(np.float32) / 255.0

    def close(self) -> None:
        self.osmesa.OSMesaDestroyContext(self.ctx)
