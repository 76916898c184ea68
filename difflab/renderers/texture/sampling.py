"""Image textures in Warp: wrap modes, texel fetch, nearest / bilinear / mip-map / trilinear / EWA
filtering. The footprints that drive them (d(uv)/dx, d(uv)/dy) are `footprint`'s.

Texture space. uv = (0, 0) is the image's bottom-left corner and (1, 1) its top-right (OpenGL):
level l (width W_l, height H_l) has texel (row r, column c) centred at uv = ((c + 0.5) / W_l,
(r + 0.5) / H_l); rows are stored bottom-up (`texture_store` flips the image once when packing).

Storage (`TexturesW`). Every level of every texture lives in one flat `texels` array; `level[k]`
= (offset, width, height) of level k, and texture t owns levels first_level[t] ..
first_level[t] + n_levels[t] - 1 (level 0 the image, each next one half as wide and high, rounded
down, averaging its exact footprint on the one below (the 2x2 box mean for even sizes), down to
1x1: see `store.mip_pyramid`).

Texel fetch is always in range: the wrap mode is applied to the *float* texel index (so u = 1,
negative, huge or non-finite coordinates all land inside), and the integer is clamped again after.
repeat: i mod n; clamp: min(max(i, 0), n - 1); mirror: period 2n, reflected (n..2n-1 -> n-1..0).

Filters (`sample_texture`, `filter` in the scene's TEXTURE_FILTERS order):
- nearest:   the texel containing uv, level 0.
- bilinear:  the four texels around uv (centres at half-integers), level 0, lerped.
- mipmap:    bilinear inside the level nearest to the level of detail (GL_LINEAR_MIPMAP_NEAREST).
- trilinear: bilinear in levels floor(lod) and floor(lod) + 1, lerped (GL_LINEAR_MIPMAP_LINEAR).
  lod = log2(rho), rho = max(|d(s,t)/dx|, |d(s,t)/dy|) in level-0 texels (the OpenGL spec's
  scale factor); lod <= 0 is magnification: bilinear at level 0.
- ewa:       Heckbert's elliptical weighted average, as in pbrt: the screen pixel's footprint in
  texture space is the ellipse spanned by the Jacobian columns d(uv)/dx, d(uv)/dy; its minor axis
  is lengthened so the eccentricity is at most EWA_MAX_ANISOTROPY; the level is chosen so the minor
  axis is about one texel (lod = log2(minor axis in level-0 texels)), and levels floor(lod) and
  floor(lod) + 1 are each filtered with the Gaussian exp(-alpha r^2) - exp(-alpha) (alpha =
  EWA_ALPHA) over the ellipse r^2 < 1, whose quadratic form has the identity added (a one-texel
  reconstruction filter, so the ellipse always covers a texel centre; pbrt-v4's MIPMap::EWA adds it
  too, and it blurs a 1:1 mapping: the texel 0.48, its 4 edge neighbours 0.13 each), then lerped. Taps are
  bounded: the search box is clamped to EWA_MAX_RADIUS texels around uv, so at most
  (2 EWA_MAX_RADIUS + 1)^2 taps per level (the ellipse itself, by construction, has a major
  semi-axis of at most 2 EWA_MAX_ANISOTROPY + 1 texels at the finer level).
"""

from __future__ import annotations

from ..._warp import wp

from ...vocabulary import TEXTURE_FILTER_IDS, TEXTURE_WRAP_IDS

wp.set_module_options({"enable_backward": False})

FILTERS = TEXTURE_FILTER_IDS  # the scene's names -> ids (MaterialW.texture_filter)
WRAPS = TEXTURE_WRAP_IDS
NEAREST, BILINEAR, MIPMAP, TRILINEAR, EWA = (FILTERS[k] for k in ("nearest", "bilinear", "mipmap", "trilinear", "ewa"))
REPEAT, CLAMP, MIRROR = (WRAPS[k] for k in ("repeat", "clamp", "mirror"))
EWA_MAX_ANISOTROPY = 8.0  # longest / shortest axis of the filtered ellipse (pbrt's default)
EWA_ALPHA = 2.0  # Gaussian falloff exp(-alpha r^2), r = 1 on the ellipse (pbrt's default)
EWA_MAX_RADIUS = 17  # search box half-width in texels (>= 2 * 8 + 1: the ellipse always fits)
NO_LOD = -1.0e30  # lod of a zero footprint (magnification)


@wp.struct
class TexturesW:
    """All textures of a scene: every level of every texture in one flat array (see the module doc)."""

    texels: wp.array(dtype=wp.vec3)  # linear RGB, level by level, rows bottom-up
    level: wp.array(dtype=wp.vec3i)  # (offset into texels, width, height) of each level
    first_level: wp.array(dtype=wp.int32)  # per texture: index of its level 0 in `level`
    n_levels: wp.array(dtype=wp.int32)  # per texture


