"""A jaxsss :class:`~jaxsss.render.scene.Scene` as a Mitsuba 3 scene: a dict to render in-process, or XML + PLY.

Conventions matched (units: mm, so Mitsuba's unitless lengths are mm and its radiance is W/(mm^2 sr)):

- **Medium.** ``homogeneous`` inside the mesh (``interior``) with ``sigma_s = sigma_s' / (1 - g)``, an ``hg`` phase
  function of the same ``g`` (0 when the scene has none), ``albedo = sigma_s / sigma_t`` and ``sigma_t`` as an RGB
  ``sigma_t / max(sigma_t)`` times ``scale = max(sigma_t)`` (Mitsuba's ``rgb`` rejects values above 1).
- **Boundary.** ``null`` BSDF when ``eta = 1`` (index-matched), else ``dielectric`` with ``int_ior = eta`` and
  ``ext_ior = 1`` (eta is n_inside / n_outside); ``roughdielectric`` (GGX, ``alpha = specular_roughness``) when the
  material has a specular roughness. A smooth dielectric cannot be connected to a point, spot or directional light
  by a path tracer: such an export renders the object black in Mitsuba, and :func:`scene_dict` warns. It also
  warns for a mesh that is not watertight (the built-in teapot is not: 1616 open edges), whose medium is ill
  defined in a path tracer.
- **Integrator.** ``volpathmis``, unlimited depth (``max_depth = -1``); Russian roulette starts after
  :func:`rr_depth` bounces. Mitsuba keeps a path with probability ``min(max(throughput), 0.95)``: above a
  single-scattering albedo of 0.95 the roulette makes the weights of surviving paths grow, and above 0.975 its
  variance infinite, so for those media it starts only once the albedo alone has cut the throughput below
  :data:`RR_START_THROUGHPUT` (unbiased either way; a practical render with the early start comes out 2-3% dark at
  marble's albedo: :func:`rr_depth`).
- **Lights** (same units): ``point`` (``intensity`` W/sr), ``directional`` (``irradiance`` W/mm^2 on a surface facing
  it), ``spot`` (``intensity`` W/sr on the axis, ``cutoff_angle = cone_deg``, ``beam_width = cone_deg -
  falloff_deg``): both fall off linearly in angle between ``beam_width`` and ``cutoff_angle``
  (:func:`jaxsss.render.lights.spot_factor`; measured on Mitsuba's own emitter in tests/export).
  Area lights: a ``sphere`` (``center``, ``radius``) or ``rectangle`` shape (``to_world`` = ``look_at(position,
  position + direction, up)`` times ``scale(width/2, height/2, 1)``: the height runs along ``up``, the width along
  ``up x direction``, and it emits on the side ``direction`` points to, as jaxsss's) with an ``area`` emitter of
  the same ``radiance`` and a black ``diffuse`` BSDF. Differs: Mitsuba's emitting shapes are seen by the camera and
  block light; jaxsss's area lights are neither (keep them out of view and out of the way).
  Environment: a constant one is a ``constant`` emitter (``radiance``); a map is an ``envmap`` of
  ``environment.exr`` (the scene's ``scale`` multiplied in) with ``to_world`` = the map's rotation. jaxsss reads a
  lat-long map exactly as Mitsuba's ``envmap`` does (:mod:`jaxsss.render.environment`: +y up in the map's frame,
  ``u = 0`` towards -z, the same texel positions; checked against ``envmap.eval`` in tests/export).
- **Camera.** ``perspective`` with ``fov_axis = "y"`` (jaxsss's vertical field of view), ``to_world = look_at``
  (Mitsuba's image x runs along forward x up, as jaxsss's), ``hdrfilm`` of the same ``(W, H)`` with row 0 at the
  top, and a ``box`` reconstruction filter so each pixel averages exactly its own square (jaxsss's pixels). jaxsss
  at ``spp = 1`` samples the pixel centre only; Mitsuba averages over the pixel, so silhouette pixels differ by
  construction: compare on fully covered pixels (:mod:`jaxsss.export.compare`).
- **Occluders**: ``diffuse`` with ``reflectance = albedo``. Mitsuba computes all interreflections; jaxsss only the
  terms its plan keeps.
- **Mesh**: binary PLY (mm) with jaxsss's shading normals (:mod:`jaxsss.export.ply`).

**A bias of the references: the layer below the boundary.** Mitsuba (single precision) starts every ray that leaves
a surface :data:`RAY_EPSILON` ``(1 + max |p_i|)`` off it along the normal (``p`` in scene units, mm). A camera path
that crosses the null boundary into the medium therefore skips a layer of that thickness ``epsilon``; the shadow ray
from a scattering event to the light does not. The first order comes out ``exp(-sigma_t epsilon / mu_i)`` of its
exact value (``mu_i`` the light's cosine): measured, 0.99-1.02 of that at ``mu_i`` 0.1 and 1 with the scene at its
size and at a tenth of it (tests/export/test_exact.py), 0.97 at ``mu_i`` 0.05, and 0.91 with the scene ten times
larger (then 6% of the exact first order is left at ``mu_i`` 0.1). The bias is a property of the scene's optical
size, not of its units: :func:`skipped_layer` gives its optical depth. At the g = 0.9 references' scale (``sigma_t``
10.1 per mm, face 30 mm from the origin: 0.028) a uniformly lit face's radiance, every order, came out 12% / 6% / 0%
low at ``mu_i`` 0.1 / 0.15 / 0.25 against jaxsss's Monte Carlo, which adding-doubling confirms (docs/path_tracer.md,
"Mitsuba's skipped layer"). On a curved object the effect is far smaller, because the light at a grazing pixel
entered nearby at steeper cosines: the g = 0.9 sphere's reference moved to a 5.6 times thicker layer changed by at
most about 1% in any bin of the light's cosine. At the g = 0 references' scale (``sigma_t`` about 1 per mm) the
layer is ten times thinner.

Not representable, refused by :func:`jaxsss.export.support.check_exportable`: blockers, layer textures, material
textures, a non-black background. ``output.exposure`` is a display setting of jaxsss's sRGB
output and is not applied: Mitsuba's image is linear radiance.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
import warnings
from pathlib import Path
from typing import NamedTuple
from xml.sax.saxutils import quoteattr

import numpy as np

from jaxsss.export.ply import OBJECT_ID, write_meshes
from jaxsss.export.support import ENVIRONMENT_ID, check_exportable, medium_arrays, write_environment

__all__ = [
    "DEFAULT_SPP",
    "LookAt",
    "Matrix",
    "MitsubaRender",
    "RAY_EPSILON",
    "RR_DEPTH_MAX",
    "RR_START_THROUGHPUT",
    "RR_SURVIVAL_CAP",
    "load",
    "medium_dict",
    "object_coverage",
    "render_mitsuba",
    "rr_depth",
    "scene_dict",
    "scene_xml",
    "select_variant",
    "skipped_layer",
    "to_mitsuba_dict",
    "write_scene",
]

DEFAULT_SPP = 1024
"""Samples per pixel written into an exported scene (a final render; override with ``spp=``)."""

RR_SURVIVAL_CAP = 0.95
"""Mitsuba's Russian roulette keeps a path with probability ``min(max(throughput), 0.95)``."""
RR_START_THROUGHPUT = 1e-3
"""Above an albedo of ``sqrt(RR_SURVIVAL_CAP)`` the roulette starts once ``albedo^n`` is below this
(:func:`rr_depth`)."""
RR_DEPTH_MAX = 100_000_000
"""The latest start of the roulette (an albedo of 1: no absorption to end a path; it ends by leaving the object)."""

