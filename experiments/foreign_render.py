"""Foreign renderers for `foreign_targets.py`: a difflab scene written as a POV-Ray 3.7 scene file and
rendered by `povray`, and a sphere under a point light rendered by Mitsuba 3.

POV-Ray's classic finish (source/core/render/trace.cpp of POV-Ray 3.7) is, per light, with pigment
colour C, no `fade_distance` (attenuation 1; the fade below) and `brilliance` 1:

    C * ambient * ambient_light  +  sum_p  s_p I_p ( diffuse * C * (N.L_p)  +  phong * (R_V.L_p)^phong_size )
                                 +  reflection * I_reflected

where R_V is the view direction reflected about N (R_V.L = R_L.V: difflab's "phong" term), lights
with N.L < EPSILON are skipped (difflab gates its specular term at N.L <= 0 the same way), and
neither the highlight nor the reflection is tinted by C (no `metallic`). So a difflab material
maps exactly onto

    pigment { rgb kd }  finish { ambient rgb ka / kd  diffuse 1  phong ks  phong_size n  reflection kr }

with global `ambient_light` = the scene's ambient Ia and `max_trace_level` = max_depth, when ks is
grey (POV's highlight is the light's colour), kd > 0 in every channel, and every light is a point
light whose attenuation has kc > 0 and not both kl and kq > 0 (`pov_fade`: POV-Ray 3.7 multiplies
a light by 2 / (1 + (d / fade_distance)^fade_power), in Attenuate_Light, source/core/lighting/
lightsource.cpp: fade_power 1 and 2 are difflab's (kc, kl, 0) and (kc, 0, kq) with the light's colour
scaled by 1 / (2 kc); a pure 1 / d^2, kc = 0, has no POV-Ray 3.7 form). Blinn maps onto `specular ks roughness 1 / n` (POV's `specular` uses the
normalised half vector, no 1 / cos factors). Where the models do NOT coincide, on purpose: an
`area_light` (soft shadows, a highlight spread over the light's extent), `brilliance` b != 1
(diffuse (N.L)^b), `metallic`, `fresnel`, `conserve_energy`, POV's `fog`, anti-aliasing.

POV-Ray is left-handed (y up, the camera looking down +z), difflab right-handed (looking down -z):
every z is negated, which leaves the image as it is. The camera's `angle` is POV's horizontal
field of view, 2 atan(tan(fov_y / 2) width / height). POV samples pixel centres without `+A`, as
difflab does: its float render matches difflab's ray tracer to half-float precision away from edges.
"""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np

POV_FORMATS = {"png8": ("+FN8", "File_Gamma=sRGB"), "png16": ("+FN16", "File_Gamma=sRGB"),
               "png16lin": ("+FN16", "File_Gamma=1.0"), "exr": ("+FE",)}


def _vec(v, flip_z=True) -> str:
    x, y, z = (float(c) for c in v)
    return f"<{x:.9g}, {y:.9g}, {-z if flip_z else z:.9g}>"


def _rgb(v) -> str:
    return "rgb " + _vec(np.broadcast_to(np.asarray(v, float), (3,)), flip_z=False)


def pov_finish(material: dict, specular: str, extra: str = "") -> str:
    """The pigment and finish of one difflab material (the module docstring's mapping)."""
    kd = np.broadcast_to(np.asarray(material.get("kd", 0.8), float), (3,))
    ka = np.broadcast_to(np.asarray(material.get("ka", 0.0), float), (3,))
    ks = np.broadcast_to(np.asarray(material.get("ks", 0.0), float), (3,))
    if np.any(kd <= 0) or np.ptp(ks) > 0:
        raise ValueError(f"POV-Ray cannot express kd {kd.tolist()} / ks {ks.tolist()}: kd > 0 and a grey ks needed")
    n = float(material.get("n", 1.0))
    highlight = f"phong {ks[0]:.9g} phong_size {n:.9g}" if specular == "phong" else \
        f"specular {ks[0]:.9g} roughness {1.0 / n:.9g}"
    return (f"pigment {{ {_rgb(kd)} }} finish {{ ambient {_rgb(ka / kd)} diffuse 1 {highlight} "
            f"reflection {{ {float(material.get('kr', 0.0)):.9g} }} {extra} }}")


