"""4x4 homogeneous transforms (column vectors, p' = M @ [x, y, z, 1]), right-handed, degrees."""

from __future__ import annotations

import numpy as np


def _vec3(value, what: str, allow_scalar: bool = False) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if allow_scalar and arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape != (3,):
        raise ValueError(f"{what} must be 3 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {arr.tolist()}")
    return arr


def rotation_matrix(axis, degrees: float) -> np.ndarray:
    """(4, 4) rotation by `degrees` about the unit direction `axis` through the origin,
    right-handed (counter-clockwise looking down the axis towards the origin; Rodrigues' formula).
    `rotation_matrix((0, 0, 1), 90)` maps (1, 0, 0) to (0, 1, 0)."""
    a = _vec3(axis, "axis")
    length = np.linalg.norm(a)
    if length == 0.0:
        raise ValueError("axis must not be the zero vector")
    x, y, z = a / length
    t = np.radians(float(degrees))
    c, s = np.cos(t), np.sin(t)
    # Exact values at multiples of 90 degrees keep axis rotations free of 1e-17 noise.
    if float(degrees) % 90.0 == 0.0:
        c, s = float(np.round(c)), float(np.round(s))
    C = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]
    return m


def translation_matrix(offset) -> np.ndarray:
    """(4, 4) translation by `offset`."""
    m = np.eye(4)
    m[:3, 3] = _vec3(offset, "translate")
    return m


def scale_matrix(scale) -> np.ndarray:
    """(4, 4) scale about the origin; `scale` is a number or 3 numbers."""
    return np.diag(np.append(_vec3(scale, "scale", allow_scalar=True), 1.0))


def transform_matrix(translate=(0.0, 0.0, 0.0), rotate_deg=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0),
                     matrix=None) -> np.ndarray:
    """(4, 4) M = matrix @ T @ Rz @ Ry @ Rx @ S.

    Applied to a point: first scale `S` (a number or 3 numbers, about the origin), then rotate
    about the x axis by rotate_deg[0], then about y by rotate_deg[1], then about z by
    rotate_deg[2] (all about the origin, right-handed, degrees), then translate, and finally the
    optional `matrix` (row-major 4x4, i.e. `matrix[i][j]` is row i, column j).
    """
    r = _vec3(rotate_deg, "rotate_deg")
    m = (translation_matrix(translate)
         @ rotation_matrix((0, 0, 1), r[2])
         @ rotation_matrix((0, 1, 0), r[1])
         @ rotation_matrix((1, 0, 0), r[0])
         @ scale_matrix(scale))
    if matrix is not None:
        extra = np.asarray(matrix, dtype=np.float64)
        if extra.shape != (4, 4) or not np.all(np.isfinite(extra)):
            raise ValueError(f"matrix must be a finite 4x4 array, got shape {extra.shape}")
        m = extra @ m
    return m


