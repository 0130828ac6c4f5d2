"""Exact transport references that need no path tracer: a point-lit flat face of an isotropic half-space.

An isotropically scattering (``g = 0``), index-matched (``eta = 1``) half-space reflects every scattering order
exactly as Chandrasekhar's ``f_r(mu_i, mu_o) = a H(mu_i) H(mu_o) / (4 pi (mu_i + mu_o))``
(:func:`jaxsss.render.bssrdf.half_space_reflection`). A flat face of a deep object, lit by a point light whose
irradiance ``E = I mu_i / r^2`` changes little over a diffusion length, reflects ``L = E f_r`` away from its edges
(to second order in ``l_d`` over the light's distance at normal incidence; oblique light leaves ahead of its
entry, about 1.1 transport lengths at ``mu_i = 0.1``, which makes the error first order: 1% in skin1's red with the
light 400 mm away at ``mu_i`` 0.12, where ``E`` falls by 0.74% per mm). :func:`point_lit_face` gives that radiance
per pixel: a reference for a whole pipeline -- the renderer's sampling, kernels and exit, or an exported scene in a
path tracer -- that neither computed.

Measured with it (docs/path_tracer.md, "Mitsuba's Russian roulette at high albedo"; a 200 x 200 x 60 mm slab, light
130 mm above the face at 90 mm to the side, pixels at least 40 mm from the edges):

- jaxsss (hierarchical, ``auto``): 0.998 / 0.999 / 0.997 of it for skin1, 0.998 / 0.998 / 0.998 for marble; for
  skin1 at grazing light from far away (``mu_i`` 0.124, uniform; the camera on the far side of the light's flow, where
  the plan keeps the exit's current and the oblique azimuth) 1.002 / 0.997 / 0.991 (stop 49).
- Mitsuba ``volpathmis`` (``scalar_rgb``): 1.007 / 0.998 / 0.995 for skin1 at 64 spp; for marble (albedo 0.999)
  0.975 / 0.976 / 0.984 at 4096 spp with Russian roulette from the fifty-seventh bounce, and 1.005 +- 0.001 with it
  from :func:`jaxsss.export.mitsuba.rr_depth`'s later start (1024 spp).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

__all__ = ["FaceReference", "point_lit_face", "single_scattering_face"]


class FaceReference(NamedTuple):
    """The exact radiance of a point-lit flat face (:func:`point_lit_face`).

    Attributes:
        image: ``(H, W, 3)`` radiance, W/(mm^2 sr); NaN off ``mask``.
        mask: ``(H, W)`` bool: the pixel centre's first hit is on the face, at least ``margin`` mm inside its edges.
        mu_i: ``(H, W)`` cosine of the light's direction to the face's normal (NaN off ``mask``).
    """

    image: np.ndarray
    mask: np.ndarray
    mu_i: np.ndarray


def _refuse(key: str, value, allowed: str):
    raise ValueError(f"{key}={value!r} is not supported by the exact half-space reference; allowed: {allowed}")


class _Face(NamedTuple):
    """The camera's pixels on the flat face it looks at (:func:`_face_pixels`)."""

    shape: tuple
    on: np.ndarray  # (P,) bool
    position: np.ndarray  # (P, 3) mm
    normal: np.ndarray  # (3,)
    view: np.ndarray  # (P, 3) unit direction of the camera ray (towards the face)


