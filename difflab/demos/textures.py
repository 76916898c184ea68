"""The texture-filtering comparison: a receding checkerboard plane rendered with every filter and
measured against a supersampled ground truth (the lecture's "texture filtering" slides as numbers).

The scene: an image texture of a checkerboard (`checker_texture`) on the floor plane y = 0, seen
from a height of 1 looking toward the horizon, shaded unlit (ka = texture, Ia = 1, kd = ks = 0) so
a pixel is exactly the filtered texture. The ground truth (`plane_reference`) averages n x n
(default 32 x 32) analytic ray-plane hits per pixel, each the bilinearly reconstructed level-0
texture: the box-filtered image of the continuous texture, what an ideal filter would give.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .._warp import wp
from ..io import save_image
from ..renderers.api import as_scene, render, render_frame
from ..renderers.camera import CameraW, camera_struct, primary_ray
from ..renderers.launch import launch_rows
from ..renderers.tessellate import plane_uv_anchor
from ..renderers.texture.footprint import plane_uv
from ..renderers.texture.sampling import WRAPS, TexturesW, sample_bilinear
from ..renderers.texture.store import TextureStore
from .figures import image_grid

wp.set_module_options({"enable_backward": False})

FILTER_ORDER = ("nearest", "bilinear", "mipmap", "trilinear", "ewa")
FILTER_TITLES = {"nearest": "nearest", "bilinear": "bilinear", "mipmap": "mip-map (nearest level)",
                 "trilinear": "trilinear mip-map", "ewa": "EWA"}
HIGH_FREQUENCY = 0.125  # cycles per pixel above which error energy counts as moire


@wp.kernel
def plane_reference_kernel(row0: int, cam: CameraW, near: float, far: float, point: wp.vec3, normal: wp.vec3,
                           tangent: wp.vec3, bitangent: wp.vec3, anchor: wp.vec3, anchor_uv: wp.vec2,
                           tex: TexturesW, wrap: int, n: int, background: wp.vec3, image: wp.array2d(dtype=wp.vec3)):
    """Pixel (i, j): the mean over n x n sub-pixel rays of the level-0 bilinear texture at the ray's
    hit on the plane (background where the hit is outside [near, far] along the view axis)."""
    ii, j = wp.tid()
    i = row0 + ii
    total = wp.vec3(0.0)
    for a in range(n):
        for b in range(n):
            x = float(j) + (float(b) + 0.5) / float(n)
            y = float(i) + (float(a) + 0.5) / float(n)
            origin, direction = primary_ray(cam, x, y)
            denom = wp.dot(direction, normal)
            value = background
            if wp.abs(denom) > 1.0e-12:
                t = wp.dot(point - origin, normal) / denom
                p = origin + t * direction
                depth = wp.dot(p - cam.eye, cam.forward)
                if t > 0.0 and depth >= near and depth <= far:
                    value = sample_bilinear(tex, tex.first_level[0], plane_uv(p, anchor, tangent, bitangent, anchor_uv),
                                             wrap)
            total = total + value
    image[i, j] = total / float(n * n)


def checker_texture(size: int = 64, checks: int = 2, dark: float = 0.05, light: float = 0.9) -> np.ndarray:
    """A (size, size, 3) linear checkerboard image with `checks` x `checks` cells."""
    k = size // checks
    r, c = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    return np.where((r // k + c // k) % 2 == 0, light, dark).astype(np.float32)[..., None].repeat(3, axis=-1)


def receding_plane_scene(texture_path, filter: str, width: int, height: int, interpolation: str = "perspective",
                         eye=(0.0, 1.0, 0.0), target=(0.0, 0.0, -6.0), fov_y: float = 50.0, far: float = 200.0) -> dict:
    """The floor plane with an image texture, unlit (pixel = filtered texel), as a scene dict."""
    return {
        "camera": {"eye": list(eye), "target": list(target), "fov_y": fov_y, "width": width, "height": height,
                   "near": 0.1, "far": far},
        "ambient": [1.0, 1.0, 1.0], "background": [0.0, 0.0, 0.0],
        "materials": {"floor": {"ka": [1, 1, 1], "kd": [0, 0, 0], "texture": str(texture_path),
                                "texture_target": "ka", "filter": filter, "wrap": "repeat"}},
        "objects": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"shadows": False, "interpolation": interpolation},
    }


def plane_reference(scene, n: int = 32, device: str = "cpu") -> np.ndarray:
    """The n x n supersampled ground truth of a `receding_plane_scene` (its first plane, material's
    texture bilinear at level 0), as (H, W, 3) float32."""
    scene = as_scene(scene)
    plane = scene.objects[0]
    material = scene.materials[plane.material]
    camera = scene.camera
    store = TextureStore.from_paths([material.texture], device)
    anchor, anchor_uv = plane_uv_anchor(plane, camera.eye, material.uv_period)
    image = wp.zeros((camera.height, camera.width), dtype=wp.vec3, device=device)
    launch_rows(plane_reference_kernel, (camera.height, camera.width), [
        camera_struct(camera, camera.width, camera.height), float(camera.near), float(camera.far),
        wp.vec3(*plane.point), wp.vec3(*plane.normal), *(wp.vec3(*axis) for axis in plane.uv_frame()),
        wp.vec3(*anchor), wp.vec2(*anchor_uv), store.warp, WRAPS[material.wrap], int(n),
        wp.vec3(*scene.background), image], device)
    return image.numpy()


def far_rows(reference: np.ndarray, fraction: float = 0.35) -> slice:
    """The rows of the plane's far region: the `fraction` of covered rows nearest the horizon."""
    covered = np.flatnonzero(reference.max(axis=(1, 2)) > 0)
    top = int(covered[0]) + 1  # skip the partially covered horizon row
    return slice(top, top + max(2, int(fraction * (covered[-1] - top + 1))))