@wp.func
def wrap_index(i: float, n: int, mode: int):
    """A texel index (an integer-valued float, any value) wrapped into [0, n - 1] by `mode`."""
    nf = float(n)
    x = i
    if not wp.isfinite(x):
        x = 0.0
    if mode == CLAMP:
        x = wp.clamp(x, 0.0, nf - 1.0)
    elif mode == MIRROR:
        x = x - 2.0 * nf * wp.floor(x / (2.0 * nf))  # in [0, 2n) up to rounding
        if x >= nf:
            x = 2.0 * nf - 1.0 - x
    else:
        x = x - nf * wp.floor(x / nf)  # in [0, n) up to rounding
    return wp.clamp(int(wp.clamp(x, 0.0, nf - 1.0)), 0, n - 1)  # rounding of huge values stays inside


@wp.func
def fetch(tex: TexturesW, level: int, col: float, row: float, wrap: int):
    """Texel (row, col) of absolute level index `level`, wrapped into range."""
    info = tex.level[level]
    c = wrap_index(col, info[1], wrap)
    r = wrap_index(row, info[2], wrap)
    return tex.texels[info[0] + r * info[1] + c]


@wp.func
def sample_nearest(tex: TexturesW, level: int, uv: wp.vec2, wrap: int):
    """The texel whose square contains uv."""
    info = tex.level[level]
    return fetch(tex, level, wp.floor(uv[0] * float(info[1])), wp.floor(uv[1] * float(info[2])), wrap)


@wp.func
def sample_bilinear(tex: TexturesW, level: int, uv: wp.vec2, wrap: int):
    """The four texels around uv, lerped (lerp form: a constant texture returns the constant exactly)."""
    info = tex.level[level]
    x = uv[0] * float(info[1]) - 0.5
    y = uv[1] * float(info[2]) - 0.5
    if not (wp.isfinite(x) and wp.isfinite(y)):
        x = 0.0
        y = 0.0
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    bottom = wp.lerp(fetch(tex, level, x0, y0, wrap), fetch(tex, level, x0 + 1.0, y0, wrap), fx)
    top = wp.lerp(fetch(tex, level, x0, y0 + 1.0, wrap), fetch(tex, level, x0 + 1.0, y0 + 1.0, wrap), fx)
    return wp.lerp(bottom, top, fy)


@wp.func
def texture_lod(tex: TexturesW, tex_id: int, duv_dx: wp.vec2, duv_dy: wp.vec2):
    """OpenGL's level of detail log2(rho), rho = max(|d(s,t)/dx|, |d(s,t)/dy|) in level-0 texels;
    NO_LOD for a zero or non-finite footprint."""
    info = tex.level[tex.first_level[tex_id]]
    w = float(info[1])
    h = float(info[2])
    ax = duv_dx[0] * w
    ay = duv_dx[1] * h
    bx = duv_dy[0] * w
    by = duv_dy[1] * h
    rho2 = wp.max(ax * ax + ay * ay, bx * bx + by * by)
    if not (rho2 > 0.0 and wp.isfinite(rho2)):
        return NO_LOD
    return 0.5 * wp.log2(rho2)


@wp.func
def sample_mipmap(tex: TexturesW, tex_id: int, uv: wp.vec2, lod: float, wrap: int):
    """Bilinear in the level nearest to `lod` (level 0 when magnifying)."""
    first = tex.first_level[tex_id]
    level = 0
    if lod > 0.0:
        level = wp.min(int(wp.floor(lod + 0.5)), tex.n_levels[tex_id] - 1)
    return sample_bilinear(tex, first + level, uv, wrap)


@wp.func
def sample_trilinear(tex: TexturesW, tex_id: int, uv: wp.vec2, lod: float, wrap: int):
    """Bilinear in levels floor(lod) and floor(lod) + 1, lerped by frac(lod)."""
    first = tex.first_level[tex_id]
    last = tex.n_levels[tex_id] - 1
    if lod <= 0.0:
        return sample_bilinear(tex, first, uv, wrap)
    if lod >= float(last):
        return sample_bilinear(tex, first + last, uv, wrap)
    lower = int(wp.floor(lod))
    f = lod - float(lower)
    return wp.lerp(sample_bilinear(tex, first + lower, uv, wrap), sample_bilinear(tex, first + lower + 1, uv, wrap), f)