RAY_EPSILON = 1500.0 * 2.0**-24
"""Mitsuba's single-precision ``math::RayEpsilon``: rays leaving a surface at ``p`` start ``RAY_EPSILON (1 + max
|p_i|)`` off it (module docstring, "the layer below the boundary")."""


def skipped_layer(scene, points=None) -> np.ndarray:
    """The optical depth ``sigma_t epsilon`` of the layer below an index-matched boundary that Mitsuba's camera paths
    skip, ``epsilon = RAY_EPSILON (1 + max |p_i|)`` (mm): the path-traced first order is ``exp(-sigma_t epsilon /
    mu_i)`` of the exact one, and light entering at grazing cosines is under-counted (module docstring).

    Args:
        scene: a :class:`jaxsss.render.Scene`.
        points: ``(N, 3)`` surface points, mm; None: the largest over the object's vertices (an upper bound).

    Returns:
        ``(N, C)`` at ``points``, or ``(C,)``.
    """
    sigma_t = np.asarray(medium_arrays(scene.material.medium)["sigma_t"], dtype=np.float64)
    if points is None:
        return sigma_t * RAY_EPSILON * (1.0 + float(np.max(np.abs(np.asarray(scene.mesh.vertices)))))
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"skipped_layer(points=...) must be (N, 3) mm; got shape {p.shape}")
    return (RAY_EPSILON * (1.0 + np.max(np.abs(p), axis=1)))[:, None] * sigma_t