def pov_fade(attenuation) -> tuple[float, str]:
    """(colour scale, POV-Ray fade keywords) of a difflab point light's attenuation (kc, kl, kq).
    POV-Ray 3.7 multiplies a light's colour C by 2 / (1 + (d / fd)^p) (fade_distance fd, fade_power
    p): with C = I / (2 kc) that is I / (kc + kc (d / fd)^p), which is I / (kc + kl d) for p = 1,
    fd = kc / kl, and I / (kc + kq d^2) for p = 2, fd = sqrt(kc / kq); (kc, 0, 0) is the colour
    I / kc without a fade. ValueError for kc = 0 or both kl, kq > 0."""
    kc, kl, kq = (float(a) for a in attenuation)
    if kl == 0 and kq == 0 and kc > 0:
        return 1.0 / kc, ""
    if kc > 0 and (kl == 0) != (kq == 0):
        power, distance = (1, kc / kl) if kq == 0 else (2, math.sqrt(kc / kq))
        return 0.5 / kc, f"fade_distance {distance:.9g} fade_power {power}"
    raise ValueError(f"POV-Ray 3.7 has no fade for attenuation {list(attenuation)}: it needs kc > 0 and one of kl, kq")


def pov_scene(scene: dict, *, finish_extra: dict | None = None, light_extra: str = "") -> str:
    """POV-Ray 3.7 source for a difflab scene dict (spheres, planes, point lights). finish_extra:
    material name -> finish keywords added (e.g. "brilliance 3"); light_extra: added to every
    light_source (e.g. an area_light)."""
    cam, render = scene["camera"], scene.get("render", {})
    aspect = cam["width"] / cam["height"]
    fov_x = math.degrees(2.0 * math.atan(math.tan(math.radians(cam["fov_y"]) / 2.0) * aspect))
    lines = ["#version 3.7;",
             f"global_settings {{ assumed_gamma 1.0 ambient_light {_rgb(scene.get('ambient', 0.0))} "
             f"max_trace_level {int(render.get('max_depth', 5))} }}",
             f"camera {{ perspective location {_vec(cam['eye'])} look_at {_vec(cam['target'])} "
             f"sky {_vec(cam.get('up', [0, 1, 0]))} right x * {aspect:.9g} up y angle {fov_x:.9g} }}",
             f"background {{ {_rgb(scene.get('background', 0.0))} }}"]
    for light in scene["lights"]:
        if light["type"] != "point":
            raise ValueError(f"POV-Ray: only point lights are mapped, got {light}")
        scale, fade = pov_fade(light.get("attenuation", [1, 0, 0]))
        colour = np.asarray(light.get("intensity", 1.0), float) * scale
        lines.append(f"light_source {{ {_vec(light['position'])} color {_rgb(colour)} {fade} {light_extra} }}")
    specular = render.get("specular", "phong")
    finishes = {name: pov_finish(m, specular, (finish_extra or {}).get(name, ""))
                for name, m in scene["materials"].items()}
    for obj in scene["objects"]:
        if obj["type"] == "sphere":
            lines.append(f"sphere {{ {_vec(obj['center'])}, {obj['radius']:.9g} {finishes[obj['material']]} }}")
        elif obj["type"] == "plane":
            normal = np.asarray(obj["normal"], float) / np.linalg.norm(obj["normal"])
            offset = float(np.dot(normal, obj.get("point", [0, 0, 0])))
            lines.append(f"plane {{ {_vec(normal)}, {offset:.9g} {finishes[obj['material']]} }}")
        else:
            raise ValueError(f"POV-Ray: object type {obj['type']!r} is not mapped")
    return "\n".join(lines) + "\n"


