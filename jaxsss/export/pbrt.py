"""A jaxsss :class:`~jaxsss.render.scene.Scene` as a pbrt-v4 scene (``.pbrt`` text + PLY meshes).

The material is pbrt-v4's ``subsurface`` (its photon-beam-diffusion BSSRDF, ``TabulatedBSSRDF``, tabulated for the
given ``g`` and ``eta``) with ``sigma_a`` and ``sigma_s`` given directly.

Units. pbrt-v4 has no intrinsic length unit: ``subsurface`` multiplies ``sigma_a`` and ``sigma_s`` by ``scale`` and
reads the products as per *scene unit* (its built-in named media, from Jensen et al. 2001, are tabulated in mm^-1, so
they are right as they stand only in a scene modelled in mm). This export writes everything in mm: the PLY
vertices, the camera and light positions, and ``sigma_a``, ``sigma_s = sigma_s' / (1 - g)`` in 1/mm with
``"float scale" [1]``. (Were the geometry rescaled to metres, ``scale`` would have to be 1000.)

Other conventions:

- ``Scale -1 1 1`` before ``LookAt``: pbrt's camera space is left-handed (image x along up x forward), jaxsss's image
  x runs along forward x up; the flip keeps the image unmirrored.
- ``fov`` is pbrt's field of view of the *shorter* image axis: ``fov_deg`` itself when ``W >= H``, else the
  horizontal field of view ``2 atan(tan(fov_deg / 2) W / H)``.
- ``Film "rgb"`` of the same ``(W, H)``, ``PixelFilter "box"`` (radius 0.5: each pixel averages its own square),
  ``Integrator "volpath"`` (which handles BSSRDFs).
- Lights: ``point`` (``I`` W/sr), ``distant`` (``L`` is the irradiance in W/mm^2 on a surface facing it), ``spot``
  (``coneangle = cone_deg``, ``conedelta = falloff_deg``; pbrt-v4's falloff is a smoothstep in cos(theta), jaxsss's
  linear in theta: they agree inside the beam, half way and outside the cone). pbrt-v4 divides an RGB light's
  spectrum by the luminance of its illuminant, so ``rgb I [1 1 1]`` renders as RGB 1 on its film.
- Area lights: ``AreaLightSource "diffuse"`` (``L`` = the radiance, one-sided) on a ``sphere`` (``Translate`` to its
  centre) or on a two-triangle ``trianglemesh`` whose per-vertex ``normal N`` is the light's ``direction`` (pbrt-v4
  turns the geometric normal to the shading normal, and a one-sided diffuse area light emits on that side), with a
  black ``diffuse`` material. As in Mitsuba, pbrt's emitting shapes are visible and block light; jaxsss's are not.
- Environment: a constant one is ``LightSource "infinite" "rgb L"``; a map is ``LightSource "infinite" "string
  filename" "environment.exr"``: pbrt-v4 reads only square equal-area octahedral maps, so the export resamples the
  lat-long map (jaxsss's bilinear lookup, its rotation and ``scale`` baked in) at the pixel centres of pbrt-v4's
  ``EqualAreaSquareToSphere`` (:func:`jaxsss.export.support.equal_area_directions`), in world coordinates (the light
  is declared with the identity transform after ``WorldBegin``). Not rendered here: pbrt-v4's normalisation of image
  lights by the illuminant is assumed to match that of its RGB ``L`` (RGB 1 renders as RGB 1).
- pbrt-v4 renders spectrally: RGB coefficients become smooth spectra (``RGBUnboundedSpectrum``), so colours are close
  to but not exactly those of an RGB renderer.
- Specular roughness: ``roughness = specular_roughness`` (GGX alpha) with ``remaproughness false``; none -> 0 (a
  smooth dielectric boundary, as in jaxsss without a highlight).
- Occluders: ``diffuse`` with ``reflectance = albedo``.

Refused (:func:`jaxsss.export.support.check_exportable`): blockers, layer textures, material textures, a non-black
background.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from jaxsss.export.ply import OBJECT_ID, write_meshes
from jaxsss.export.support import ENVIRONMENT_ID, check_exportable, medium_arrays, write_environment

__all__ = ["DEFAULT_SPP", "MAX_DEPTH", "pbrt_fov", "scene_text", "write_scene"]

DEFAULT_SPP = 1024
MAX_DEPTH = 100
"""``volpath`` maximum depth: every BSSRDF probe and subsurface exit counts as a bounce."""


def _nums(a) -> str:
    return " ".join(repr(float(v)) for v in np.asarray(a, dtype=np.float64).ravel())


def _rgb(name: str, a) -> str:
    return f'"rgb {name}" [ {_nums(np.broadcast_to(np.asarray(a, dtype=np.float64), (3,)))} ]'


def pbrt_fov(fov_deg: float, width: int, height: int) -> float:
    """pbrt's ``fov`` (degrees, of the shorter image axis) for a vertical field of view ``fov_deg``."""
    if width >= height:
        return float(fov_deg)
    # tan(fov_x / 2) = tan(fov_y / 2) * W / H for a pinhole with square pixels.
    return math.degrees(2.0 * math.atan(math.tan(math.radians(fov_deg) / 2.0) * width / height))