class LookAt(NamedTuple):
    """A ``to_world`` transform: Mitsuba's ``look_at(origin, target, up)`` (mm)."""

    origin: tuple
    target: tuple
    up: tuple


class Matrix(NamedTuple):
    """A ``to_world`` transform given as its ``(4, 4)`` matrix, row-major (16 numbers)."""

    values: tuple


def _matrix(linear: np.ndarray, translate=(0.0, 0.0, 0.0)) -> Matrix:
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = np.asarray(translate, dtype=np.float64)
    return Matrix(tuple(float(v) for v in m.ravel()))


def _vec(a) -> list[float]:
    return [float(v) for v in np.asarray(a, dtype=np.float64).reshape(3)]


def _rgb(a) -> dict:
    return {"type": "rgb", "value": _vec(np.broadcast_to(np.asarray(a, dtype=np.float64), (3,)))}


def rr_depth(albedo_max: float) -> int:
    """Bounces before Russian roulette starts: 5 (Mitsuba's default) up to an albedo of 0.95; up to ``sqrt(0.95)``
    (0.9747) the first ``n`` with ``albedo_max ** n < 0.95`` plus 5; above it the first ``n`` with ``albedo_max ** n <
    RR_START_THROUGHPUT`` plus 5, at most :data:`RR_DEPTH_MAX` (an albedo of 1: paths end only by leaving the object).

    Why: Mitsuba keeps a path with probability ``q = min(max(throughput), 0.95)`` and divides its throughput by ``q``.
    Above an albedo ``a`` of 0.95 a surviving path's throughput grows by ``a / 0.95`` per bounce and its second moment
    by ``a^2 / 0.95``: up to ``a = sqrt(0.95)`` the variance stays finite and the early start is the efficient one
    (skin1's red, 0.959: 1.009 and 0.967 per bounce); above it the variance is infinite. The estimator stays
    unbiased, but a render of practical length comes out dark, its missing light in rare fireflies. Measured on
    marble (``a`` = 0.99904 / 0.99844 / 0.99764) on a flat slab under a point light, ``scalar_rgb``, against
    Chandrasekhar's exact half-space reflection (docs/path_tracer.md, "Mitsuba's Russian roulette at high albedo"):
    with the roulette from ``a^n < 0.95``, 0.975 / 0.976 / 0.984 at 4096 spp (0.968 / 0.993 / 0.980 at 512); from
    ``a^n < 1e-3``, 1.005 / 1.005 / 1.005 +- 0.001 at 1024 spp. Starting there leaves to the roulette only the tail
    beyond a thousandth of the throughput.

    Args:
        albedo_max: the largest single-scattering albedo ``sigma_s / sigma_t`` over the channels, in ``[0, 1]``.
    """
    if not 0.0 <= albedo_max <= 1.0:
        raise ValueError(f"albedo_max={albedo_max!r} is outside the allowed range [0, 1]")
    if albedo_max <= RR_SURVIVAL_CAP:
        return 5
    if albedo_max >= 1.0:
        return RR_DEPTH_MAX
    # Throughput from absorption alone after n scatterings is albedo^n; the roulette's second moment grows by
    # albedo^2 / 0.95 per bounce once it runs.
    start = RR_SURVIVAL_CAP if albedo_max**2 <= RR_SURVIVAL_CAP else RR_START_THROUGHPUT
    return min(RR_DEPTH_MAX, 5 + math.ceil(math.log(start) / math.log(albedo_max)))


