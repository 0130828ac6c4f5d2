"""Photons leaving the scene's lights towards the translucent object (photon diffusion, Section 5; NumPy).

Each light sends its photons only towards the object's bounding sphere, so none are wasted, and each photon carries
an equal share of the flux the light sends into that sphere:

- a **directional** light (irradiance ``E`` on a surface facing it, W/mm^2) starts photons on a disc of the sphere's
  radius ``R`` across the beam, stratified (a jittered grid in the unit square mapped to the disc by the concentric
  map): power ``E pi R^2 / n`` each, cross-section ``pi R^2 / n`` (mm^2);
- a **point** or **spot** light (radiant intensity ``I``, W/sr) samples directions uniformly in the cone that holds
  the sphere (solid angle ``Omega = 2 pi (1 - cos theta_max)``; the whole sphere of directions if the light is inside
  it), or in a spot's own cone where that is narrower: power ``I Omega / n`` each, times the spot's angular factor,
  and solid angle ``Omega / n`` (sr).

- an **environment** (radiance ``L(w)`` from every direction) draws each photon's direction from the map's
  luminance distribution (:meth:`jaxsss.render.environment.EnvironmentMap.sample`) and its start on the disc of
  radius ``R`` across it (stratified): power ``L(w) / p(w) pi R^2 / n``, cross-section ``pi R^2 / n``. Its flux into
  the sphere is ``pi R^2 int L dw`` (the map's texels times their solid angles).

The photons of all lights are split in proportion to each light's channel-mean flux into the sphere.

The *area* a photon stands for on the surface (its cross-section over the cosine at the hit, or its solid angle times
distance squared over the cosine) is what the source octree uses for the solid-angle criterion, as the sample areas
are for the irradiance samples (:mod:`jaxsss.photon.tree`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from jaxsss.validate import check_integer
from jaxsss.render.lights import spot_factor

__all__ = ["PhotonRays", "emit_photons"]


class PhotonRays(NamedTuple):
    """``P`` photons leaving the lights.

    Attributes:
        origin: ``(P, 3)`` start points, mm (outside the object's bounding sphere for directional lights).
        direction: ``(P, 3)`` unit directions of travel.
        power: ``(P, C)`` flux each photon carries, W.
        spread: ``(P,)`` cross-section (mm^2, directional) or solid angle (sr, point and spot) of each photon.
        solid_angle: ``(P,)`` bool, True where ``spread`` is a solid angle (the area at a hit is then
            ``spread t^2 / cos``).
        light: ``(P,)`` int index of the light that sent it.
    """

    origin: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    spread: np.ndarray
    solid_angle: np.ndarray
    light: np.ndarray


def _frame(axis: np.ndarray):
    """Two unit vectors perpendicular to the unit ``axis`` and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _frames(axes: np.ndarray):
    """Per-row :func:`_frame` of ``(n, 3)`` unit axes."""
    helper = np.where(np.abs(axes[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    u = np.cross(axes, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axes, u)


def _jittered_square(n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 2)`` stratified points in the unit square: a jittered ``k x k`` grid (``k^2 >= n``), shuffled, first n."""
    k = max(1, math.ceil(math.sqrt(n)))
    ij = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
    pts = (ij + rng.random(ij.shape)) / k
    return pts[rng.permutation(len(pts))[:n]]


def _concentric_disc(u: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of the unit square to the unit disc (area preserving, low distortion)."""
    a, b = 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 1] - 1.0
    first = np.abs(a) > np.abs(b)
    r = np.where(first, a, b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    phi = np.where(first, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def _cone(light, centre: np.ndarray, radius: float):
    """``(axis, cos_max)``: the cone of directions a point or spot light samples -- the one holding the sphere, or
    a spot's own cone where that is narrower (its photons outside the sphere then miss)."""
    to_c = centre - np.asarray(light.position, dtype=np.float64)
    dist = float(np.linalg.norm(to_c))
    axis = to_c / dist if dist > 0 else np.array([0.0, 0.0, 1.0])
    cos_max = -1.0 if dist <= radius else math.sqrt(max(0.0, 1.0 - (radius / dist) ** 2))
    if light.kind == "spot":
        cos_spot = math.cos(math.radians(light.cone_deg))
        if cos_spot > cos_max:
            return np.asarray(light.direction, dtype=np.float64), cos_spot
    return axis, cos_max


def _light_flux(light, centre: np.ndarray, radius: float):
    """``(C,)`` flux (W) one light sends into its sampling cone or disc (an upper bound for spot lights, whose angular
    factor is applied per photon)."""
    intensity = np.asarray(light.intensity, dtype=np.float64)
    if light.kind == "directional":
        return intensity * math.pi * radius * radius
    if light.kind == "environment":
        env = light.environment
        h, w = env.shape
        # Flux through a disc of radius R from every direction: pi R^2 int L dw (texel radiance times solid angle).
        edges = np.cos(np.pi * np.arange(h + 1) / h)
        omega = (2.0 * np.pi / w) * (edges[:-1] - edges[1:])
        return intensity * math.pi * radius * radius * np.einsum("ijc,i->c", env.image, omega)
    _, cos_max = _cone(light, centre, radius)
    return intensity * 2.0 * math.pi * (1.0 - cos_max)


def _emit_one(light, n: int, centre, radius, rng):
    intensity = np.asarray(light.intensity, dtype=np.float64)
    if light.kind == "directional":
        d = np.asarray(light.direction, dtype=np.float64)
        u, v = _frame(d)
        disc = _concentric_disc(_jittered_square(n, rng)) * radius
        origin = centre - 2.0 * radius * d + disc[:, :1] * u + disc[:, 1:] * v
        area = math.pi * radius * radius / n
        power = np.broadcast_to(intensity * area, (n, intensity.size))
        return origin, np.broadcast_to(d, (n, 3)), power, np.full(n, area), False
    if light.kind == "environment":
        # Direction towards the sky w from the map's distribution; the photon travels along -w from a disc across it.
        w_dir, pdf = light.environment.sample(np.concatenate([_jittered_square(n, rng), rng.random((n, 1))], axis=1))
        d = -w_dir
        u, v = _frames(d)
        disc = _concentric_disc(_jittered_square(n, rng)[rng.permutation(n)]) * radius
        origin = centre - 2.0 * radius * d + disc[:, :1] * u + disc[:, 1:] * v
        area = math.pi * radius * radius / n
        power = light.environment.radiance(w_dir) * intensity / pdf[:, None] * area
        return origin, d, power, np.full(n, area), False
    pos = np.asarray(light.position, dtype=np.float64)
    axis, cos_max = _cone(light, centre, radius)
    u, v = _frame(axis)
    sq = _jittered_square(n, rng)
    # Uniform directions in the cone: cos theta uniform in [cos_max, 1].
    cos_t = 1.0 - sq[:, 0] * (1.0 - cos_max)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * sq[:, 1]
    d = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    omega = 2.0 * math.pi * (1.0 - cos_max) / n
    factor = np.ones(n)
    if light.kind == "spot":
        factor = spot_factor(d @ np.asarray(light.direction, dtype=np.float64), light.cone_deg, light.falloff_deg)
    power = intensity[None, :] * omega * factor[:, None]
    return np.broadcast_to(pos, (n, 3)), d, power, np.full(n, omega), True


def emit_photons(lights: Sequence, centre, radius: float, n_photons: int, *, seed: int = 0) -> PhotonRays:
    """Photons from every light towards the sphere ``(centre, radius)`` that holds the object.

    Args:
        lights: the scene's lights (:class:`jaxsss.render.scene.Light`).
        centre: ``(3,)`` centre of the object's bounding sphere, mm.
        radius: its radius, mm, ``> 0``.
        n_photons: photons in total, ``>= 1`` (split over the lights by their flux into the sphere; a light with
            any flux gets at least one).
        seed: NumPy random seed.

    Returns:
        :class:`PhotonRays`; their powers sum to each light's flux into the sphere (the spot factor included).
    """
    check_integer(n_photons, "n_photons", 1, owner="emit_photons")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"emit_photons(radius={radius!r}) is outside the allowed range (0, inf) mm")
    if not lights:
        raise ValueError("emit_photons(lights=()) needs at least one light")
    centre = np.asarray(centre, dtype=np.float64)
    rng = np.random.default_rng(seed)
    flux = np.array([float(np.mean(_light_flux(light, centre, radius))) for light in lights])
    if not (flux.sum() > 0):
        raise ValueError("emit_photons(lights=...): no light sends any flux towards the object")
    share = flux / flux.sum()
    counts = np.where(flux > 0, np.maximum(1, np.floor(share * n_photons).astype(np.int64)), 0)
    counts[int(np.argmax(flux))] += max(0, n_photons - int(counts.sum()))
    parts = []
    for k, (light, n) in enumerate(zip(lights, counts, strict=True)):
        if n == 0:
            continue
        origin, d, power, spread, solid = _emit_one(light, int(n), centre, radius, rng)
        parts.append((origin, d, power, spread, np.full(int(n), solid), np.full(int(n), k)))
    cat = [np.ascontiguousarray(np.concatenate([p[i] for p in parts])) for i in range(6)]
    return PhotonRays(*cat)
