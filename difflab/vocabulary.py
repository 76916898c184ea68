"""The names difflab's scene files, renderers, illumination models and command line share, with the
integer ids the Warp kernels and the JAX model switch on. Defined once here, without Warp or JAX:
scene validation takes its choices from these tables, `lighting.warp_model` and
`lighting.jax_model` their ids, the CLI its `choices`.

Each table maps a name (as written in a scene file) to its id; the order of the names is the order
in which they are documented and offered.
"""

from __future__ import annotations

# -- render methods, shading and specular models ---------------------------------------------------
METHODS = ("raster", "raytrace")
FLAT, GOURAUD, PHONG_SHADING = 0, 1, 2
SHADING_MODELS = {"flat": FLAT, "gouraud": GOURAUD, "phong": PHONG_SHADING}
PHONG, BLINN, TORRANCE = 0, 1, 2
SPECULAR_MODELS = {"phong": PHONG, "blinn": BLINN, "torrance": TORRANCE}
INTERPOLATIONS = ("perspective", "affine")
SAMPLINGS = ("grid", "stratified")
PROJECTIONS = ("perspective", "orthographic")

# -- lights and fog --------------------------------------------------------------------------------
POINT, DIRECTIONAL, SPOT = 0, 1, 2
LIGHT_TYPES = {"point": POINT, "directional": DIRECTIONAL, "spot": SPOT}
FOG_NONE, FOG_LINEAR, FOG_EXP, FOG_EXP2 = 0, 1, 2, 3
#: Fog modes of a scene's "fog" block; a scene without one renders with FOG_NONE.
FOG_MODES = {"linear": FOG_LINEAR, "exp": FOG_EXP, "exp2": FOG_EXP2}

# -- ray tracing -----------------------------------------------------------------------------------
FRESNEL_NONE, FRESNEL_SCHLICK, FRESNEL_EXACT = 0, 1, 2
FRESNEL_MODES = {"none": FRESNEL_NONE, "schlick": FRESNEL_SCHLICK, "exact": FRESNEL_EXACT}
#: Deepest ray tree a scene may ask for (render.max_depth, the primary ray counting as 1). The ray
#: tracer's stack of pending rays holds this many entries: a depth-first walk never holds more.
MAX_DEPTH_LIMIT = 64

# -- textures --------------------------------------------------------------------------------------
TEXTURE_FILTER_IDS = {"nearest": 0, "bilinear": 1, "mipmap": 2, "trilinear": 3, "ewa": 4}
TEXTURE_WRAP_IDS = {"repeat": 0, "clamp": 1, "mirror": 2}
TARGET_KA, TARGET_KD, TARGET_KS = 0, 1, 2
#: The coefficient an image texture modulates.
TEXTURE_TARGET_IDS = {"ka": TARGET_KA, "kd": TARGET_KD, "ks": TARGET_KS}

# -- limits ----------------------------------------------------------------------------------------
#: Most samples per pixel a scene may ask for (render.spp).
MAX_SPP = 4096
#: Below this N.H the Beckmann distribution exp(-tan^2/m^2) is ~0 and evaluating it would give 0/0;
#: both halves of the illumination model return 0 there.
BECKMANN_MIN_COS = 1.0e-3

# -- fractals (`difflab fractal KIND`) ---------------------------------------------------------------
#: Curves are drawn as figures, images are rendered.
FRACTAL_CURVES = ("koch", "peano", "hilbert", "cantor")
FRACTAL_IMAGES = ("terrain", "mandelbrot", "julia", "mandelbulb")
FRACTAL_KINDS = FRACTAL_CURVES + FRACTAL_IMAGES
#: The `difflab fractal` options each kind reads (beyond -o, --width, --height, --force); another
#: given is an error, as `difflab render` refuses the other renderer's flags.
FRACTAL_OPTIONS = {**{kind: ("order",) for kind in FRACTAL_CURVES}, "terrain": ("order", "seed", "hurst", "device"),
                   "mandelbrot": ("max_iter", "device"), "julia": ("max_iter", "device"), "mandelbulb": ("device",)}

__all__ = sorted(name for name in dir() if name.isupper())  # every table and id above