def _light(light, key: str, mesh_files: dict | None = None) -> dict:
    black = {"type": "diffuse", "reflectance": _rgb(0.0)}
    if light.kind == "sphere":
        return {"type": "sphere", "center": _vec(light.position), "radius": float(light.radius), "bsdf": black,
                "emitter": {"type": "area", "radiance": _rgb(light.intensity)}}
    if light.kind == "rectangle":
        n, e_v = np.asarray(light.direction, dtype=np.float64), np.asarray(light.up, dtype=np.float64)
        e_u = np.cross(e_v, n)  # look_at: x = up x dir, y = up, z = dir; the unit square [-1, 1]^2 scaled
        width, height = light.size
        linear = np.stack([e_u * width / 2.0, e_v * height / 2.0, n], axis=1)
        return {"type": "rectangle", "to_world": _matrix(linear, light.position), "bsdf": black,
                "emitter": {"type": "area", "radiance": _rgb(light.intensity)}}
    if light.kind == "environment":
        env = light.environment
        if env.path is None:  # a constant environment: its one texel times the scale
            return {"type": "constant", "radiance": _rgb(env.image[0, 0] * np.asarray(light.intensity))}
        return {"type": "envmap", "filename": (mesh_files or {})[ENVIRONMENT_ID], "to_world": _matrix(env.rotation)}
    if light.kind == "point":
        return {"type": "point", "position": _vec(light.position), "intensity": _rgb(light.intensity)}
    if light.kind == "directional":
        return {"type": "directional", "direction": _vec(light.direction), "irradiance": _rgb(light.intensity)}
    if light.kind == "spot":
        pos, axis = np.asarray(light.position, dtype=np.float64), np.asarray(light.direction, dtype=np.float64)
        up = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        return {
            "type": "spot",
            "to_world": LookAt(tuple(_vec(pos)), tuple(_vec(pos + axis)), tuple(_vec(up))),
            "intensity": _rgb(light.intensity),
            "cutoff_angle": float(light.cone_deg),
            "beam_width": float(light.cone_deg - light.falloff_deg),
        }
    raise ValueError(f"[{key}.type] {light.kind!r} cannot be exported; allowed: point, directional, spot, sphere, "
                     "rectangle, environment")


def _boundary(medium: dict, roughness) -> dict:
    eta = medium["eta"]
    if roughness is not None and eta != 1.0:
        return {"type": "roughdielectric", "distribution": "ggx", "alpha": float(roughness), "int_ior": eta,
                "ext_ior": 1.0}
    if eta == 1.0:
        return {"type": "null"}
    return {"type": "dielectric", "int_ior": eta, "ext_ior": 1.0}


def medium_dict(medium) -> dict:
    """The Mitsuba ``homogeneous`` medium (with its ``hg`` phase) of a :class:`jaxsss.Medium` (1/mm)."""
    m = medium_arrays(medium)
    sigma_t = m["sigma_t"]
    scale = float(sigma_t.max())
    if not scale > 0.0:
        raise ValueError(f"[material] sigma_t = sigma_a + sigma_s = {sigma_t.tolist()} 1/mm: allowed: some "
                         "channel > 0")
    # albedo = sigma_s / sigma_t per channel (0 where sigma_t = 0).
    albedo = np.divide(m["sigma_s"], sigma_t, out=np.zeros(3), where=sigma_t > 0)
    return {
        "type": "homogeneous",
        "albedo": _rgb(albedo),
        "sigma_t": _rgb(sigma_t / scale),
        "scale": scale,
        "phase": {"type": "hg", "g": m["g"]},
        "sample_emitters": True,
    }