@wp.func
def ewa_level(tex: TexturesW, level: int, uv: wp.vec2, d0: wp.vec2, d1: wp.vec2, wrap: int):
    """Gaussian-weighted average over the ellipse spanned by d0, d1 (uv units) at one level."""
    info = tex.level[level]
    w = float(info[1])
    h = float(info[2])
    s = uv[0] * w - 0.5
    t = uv[1] * h - 0.5
    s0 = d0[0] * w
    t0 = d0[1] * h
    s1 = d1[0] * w
    t1 = d1[1] * h
    # Implicit ellipse A ds^2 + B ds dt + C dt^2 < 1 (the +1 adds a one-texel reconstruction filter).
    a = t0 * t0 + t1 * t1 + 1.0
    b = -2.0 * (s0 * t0 + s1 * t1)
    c = s0 * s0 + s1 * s1 + 1.0
    inv_f = 1.0 / (a * c - 0.25 * b * b)
    a = a * inv_f
    b = b * inv_f
    c = c * inv_f
    det = 4.0 * a * c - b * b
    half_s = wp.min(2.0 * wp.sqrt(det * c) / det, float(EWA_MAX_RADIUS))
    half_t = wp.min(2.0 * wp.sqrt(det * a) / det, float(EWA_MAX_RADIUS))
    i_lo = int(wp.ceil(s - half_s))
    i_hi = int(wp.floor(s + half_s))
    j_lo = int(wp.ceil(t - half_t))
    j_hi = int(wp.floor(t + half_t))
    total = wp.vec3(0.0)
    weight = float(0.0)
    edge = wp.exp(-EWA_ALPHA)
    for j in range(j_lo, j_hi + 1):
        dt = float(j) - t
        for i in range(i_lo, i_hi + 1):
            ds = float(i) - s
            r2 = a * ds * ds + b * ds * dt + c * dt * dt
            if r2 < 1.0:
                k = wp.exp(-EWA_ALPHA * r2) - edge
                total = total + k * fetch(tex, level, float(i), float(j), wrap)
                weight = weight + k
    if weight > 0.0:
        return total / weight
    return sample_bilinear(tex, level, uv, wrap)


@wp.func
def sample_ewa(tex: TexturesW, tex_id: int, uv: wp.vec2, duv_dx: wp.vec2, duv_dy: wp.vec2, wrap: int):
    """Heckbert's EWA filter driven by the Jacobian columns d(uv)/dx, d(uv)/dy (see the module doc)."""
    first = tex.first_level[tex_id]
    last = tex.n_levels[tex_id] - 1
    info = tex.level[first]
    scale = wp.vec2(float(info[1]), float(info[2]))  # uv -> level-0 texels
    major = duv_dx
    minor = duv_dy
    if wp.length_sq(wp.cw_mul(major, scale)) < wp.length_sq(wp.cw_mul(minor, scale)):
        major = duv_dy
        minor = duv_dx
    major_len = wp.length(wp.cw_mul(major, scale))
    minor_len = wp.length(wp.cw_mul(minor, scale))
    if not (wp.isfinite(major_len) and wp.isfinite(minor_len)) or major_len == 0.0:
        return sample_bilinear(tex, first, uv, wrap)
    if minor_len * EWA_MAX_ANISOTROPY < major_len:  # clamp the eccentricity: widen the minor axis
        target = major_len / EWA_MAX_ANISOTROPY
        if minor_len > 0.0:
            minor = minor * (target / minor_len)
        else:  # a degenerate (line) footprint: the perpendicular of the major axis
            perp = wp.vec2(-major[1] * scale[1], major[0] * scale[0])
            minor = wp.cw_div(perp * (target / wp.length(perp)), scale)
        minor_len = target
    lod = wp.log2(minor_len)
    if lod <= 0.0:
        return ewa_level(tex, first, uv, major, minor, wrap)
    if lod >= float(last):
        return ewa_level(tex, first + last, uv, major, minor, wrap)
    lower = int(wp.floor(lod))
    f = lod - float(lower)
    return wp.lerp(ewa_level(tex, first + lower, uv, major, minor, wrap),
                   ewa_level(tex, first + lower + 1, uv, major, minor, wrap), f)


@wp.func
def sample_texture(tex: TexturesW, tex_id: int, uv: wp.vec2, duv_dx: wp.vec2, duv_dy: wp.vec2, filter: int,
                   wrap: int):
    """Texture `tex_id` at uv with the given filter and wrap mode; duv_dx, duv_dy are the screen-space
    derivatives of uv (per sample of the image being rendered). Returns linear RGB; (1, 1, 1) for
    tex_id < 0."""
    if tex_id < 0:
        return wp.vec3(1.0)
    first = tex.first_level[tex_id]
    if filter == NEAREST:
        return sample_nearest(tex, first, uv, wrap)
    if filter == BILINEAR:
        return sample_bilinear(tex, first, uv, wrap)
    if filter == EWA:
        return sample_ewa(tex, tex_id, uv, duv_dx, duv_dy, wrap)
    lod = texture_lod(tex, tex_id, duv_dx, duv_dy)
    if filter == MIPMAP:
        return sample_mipmap(tex, tex_id, uv, lod, wrap)
    return sample_trilinear(tex, tex_id, uv, lod, wrap)


@wp.kernel
def sample_texture_kernel(tex: TexturesW, tex_id: int, uv: wp.array(dtype=wp.vec2), duv_dx: wp.array(dtype=wp.vec2),
                          duv_dy: wp.array(dtype=wp.vec2), filter: int, wrap: int, out: wp.array(dtype=wp.vec3)):
    """`sample_texture` at many points (tests, experiments, the fit's checks)."""
    k = wp.tid()
    out[k] = sample_texture(tex, tex_id, uv[k], duv_dx[k], duv_dy[k], filter, wrap)