def render_pov(source: str, out: Path, width: int, height: int, fmt: str, options=()) -> Path:
    """Render POV-Ray source to `out` (fmt: "png8" 8-bit sRGB, "png16" 16-bit sRGB, "png16lin" 16-bit
    linear (a gAMA chunk of 1.0), "exr" half float), without anti-aliasing unless `options` (more
    command-line switches, e.g. ("+A0.1", "+R3")) say; raises RuntimeError with POV-Ray's message
    when it fails."""
    if shutil.which("povray") is None:
        raise RuntimeError("povray is not installed (apt-get install povray)")
    pov = out.with_suffix(".pov")
    pov.write_text(source)
    cmd = ["povray", f"+I{pov}", f"+O{out}", f"+W{width}", f"+H{height}", "-D", "-V", "+WT1", *POV_FORMATS[fmt],
           *options]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=out.parent)
    if done.returncode != 0 or not out.exists():
        raise RuntimeError(f"povray failed ({done.returncode}): {done.stderr[-500:]}")
    return out


def mitsuba_module():
    """Mitsuba 3 in its scalar RGB variant, or None when it is not installed."""
    try:
        import mitsuba as mi
    except ImportError:
        return None
    mi.set_variant("scalar_rgb")
    return mi


def mitsuba_dict(scene: dict, bsdf: dict, spp: int, seed: int) -> dict:
    """Mitsuba's scene for a difflab scene dict holding one sphere and one point light with
    attenuation (0, 0, 1): radiant intensity I = the light's intensity (Mitsuba's diffuse BSDF is
    reflectance / pi: difflab's kd = reflectance / pi), direct illumination, box-filtered pixels."""
    cam, light = scene["camera"], scene["lights"][0]
    sphere = next(o for o in scene["objects"] if o["type"] == "sphere")
    if list(light.get("attenuation", [1, 0, 0])) != [0, 0, 1]:
        raise ValueError("Mitsuba's point light falls off as 1 / d^2: give the difflab light attenuation [0, 0, 1]")
    return {"type": "scene", "integrator": {"type": "direct"},
            "sensor": {"type": "perspective", "fov": cam["fov_y"], "fov_axis": "y",
                       "look_at": {"origin": cam["eye"], "target": cam["target"], "up": cam.get("up", [0, 1, 0])},
                       "film": {"type": "hdrfilm", "width": cam["width"], "height": cam["height"],
                                "pixel_format": "rgb", "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
            "light": {"type": "point", "position": light["position"],
                      "intensity": {"type": "rgb", "value": light["intensity"]}},
            "sphere": {"type": "sphere", "center": sphere["center"], "radius": sphere["radius"], "bsdf": bsdf}}


def render_mitsuba(mi, description: dict) -> np.ndarray:
    """Render a `mitsuba_dict` (its look_at written as Mitsuba's transform): linear float32 (H, W, 3)."""
    d = {**description, "sensor": dict(description["sensor"])}
    look = d["sensor"].pop("look_at")
    d["sensor"]["to_world"] = mi.ScalarTransform4f().look_at(**look)
    return np.asarray(mi.render(mi.load_dict(d)), np.float32)[..., :3]


def write_mitsuba(mi, image: np.ndarray, out: Path, fmt: str) -> Path:
    """Write a linear image with Mitsuba's own writers: "png8" (8-bit sRGB, clipped), "png16"
    (16-bit sRGB) or "exr" (float32)."""
    bitmap = mi.Bitmap(np.ascontiguousarray(image, np.float32))
    if fmt == "exr":
        bitmap.write(str(out))
        return out
    component = mi.Struct.Type.UInt8 if fmt == "png8" else mi.Struct.Type.UInt16
    bitmap.convert(mi.Bitmap.PixelFormat.RGB, component, srgb_gamma=True).write(str(out))
    return out


def read_exr(path: Path) -> np.ndarray | None:
    """A float EXR as linear float32 (H, W, 3) through Mitsuba's reader (difflab reads no EXR), or
    None without Mitsuba."""
    mi = mitsuba_module()
    return None if mi is None else np.asarray(mi.Bitmap(str(path)), np.float32)[..., :3]