def scene_dict(scene, mesh_files: dict[str, str], *, spp: int = DEFAULT_SPP, seed: int = 0,
               coverage: bool = False, max_depth: int = -1) -> dict:
    """The Mitsuba scene as a plain dict (``to_world`` values are :class:`LookAt`; see :func:`to_mitsuba_dict`).

    Args:
        scene: a jaxsss :class:`~jaxsss.render.scene.Scene`.
        mesh_files: PLY file per shape id (``"object"``, ``"occluder_0"``, ...) as written by :func:`write_meshes`,
            and the environment map's EXR as ``"environment"`` (:func:`jaxsss.export.support.write_environment`)
            when the scene has one.
        spp: samples per pixel, >= 1.
        seed: the sampler's seed, >= 0.
        coverage: instead of the lit scene, a mask render: the object is an area light of radiance 1 seen by a
            ``direct`` integrator, occluders black, no lights; each pixel is then the fraction of it covered by
            the object (box filter).
        max_depth: the integrator's longest path, -1 (unbounded) or >= 2. Crossings of an index-matched boundary
            (``null`` BSDF) do not count, so at ``eta = 1`` ``max_depth = 2`` is the light scattered exactly once
            inside the object (plus the occluders' direct light): the reference for
            :mod:`jaxsss.render.first_order` (tests/export, ``chicken1_sphere_first_order``). At a dielectric
            boundary each refraction counts as a bounce.

    Raises:
        ExportError: a key the export cannot represent (see :func:`jaxsss.export.support.check_exportable`).
    """
    check_exportable(scene, "mitsuba")
    if int(spp) < 1:
        raise ValueError(f"spp={spp!r} is outside the allowed range [1, inf)")
    if int(seed) < 0:
        raise ValueError(f"seed={seed!r} is outside the allowed range [0, inf)")
    if int(max_depth) != -1 and int(max_depth) < 2:
        raise ValueError(f"max_depth={max_depth!r} is outside the allowed values: -1 (unbounded) or [2, inf)")
    cam = scene.camera
    width, height = (int(v) for v in cam.resolution)
    extent = float(np.max(scene.mesh.extents))
    distance = float(np.linalg.norm(np.asarray(scene.mesh.centroid) - np.asarray(cam.position)))
    d: dict = {"type": "scene"}
    if coverage:
        d["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}
    else:
        m = medium_arrays(scene.material.medium)
        albedo = np.divide(m["sigma_s"], m["sigma_t"], out=np.zeros(3), where=m["sigma_t"] > 0)
        d["integrator"] = {"type": "volpathmis", "max_depth": int(max_depth),
                           "rr_depth": rr_depth(float(albedo.max())), "hide_emitters": False}
        if not scene.mesh.is_watertight:
            warnings.warn(f"mesh ({scene.mesh_description}) is not watertight: Mitsuba's medium lives between the "
                          "surface crossings of each path, so light leaks through the holes and the interior is ill "
                          "defined; repair the mesh (the scene's require_watertight = true checks it)", stacklevel=2)
        if m["eta"] != 1.0 and any(light.kind in ("point", "spot", "directional") for light in scene.lights):
            warnings.warn(f"material.eta = {m['eta']:g}: a path tracer cannot connect a smooth dielectric boundary "
                          "to a point, spot or directional light; Mitsuba will render the object's subsurface "
                          "light black (use eta = 1 or an area/environment light in Mitsuba)", stacklevel=2)
    d["sensor"] = {
        "type": "perspective",
        "fov": float(cam.fov_deg),
        "fov_axis": "y",
        "near_clip": max(1e-4, 1e-4 * distance),
        "far_clip": 10.0 * (distance + extent) + 1.0,
        "to_world": LookAt(tuple(_vec(cam.position)), tuple(_vec(cam.look_at)), tuple(_vec(cam.up))),
        "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb",
                 "component_format": "float32", "rfilter": {"type": "box"}},
    }
    if coverage:
        d[OBJECT_ID] = {"type": "ply", "filename": mesh_files[OBJECT_ID],
                        "bsdf": {"type": "diffuse", "reflectance": _rgb(0.0)},
                        "emitter": {"type": "area", "radiance": _rgb(1.0)}}
    else:
        d[OBJECT_ID] = {"type": "ply", "filename": mesh_files[OBJECT_ID],
                        "bsdf": _boundary(medium_arrays(scene.material.medium), scene.material.specular_roughness),
                        "interior": medium_dict(scene.material.medium)}
        for i, light in enumerate(scene.lights):
            d[f"light_{i}"] = _light(light, light.key or f"light[{i}]", mesh_files)
    for i, occ in enumerate(scene.occluders):
        d[f"occluder_{i}"] = {"type": "ply", "filename": mesh_files[f"occluder_{i}"],
                              "bsdf": {"type": "diffuse", "reflectance": _rgb(0.0 if coverage else occ.albedo)}}
    return d


def _write_files(scene, directory, *, relative: bool) -> dict[str, str]:
    """The PLY meshes and the environment map's EXR (if any) in ``directory``: file name per id."""
    files = write_meshes(scene, directory, relative=relative)
    env = write_environment(scene, directory, mapping="latlong")
    if env is not None:
        files[ENVIRONMENT_ID] = env if relative else str(Path(directory) / env)
    return files