def moire(image: np.ndarray, reference: np.ndarray, rows: slice) -> float:
    """RMS of the error's spectral energy above HIGH_FREQUENCY cycles/pixel in `rows` (Hann-windowed
    2D FFT of the grey error): the spurious fine patterns aliasing leaves where the truth is smooth."""
    err = (image - reference)[rows].mean(axis=-1).astype(np.float64)
    h, w = err.shape
    window = np.outer(np.hanning(h), np.hanning(w))
    spectrum = np.abs(np.fft.fft2(err * window)) ** 2 / (window ** 2).sum()
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    high = np.hypot(fx, fy) > HIGH_FREQUENCY
    return float(np.sqrt(spectrum[high].sum() / (h * w)))


def compare_filters(texture_path, width: int, height: int, n_reference: int = 32, repeats: int = 3,
                    device: str = "cpu") -> tuple[dict, list[dict]]:
    """Render the receding plane with every filter; RMSE (whole image and far region) and moire
    against the n_reference^2-supersampled truth, and the median render time of `repeats`.
    Returns ({"reference": img, filter: img, ...}, rows of the table)."""
    reference = plane_reference(receding_plane_scene(texture_path, "bilinear", width, height), n_reference, device)
    rows_far = far_rows(reference)
    images, table = {"reference": reference}, []
    for name in FILTER_ORDER:
        scene = receding_plane_scene(texture_path, name, width, height)
        render_frame(scene, device=device)  # compile the kernels once
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            image = render_frame(scene, device=device).image
            times.append(time.perf_counter() - start)
        images[name] = image
        table.append({"filter": name, "rmse": float(np.sqrt(np.mean((image - reference) ** 2))),
                      "rmse_far": float(np.sqrt(np.mean((image[rows_far] - reference[rows_far]) ** 2))),
                      "moire": moire(image, reference, rows_far), "seconds": float(np.median(times))})
    return images, table


def texture_figures(out_dir: Path, size: int) -> list[tuple[Path, str]]:
    """The filtering comparison figure (and the affine-interpolation artefact) for `difflab demo`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    texture = save_image(out_dir / "checker_texture.png", checker_texture())
    width, height = size, max(8, (3 * size) // 4)
    images, table = compare_filters(texture, width, height, n_reference=16 if size <= 128 else 32, repeats=1)
    titles = ["ground truth (supersampled)"] + [f"{FILTER_TITLES[r['filter']]}: RMSE {r['rmse']:.3f}" for r in table]
    figure = image_grid([images[k] for k in ["reference", *FILTER_ORDER]], titles,
                        out_dir / "texture_filtering.png", columns=3)
    interp = [render(receding_plane_scene(texture, "trilinear", width, height, interpolation=mode))
              for mode in ("perspective", "affine")]
    artefact = image_grid(interp, ["perspective-correct uv", "affine (screen-linear) uv"],
                          out_dir / "texture_interpolation.png", columns=2)
    return [(texture, "the 64 x 64 checker texture (2 x 2 checks, sRGB) the two texture figures map onto the floor"),
            (figure, "a receding checkerboard texture: nearest and bilinear alias (moire), mip-maps blur, "
                     "EWA follows the anisotropic footprint; RMSE against a supersampled ground truth"),
            (artefact, "perspective-correct vs affine texture-coordinate interpolation on the same plane")]