def apply_to_points(matrix, points) -> np.ndarray:
    """(N, 3) points mapped by the 4x4 `matrix` (homogeneous divide when the last row is not
    [0, 0, 0, 1])."""
    m = np.asarray(matrix, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    h = p @ m[:3, :3].T + m[:3, 3]
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        h = h / (p @ m[3, :3] + m[3, 3])[:, None]
    return h


def unit_linear_part(matrix) -> tuple[np.ndarray, float]:
    """(A / s, sign(det A)) for the 3x3 part A of `matrix`, with s = |det A|^(1/3) > 0, so that
    |det(A / s)| = 1: the linear map up to a positive scale, which neither a normal's direction nor
    the sign of det sees. det is never formed: A is first divided by the power of two at or below its
    largest |entry| (exact; entries then below 2, so the LU cannot overflow) and |det| is taken in
    log space (`slogdet`), so no uniform or per-axis scale within float64's range (1e-300, 1e300,
    diag(1e-160, 1e140, 1)) under- or overflows. ValueError if A is not finite or is singular: a zero
    pivot in the LU of the scaled A (det exactly 0 at any scale)."""
    m = np.asarray(matrix, dtype=np.float64)[:3, :3]
    biggest = float(np.abs(m).max())
    if not np.isfinite(biggest):
        raise ValueError(f"the 3x3 part of the matrix is not finite (largest |entry| {biggest})")
    scaled = m / 2.0 ** np.floor(np.log2(biggest)) if biggest > 0.0 else m
    sign, log_det = np.linalg.slogdet(scaled)
    if sign == 0.0:
        raise ValueError("the 3x3 part of the matrix is singular (det = 0 at any scale): it flattens some "
                         "direction, so normals are undefined")
    return scaled * np.exp(-log_det / 3.0), float(sign)


def apply_to_normals(matrix, normals) -> np.ndarray:
    """(N, 3) unit normals mapped by the inverse-transpose of the 3x3 part A of `matrix`; zero rows
    stay zero.

    A^-T is taken as sign(det B) cof(B) for B = A / |det A|^(1/3) (`unit_linear_part`; = B^-T as
    |det B| = 1; cof(B) rows: b1 x b2, b2 x b0, b0 x b1 of B's rows b_k): no inverse and no det, so
    neither a uniform scale (1e-300, 1e300) nor a nearly singular A (an axis scaled by 1e-160)
    under- or overflows it. Each mapped normal is divided by its largest |component| before its
    length is taken, so a length of 1e160 or 1e-160 neither overflows nor underflows. A singular A
    (det 0) raises ValueError.
    """
    m, sign = unit_linear_part(matrix)
    cofactor = np.stack([np.cross(m[1], m[2]), np.cross(m[2], m[0]), np.cross(m[0], m[1])])
    mapped = sign * np.asarray(normals, dtype=np.float64).reshape(-1, 3) @ cofactor.T
    biggest = np.abs(mapped).max(axis=1, keepdims=True)
    mapped = np.divide(mapped, biggest, out=np.zeros_like(mapped), where=biggest > 0)
    length = np.linalg.norm(mapped, axis=1, keepdims=True)
    return np.divide(mapped, length, out=np.zeros_like(mapped), where=length > 0)


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(4, 4) viewing transform, world -> camera space (gluLookAt): the camera at `eye` looks at
    `target` down its -z axis, x to the right, y up (the part of `up` orthogonal to the view)."""
    eye, target, up = _vec3(eye, "eye"), _vec3(target, "target"), _vec3(up, "up")
    forward = target - eye
    right = np.cross(forward, up)
    if np.linalg.norm(forward) == 0.0 or np.linalg.norm(right) == 0.0:
        raise ValueError("look_at: eye must differ from target and up must not be parallel to the view")
    forward /= np.linalg.norm(forward)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = right, np.cross(right, forward), -forward
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) perspective projection, camera -> clip space (gluPerspective): vertical field of view
    `fov_y` in degrees, aspect = width / height, 0 < near < far. After the divide by w = -z_camera,
    the view volume is the cube [-1, 1]^3, with z_ndc = (far + near) / (far - near)
    + 2 far near / ((far - near) z_camera): -1 at the near plane, +1 at the far plane."""
    _check_depth_range(near, far, perspective=True)
    f = 1.0 / np.tan(np.radians(float(fov_y)) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(height: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) orthographic projection, camera -> clip space (glOrtho) of a view volume `height`
    tall and `height * aspect` wide, centred on the view axis, depth from near to far."""
    _check_depth_range(near, far, perspective=False)
    half_h = float(height) / 2.0
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = 1.0 / (half_h * aspect), 1.0 / half_h
    m[2, 2], m[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    m[3, 3] = 1.0
    return m


def ndc_to_raster(ndc, width: int, height: int) -> np.ndarray:
    """(N, 2) raster coordinates (x right, y down, pixel (i, j) centred at (j + 0.5, i + 0.5)) of
    (N, >=2) normalised device coordinates: x = (x_ndc + 1) W / 2, y = (1 - y_ndc) H / 2."""
    ndc = np.asarray(ndc, dtype=np.float64).reshape(len(ndc), -1)
    return np.stack([(ndc[:, 0] + 1.0) * width / 2.0, (1.0 - ndc[:, 1]) * height / 2.0], axis=1)


def _check_depth_range(near: float, far: float, perspective: bool) -> None:
    if not (np.isfinite(near) and np.isfinite(far) and far > near and (near > 0.0 or not perspective)):
        raise ValueError(f"need {'0 < ' if perspective else ''}near < far, got near={near}, far={far}")