# --- in-process ---------------------------------------------------------------------------------------------------
def select_variant(prefer=("llvm_ad_rgb", "scalar_rgb")) -> str:
    """Set and return the first usable Mitsuba variant of ``prefer``.

    An LLVM variant is tried only when ``DRJIT_LIBLLVM_PATH`` names an existing libLLVM (Dr.Jit crashes with some
    system LLVMs, e.g. Debian's 14 and 15; libLLVM 19 works), so the fallback ``scalar_rgb`` is always safe.
    """
    import mitsuba as mi

    for variant in prefer:
        if variant.startswith("llvm") and not Path(os.environ.get("DRJIT_LIBLLVM_PATH", "")).is_file():
            continue
        try:
            mi.set_variant(variant)
            return variant
        except Exception:  # noqa: BLE001 - an unavailable variant raises ImportError or AttributeError
            continue
    raise RuntimeError(f"none of the Mitsuba variants {list(prefer)} is usable (DRJIT_LIBLLVM_PATH="
                       f"{os.environ.get('DRJIT_LIBLLVM_PATH')!r})")


def to_mitsuba_dict(d):
    """Replace :class:`LookAt` values by ``mi.ScalarTransform4f`` (needs a variant set), recursively."""
    import mitsuba as mi

    if isinstance(d, LookAt):
        return mi.ScalarTransform4f().look_at(origin=list(d.origin), target=list(d.target), up=list(d.up))
    if isinstance(d, Matrix):
        return mi.ScalarTransform4f(np.asarray(d.values, dtype=np.float64).reshape(4, 4).tolist())
    if isinstance(d, dict):
        return {k: to_mitsuba_dict(v) for k, v in d.items()}
    return d


class MitsubaRender(NamedTuple):
    """A Mitsuba render: ``image`` ``(H, W, 3)`` float64 linear radiance W/(mm^2 sr); ``seconds`` of the render
    call (kernel compilation included for an LLVM variant's first render), ``load_seconds`` of scene loading."""

    image: np.ndarray
    seconds: float
    load_seconds: float
    variant: str
    spp: int
    seed: int


def load(scene, *, spp: int = DEFAULT_SPP, seed: int = 0, coverage: bool = False, max_depth: int = -1):
    """A loaded ``mi.Scene`` (the current variant; meshes go through a temporary directory; arguments as
    :func:`scene_dict`'s)."""
    import mitsuba as mi

    with tempfile.TemporaryDirectory(prefix="jaxsss_mitsuba_") as tmp:
        files = _write_files(scene, tmp, relative=False)
        return mi.load_dict(to_mitsuba_dict(scene_dict(scene, files, spp=spp, seed=seed, coverage=coverage,
                                                          max_depth=max_depth)))


def render_mitsuba(scene, *, spp: int, seed: int = 0, variant: str | None = None,
                   coverage: bool = False, max_depth: int = -1) -> MitsubaRender:
    """Render a jaxsss scene with Mitsuba 3 in-process.

    Args:
        scene: a jaxsss :class:`~jaxsss.render.scene.Scene`.
        spp: samples per pixel, >= 1.
        seed: sampler seed, >= 0.
        variant: a Mitsuba variant to set first (default: keep the current one, else :func:`select_variant`).
        coverage: render the object's coverage mask instead (see :func:`scene_dict`).
        max_depth: the longest path, -1 (unbounded) or >= 2 (2 at ``eta = 1``: single scattering; see
            :func:`scene_dict`).
    """
    import mitsuba as mi

    if variant is not None:
        mi.set_variant(variant)
    elif mi.variant() is None:
        select_variant()
    t0 = time.perf_counter()
    loaded = load(scene, spp=spp, seed=seed, coverage=coverage, max_depth=max_depth)
    load_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    image = np.array(mi.render(loaded, spp=int(spp), seed=int(seed)), dtype=np.float64)
    seconds = time.perf_counter() - t0
    return MitsubaRender(image[..., :3], seconds, load_seconds, mi.variant(), int(spp), int(seed))


def object_coverage(scene, *, spp: int = 256, seed: int = 0, variant: str | None = None) -> np.ndarray:
    """``(H, W)`` fraction of each pixel that Mitsuba's camera sees covered by the translucent object (in front of
    any occluder), from a ``spp``-sample box-filtered mask render."""
    return render_mitsuba(scene, spp=spp, seed=seed, variant=variant, coverage=True).image.mean(axis=-1)