def _face_pixels(scene, margin: float) -> _Face:
    """The pixels whose centre's first hit lies on the face hit at the image centre, at least ``margin`` mm inside
    its edges (the bounding rectangle of the mesh's vertices on its plane: exact for the ``slab`` and ``box``
    built-ins, whose faces are rectangles)."""
    from jaxsss.render.camera import camera_rays
    from jaxsss.render.rays import scene_geometry

    if not margin > 0.0:
        raise ValueError(f"margin={margin!r} is outside the allowed range (0, inf) mm")
    if scene.occluders:
        _refuse("occluder", len(scene.occluders), "none")
    if scene.material.texture is not None:
        _refuse("material.texture", scene.material.texture_path, "none")
    geometry = scene_geometry(scene.mesh, [])
    rays = camera_rays(dataclasses.replace(scene.camera, spp=1))
    hits = geometry.first_hit(rays.origins, rays.directions)
    h, w = rays.shape
    normals = np.asarray(scene.mesh.face_normals)
    centre = (h // 2) * w + w // 2
    if not hits.hit[centre]:
        raise ValueError("camera: the image centre's ray misses the object; aim it at the face to compare")
    n = normals[hits.face[centre]]
    offset = float(n @ hits.position[centre])
    on = hits.hit & (np.einsum("ij,j->i", normals[np.maximum(hits.face, 0)], n) > 1.0 - 1e-9)
    on &= np.abs(np.nan_to_num(hits.position) @ n - offset) < 1e-6 * (1.0 + abs(offset))
    # The face's frame (u, v) and its extent: the vertices on its plane.
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    verts = np.asarray(scene.mesh.vertices)
    plane = verts[np.abs(verts @ n - offset) < 1e-6 * (1.0 + abs(offset))]
    lo = np.array([(plane @ u).min(), (plane @ v).min()]) + margin
    hi = np.array([(plane @ u).max(), (plane @ v).max()]) - margin
    p = np.nan_to_num(hits.position)
    uv = np.stack([p @ u, p @ v], axis=1)
    on &= np.all((uv >= lo) & (uv <= hi), axis=1)
    d = np.asarray(rays.directions, dtype=np.float64)
    return _Face((h, w), on, p, n, d / np.linalg.norm(d, axis=1, keepdims=True))


def _light_at(light, p):
    """``(unit direction to the light (P, 3), irradiance on a surface facing it (P, C) W/mm^2)`` of a point or
    directional light at points ``p`` ``(P, 3)``."""
    intensity = np.atleast_1d(np.asarray(light.intensity, dtype=np.float64))
    if light.kind == "directional":
        d = -np.asarray(light.direction, dtype=np.float64)
        return np.broadcast_to(d / np.linalg.norm(d), p.shape), np.broadcast_to(intensity, (len(p), intensity.size))
    to_light = np.asarray(light.position, dtype=np.float64) - p
    r2 = np.sum(to_light**2, axis=1)
    return to_light / np.sqrt(r2)[:, None], intensity[None, :] / r2[:, None]


class _LitFace(NamedTuple):
    """A face's pixels lit by the scene's one light (:func:`_lit_face`); ``(P,)`` arrays unless noted."""

    shape: tuple
    on: np.ndarray  # bool: on the face, lit and seen
    mu_i: np.ndarray
    mu_o: np.ndarray
    scatter_cos: np.ndarray  # cosine of the scattering angle, light's travel to the view (jaxsss.phase)
    irradiance: np.ndarray  # (P, C) W/mm^2 on a surface facing the light
    albedo: np.ndarray  # (C,) single-scattering albedo sigma_s / sigma_t
    g: float


def _lit_face(scene, margin: float, light_kinds: tuple, isotropic: bool) -> _LitFace:
    """Check the scene (``eta = 1``, one light of ``light_kinds``, ``g = 0`` when ``isotropic``; ValueError naming
    the key) and light the pixels of :func:`_face_pixels`."""
    from jaxsss.export.support import medium_arrays

    m = medium_arrays(scene.material.medium)
    if m["eta"] != 1.0:
        _refuse("material.eta", m["eta"], "1 (index-matched)")
    if isotropic and m["g"] != 0.0:
        _refuse("material.g", m["g"], "0 or none (isotropic scattering)")
    if len(scene.lights) != 1 or scene.lights[0].kind not in light_kinds:
        _refuse("light", [light.kind for light in scene.lights],
                f"exactly one {' or '.join(light_kinds)} light")
    face = _face_pixels(scene, margin)
    to_light, e = _light_at(scene.lights[0], face.position)
    mu_i, mu_o = to_light @ face.normal, -(face.view @ face.normal)
    on = face.on & (mu_i > 0.0) & (mu_o > 0.0)
    albedo = m["sigma_s"] / np.where(m["sigma_t"] > 0.0, m["sigma_t"], 1.0)
    return _LitFace(face.shape, on, mu_i, mu_o, np.einsum("ij,ij->i", to_light, face.view), e, albedo, float(m["g"]))


def _reference(image, lit: _LitFace) -> FaceReference:
    """``image`` ``(P, C)`` as a :class:`FaceReference` (NaN off the lit face)."""
    h, w = lit.shape
    image = np.where(lit.on[:, None], image, np.nan)
    return FaceReference(image.reshape(h, w, -1), lit.on.reshape(h, w),
                         np.where(lit.on, lit.mu_i, np.nan).reshape(h, w))


def point_lit_face(scene, margin: float) -> FaceReference:
    """Per-pixel exact radiance of the flat face the camera looks at (pixel centres), ``L = E f_r``.

    The face is the plane of the facet hit at the image centre; its extent is the bounding rectangle of the mesh's
    vertices on that plane (exact for the ``slab`` and ``box`` built-ins, whose faces are rectangles).

    Args:
        scene: a :class:`jaxsss.render.Scene` with ``eta = 1``, ``g`` of 0 or none, one ``point`` light, no
            occluders and no texture (ValueError otherwise, naming the key).
        margin: mm, > 0: pixels closer than this to the face's edges are left out (some diffusion lengths: the
            half-space has no edges).
    """
    from jaxsss.render.bssrdf import half_space_reflection

    lit = _lit_face(scene, margin, ("point",), isotropic=True)
    mu_i, mu_o = np.where(lit.on, lit.mu_i, 1.0), np.where(lit.on, lit.mu_o, 1.0)
    f_r = np.asarray(half_space_reflection(mu_i[:, None], mu_o[:, None], lit.albedo[None, :]))
    # L = E f_r with the point light's irradiance on the face E = (I / r^2) mu_i.
    return _reference(lit.irradiance * mu_i[:, None] * f_r, lit)


def single_scattering_face(scene, margin: float) -> FaceReference:
    """Per-pixel exact *first-order* radiance of the flat face the camera looks at (pixel centres), any ``g``:

        L_1 = (sigma_s / sigma_t) p(cos theta) E mu_i / (mu_i + mu_o)

    (Hanrahan and Krueger 1993's single scattering of a half-space at ``eta = 1``; ``E`` the light's irradiance on a
    surface facing it, ``p`` the Henyey-Greenstein phase function per steradian, ``theta`` between the light's
    direction of travel and the view's reversed). Exact for a uniformly lit face (a directional light); for a point
    light to the same order as :func:`point_lit_face`. Its path-traced counterpart is Mitsuba at ``max_depth = 2``.

    Args:
        scene: a :class:`jaxsss.render.Scene` with ``eta = 1``, one ``point`` or ``directional`` light, no occluders
            and no texture (ValueError otherwise, naming the key).
        margin: mm, > 0: pixels closer than this to the face's edges are left out.
    """
    from jaxsss.phase import hg_phase

    lit = _lit_face(scene, margin, ("point", "directional"), isotropic=False)
    phase = np.asarray(hg_phase(lit.scatter_cos, lit.g))
    # L_1 = a p E mu_i / (mu_i + mu_o).
    return _reference(lit.albedo[None, :] * lit.irradiance
                      * (phase * lit.mu_i / np.where(lit.on, lit.mu_i + lit.mu_o, 1.0))[:, None], lit)