def _area_light(light) -> str:
    emit = f'  AreaLightSource "diffuse" {_rgb("L", light.intensity)}\n  Material "diffuse" {_rgb("reflectance", 0.0)}'
    if light.kind == "sphere":
        return (f"AttributeBegin\n  Translate {_nums(light.position)}\n{emit}\n"
                f'  Shape "sphere" "float radius" [ {float(light.radius)!r} ]\nAttributeEnd')
    n, e_v = np.asarray(light.direction, dtype=np.float64), np.asarray(light.up, dtype=np.float64)
    e_u = np.cross(e_v, n)
    half_w, half_h = (float(v) / 2.0 for v in light.size)
    c = np.asarray(light.position, dtype=np.float64)
    corners = [c + a * half_w * e_u + b * half_h * e_v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return (f"AttributeBegin\n{emit}\n"
            f'  Shape "trianglemesh" "integer indices" [ 0 1 2 0 2 3 ] "point3 P" [ {_nums(corners)} ] '
            f'"normal N" [ {_nums(np.tile(n, 4))} ]\nAttributeEnd')


def _light(light, mesh_files: dict | None = None) -> str:
    if light.kind in ("sphere", "rectangle"):
        return _area_light(light)
    if light.kind == "environment":
        env = light.environment
        if env.path is None:
            return f'LightSource "infinite" {_rgb("L", env.image[0, 0] * np.asarray(light.intensity))}'
        return f'LightSource "infinite" "string filename" [ "{(mesh_files or {})[ENVIRONMENT_ID]}" ]'
    if light.kind == "point":
        return f'LightSource "point" "point3 from" [ {_nums(light.position)} ] {_rgb("I", light.intensity)}'
    if light.kind == "directional":
        to = np.asarray(light.direction, dtype=np.float64)
        return f'LightSource "distant" "point3 from" [ 0 0 0 ] "point3 to" [ {_nums(to)} ] {_rgb("L", light.intensity)}'
    if light.kind == "spot":
        to = np.asarray(light.position, dtype=np.float64) + np.asarray(light.direction, dtype=np.float64)
        return (f'LightSource "spot" "point3 from" [ {_nums(light.position)} ] "point3 to" [ {_nums(to)} ] '
                f'"float coneangle" [ {light.cone_deg!r} ] "float conedelta" [ {light.falloff_deg!r} ] '
                f'{_rgb("I", light.intensity)}')
    raise ValueError(f"light type {light.kind!r} cannot be exported; allowed: point, directional, spot, sphere, "
                     "rectangle, environment")


def scene_text(scene, mesh_files: dict[str, str], *, spp: int = DEFAULT_SPP, image_name: str = "scene.exr") -> str:
    """The ``.pbrt`` text; ``mesh_files`` maps ``"object"``, ``"occluder_0"``, ... to PLY file names (and
    ``"environment"`` to the equal-area EXR of :func:`jaxsss.export.support.write_environment`, when there is a map).

    Raises:
        ExportError: a key the export cannot represent.
    """
    check_exportable(scene, "pbrt-v4")
    if int(spp) < 1:
        raise ValueError(f"spp={spp!r} is outside the allowed range [1, inf)")
    m = medium_arrays(scene.material.medium)
    cam = scene.camera
    width, height = (int(v) for v in cam.resolution)
    roughness = scene.material.specular_roughness
    lines = [
        f"# exported by jaxsss from {scene.path or 'a jaxsss Scene'}",
        "# units: lengths in mm; sigma_a, sigma_s in 1/mm (scale 1); radiance in W/(mm^2 sr)",
        f"# jaxsss material: sigma_a = {m['sigma_a'].tolist()} 1/mm, sigma_s' = {m['sigma_s_prime'].tolist()} 1/mm, "
        f"g = {m['g']!r}, eta = {m['eta']!r}",
        "Scale -1 1 1  # pbrt's camera space is left-handed; keeps jaxsss's image unmirrored",
        f"LookAt {_nums(cam.position)}  {_nums(cam.look_at)}  {_nums(cam.up)}",
        f'Camera "perspective" "float fov" [ {pbrt_fov(cam.fov_deg, width, height)!r} ]',
        f'Film "rgb" "integer xresolution" [ {width} ] "integer yresolution" [ {height} ] '
        f'"string filename" [ "{image_name}" ]',
        'PixelFilter "box"',
        f'Sampler "zsobol" "integer pixelsamples" [ {int(spp)} ]',
        f'Integrator "volpath" "integer maxdepth" [ {MAX_DEPTH} ]',
        "WorldBegin",
    ]
    for light in scene.lights:
        lines.append(_light(light, mesh_files))
    lines += [
        "AttributeBegin",
        f'  Material "subsurface" {_rgb("sigma_a", m["sigma_a"])} {_rgb("sigma_s", m["sigma_s"])} '
        f'"float g" [ {m["g"]!r} ] "float eta" [ {m["eta"]!r} ] "float scale" [ 1.0 ] '
        f'"float roughness" [ {0.0 if roughness is None else float(roughness)!r} ] "bool remaproughness" [ false ]',
        f'  Shape "plymesh" "string filename" [ "{mesh_files[OBJECT_ID]}" ]',
        "AttributeEnd",
    ]
    for i, occ in enumerate(scene.occluders):
        lines += [
            "AttributeBegin",
            f'  Material "diffuse" {_rgb("reflectance", occ.albedo)}',
            f'  Shape "plymesh" "string filename" [ "{mesh_files[f"occluder_{i}"]}" ]',
            "AttributeEnd",
        ]
    return "\n".join(lines) + "\n"


def write_scene(scene, out_dir, *, spp: int = DEFAULT_SPP, name: str = "scene") -> Path:
    """Write ``out_dir/<name>.pbrt`` and its PLY meshes (relative file names); return the ``.pbrt`` path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    check_exportable(scene, "pbrt-v4")
    files = write_meshes(scene, out_dir, relative=True)
    env = write_environment(scene, out_dir, mapping="equal_area")
    if env is not None:
        files[ENVIRONMENT_ID] = env
    path = out_dir / f"{name}.pbrt"
    path.write_text(scene_text(scene, files, spp=spp, image_name=f"{name}.exr"))
    return path