# --- XML ----------------------------------------------------------------------------------------------------------
_TAG = {
    "null": "bsdf", "dielectric": "bsdf", "roughdielectric": "bsdf", "diffuse": "bsdf",
    "homogeneous": "medium", "hg": "phase",
    "point": "emitter", "directional": "emitter", "spot": "emitter", "area": "emitter", "envmap": "emitter",
    "constant": "emitter", "ply": "shape", "sphere": "shape", "rectangle": "shape", "perspective": "sensor", "hdrfilm": "film", "independent": "sampler", "box": "rfilter",
    "volpathmis": "integrator", "direct": "integrator",
}
_POINT_KEYS = {"position": "point", "direction": "vector", "center": "point"}


def _num(v: float) -> str:
    return repr(float(v))


def _xml_value(key: str, value, indent: str) -> list[str]:
    name = quoteattr(key)
    if isinstance(value, LookAt):
        lookat = " ".join(f'{k}="{", ".join(_num(x) for x in getattr(value, k))}"' for k in ("origin", "target", "up"))
        return [f"{indent}<transform name={name}>", f"{indent}    <lookat {lookat}/>", f"{indent}</transform>"]
    if isinstance(value, Matrix):
        return [f"{indent}<transform name={name}>",
                f'{indent}    <matrix value="{" ".join(_num(x) for x in value.values)}"/>', f"{indent}</transform>"]
    if isinstance(value, dict) and value.get("type") == "rgb":
        return [f'{indent}<rgb name={name} value="{", ".join(_num(x) for x in value["value"])}"/>']
    if isinstance(value, dict):
        return _xml_object(value, indent, name=key)
    if isinstance(value, bool):
        return [f'{indent}<boolean name={name} value="{str(value).lower()}"/>']
    if isinstance(value, int):
        return [f'{indent}<integer name={name} value="{value}"/>']
    if isinstance(value, float):
        return [f'{indent}<float name={name} value="{_num(value)}"/>']
    if isinstance(value, str):
        return [f"{indent}<string name={name} value={quoteattr(value)}/>"]
    if isinstance(value, list) and key in _POINT_KEYS:
        return [f'{indent}<{_POINT_KEYS[key]} name={name} value="{", ".join(_num(x) for x in value)}"/>']
    raise TypeError(f"no XML form for {key}={value!r}")


def _xml_object(obj: dict, indent: str, name: str | None = None, ident: str | None = None) -> list[str]:
    kind = obj["type"]
    tag = _TAG[kind]
    attrs = f' type="{kind}"'
    if ident is not None:
        attrs += f" id={quoteattr(ident)}"
    if tag == "medium" and name is not None:  # a shape's interior/exterior medium is named
        attrs += f" name={quoteattr(name)}"
    lines = [f"{indent}<{tag}{attrs}>"]
    for k, v in obj.items():
        if k != "type":
            lines += _xml_value(k, v, indent + "    ")
    return lines + [f"{indent}</{tag}>"]


def scene_xml(d: dict, comment: str = "") -> str:
    """Mitsuba 3 XML (``version="3.0.0"``) of a scene dict from :func:`scene_dict`."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>']
    if comment:
        lines.append("<!-- " + comment.replace("--", "- -") + " -->")
    lines.append('<scene version="3.0.0">')
    for k, v in d.items():
        if k != "type":
            lines += _xml_object(v, "    ", ident=k)
    return "\n".join(lines + ["</scene>", ""])


def write_scene(scene, out_dir, *, spp: int = DEFAULT_SPP, seed: int = 0, name: str = "scene") -> Path:
    """Write ``out_dir/<name>.xml`` and its PLY meshes (file names relative to the XML); return the XML path.

    Render it with ``mitsuba -m llvm_ad_rgb out_dir/scene.xml`` or ``mi.load_file``; the image is linear radiance
    in W/(mm^2 sr).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    check_exportable(scene, "mitsuba")
    files = _write_files(scene, out_dir, relative=True)
    d = scene_dict(scene, files, spp=spp, seed=seed)
    src = scene.path or "a jaxsss Scene"
    comment = (f"exported by jaxsss from {src}: lengths in mm, coefficients in 1/mm, radiance in W/(mm^2 sr); "
               f"material sigma_a={medium_arrays(scene.material.medium)['sigma_a'].tolist()} "
               f"sigma_s_prime={medium_arrays(scene.material.medium)['sigma_s_prime'].tolist()}")
    path = out_dir / f"{name}.xml"
    path.write_text(scene_xml(d, comment))
    return path
