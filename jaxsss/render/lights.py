"""Direct irradiance from the scene's lights at surface points (NumPy), with optional shadow rays.

Light kinds (:class:`jaxsss.render.scene.Light`) and units (positions in mm):

- ``point``, ``spot``: ``intensity`` is radiant intensity, W/sr (inverse-square law);
- ``directional``: ``intensity`` is the irradiance in W/mm^2 on a surface facing it;
- ``sphere``, ``rectangle`` (area lights): ``intensity`` is the emitted radiance, W/(mm^2 sr), uniform over the
  surface (a rectangle emits from its front side, the side ``direction`` points to); sampled per surface point with
  ``light.samples`` shadow rays: a sphere uniformly in the solid angle it subtends, a rectangle uniformly in area;
- ``environment``: the radiance of an :class:`~jaxsss.render.environment.EnvironmentMap` (times ``intensity``, the
  scene's ``scale``), sampled with ``light.samples`` directions per point: half drawn from the map's luminance
  (importance sampling), half cosine-weighted about the normal, combined by the balance heuristic (multiple
  importance sampling), so a constant or smooth sky converges as fast as a bright sun.

The irradiance returned is on the surface, cosine included and *before* any Fresnel transmittance (the
material-dependent entry Fresnel is applied in JAX, so an image stays differentiable in eta). A delta light
(point, spot, directional) is one column of the :class:`LightField`. An extended light (area, environment) arrives
from many directions with different Fresnel transmittances, so it becomes :data:`COS_BINS` columns: its samples are
binned by the cosine to the normal, and each column holds the bin's summed irradiance, its irradiance-weighted mean
cosine and a direction at that cosine (in the azimuth of the bin's mean direction), so that the single-scattering and
GGX terms, which read the direction, see the right angle of incidence. The entry Fresnel ``F_t(eta, cos)`` is smooth in ``cos``, so 8 bins reproduce the exact
hemispherical average of a uniform sky (``F_dt,ext``) to better than 0.2% for eta in [1, 1.5] (test).

A smooth boundary also shows the mirror image of extended lights (:mod:`jaxsss.render.mirror`). With a
``specular_roughness``, the GGX highlight of an extended light is evaluated on its cosine-bin columns (an
approximation for large lights).

Sample streams are deterministic: they depend on ``seed``, the light's kind and placement, and the point's index only
(not on the other lights, so an image is exactly additive in its lights).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import zlib

import numpy as np

__all__ = ["AREA_KINDS", "COS_BINS", "DELTA_KINDS", "EXTENDED_KINDS", "LightField", "capped_samples", "light_channels",
           "light_columns", "light_field", "refuse_lights", "spot_factor"]

DELTA_KINDS = ("point", "directional", "spot")
AREA_KINDS = ("sphere", "rectangle")
EXTENDED_KINDS = (*AREA_KINDS, "environment")
COS_BINS = 8
"""Columns of an extended light in a :class:`LightField` (bins of the cosine to the normal, equal width in cos)."""
_CHUNK_RAYS = 1 << 20  # shadow rays per chunk of points (memory: ~100 bytes per ray)


def light_channels(lights) -> int:
    """The channel count ``C`` of the lights' radiance: the longest ``intensity`` (a scalar light is grey, 1)."""
    return max(np.asarray(light.intensity).size for light in lights)


class LightField(NamedTuple):
    """The lights' contributions at ``P`` surface points, in ``L`` columns (:func:`light_columns`: one per delta
    light, :data:`COS_BINS` per area or environment light).

    Attributes:
        cos: ``(P, L)`` cosine between the normal and the direction *towards* the light, clipped at 0 (an extended
            light's column: the irradiance-weighted mean cosine of its bin).
        irradiance: ``(P, L, C)`` incident irradiance on the surface, W/mm^2 (cosine, falloff and shadowing
            included; zero where the light is below the horizon or blocked).
        to_light: ``(P, L, 3)`` unit direction from the point towards the light (an extended light's column: at the
            bin's mean cosine to the normal, in the azimuth of its irradiance-weighted mean direction; the normal where
            the bin is empty). ``to_light . normal == cos`` for every column that holds light.
    """

    cos: np.ndarray
    irradiance: np.ndarray
    to_light: np.ndarray


def light_columns(light) -> int:
    """How many :class:`LightField` columns ``light`` takes."""
    return COS_BINS if light.kind in EXTENDED_KINDS else 1


def capped_samples(lights: Sequence, n: int) -> tuple:
    """The lights with area and environment lights sampled at most ``n`` times per point (secondary evaluations such
    as the indirect bounce's occluder hits)."""
    import dataclasses

    return tuple(dataclasses.replace(light, samples=min(int(light.samples), int(n)))
                 if light.kind in EXTENDED_KINDS else light for light in lights)


def refuse_lights(scene, method: str, allowed=DELTA_KINDS, why: str = "") -> None:
    """Raise a ``ValueError`` naming the scene key of the first light whose kind ``method`` cannot use.

    Render methods that do not sample area or environment light call this in ``prepare`` (an accepted key must work
    or be refused, never ignored).
    """
    for i, light in enumerate(scene.lights):
        if light.kind not in allowed:
            key = getattr(light, "key", "") or f"light[{i}]"
            article = "an" if light.kind[0] in "aeiou" else "a"
            raise ValueError(f"[{key}] {article} {light.kind} light cannot be rendered by --method {method}"
                             f"{': ' + why if why else ''}; it takes {', '.join(allowed)} lights; --method "
                             "hierarchical, direct and cached take every kind")


def spot_factor(cos_axis: np.ndarray, cone_deg: float, falloff_deg: float) -> np.ndarray:
    """A spot light's angular factor: 1 inside ``cone_deg - falloff_deg``, linear in the angle to 0 at ``cone_deg``.

    Linear in the angle as Mitsuba 3's ``spot`` (``beam_width = cone_deg - falloff_deg``, ``cutoff_angle =
    cone_deg``; measured on its emitter in tests/export), so that an exported scene is lit as jaxsss lights it (a
    smoothstep, this module's form until 2026-11-29, differed by up to 0.096 of the on-axis intensity there)."""
    theta = np.degrees(np.arccos(np.clip(cos_axis, -1.0, 1.0)))
    if falloff_deg <= 0:
        return (theta <= cone_deg).astype(np.float64)
    return np.clip((cone_deg - theta) / falloff_deg, 0.0, 1.0)


def _one_light(light, points: np.ndarray):
    """``(to_light (P,3), distance (P,) or None, radiant factor (P,C))`` for one delta light, before the cosine."""
    intensity = np.asarray(light.intensity, dtype=np.float64)
    if light.kind == "directional":
        d = -np.asarray(light.direction, dtype=np.float64)
        to_light = np.broadcast_to(d, points.shape).copy()
        return to_light, None, np.broadcast_to(intensity, (len(points), intensity.size)).copy()
    delta = np.asarray(light.position, dtype=np.float64) - points
    dist = np.linalg.norm(delta, axis=1)
    to_light = delta / np.maximum(dist, 1e-300)[:, None]
    # Inverse-square law: E = I / d^2 (times the cosine, applied by the caller).
    factor = intensity[None, :] / np.maximum(dist, 1e-300)[:, None] ** 2
    if light.kind == "spot":
        cos_axis = np.einsum("ij,j->i", -to_light, np.asarray(light.direction, dtype=np.float64))
        factor = factor * spot_factor(cos_axis, light.cone_deg, light.falloff_deg)[:, None]
    return to_light, dist, factor


def _frame(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``(..., 3)`` unit ``w`` to an orthonormal frame."""
    helper = np.where(np.abs(w[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    t = np.cross(w, helper)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return t, np.cross(w, t)


def _stratified(rng: np.random.Generator, p: int, n: int, dims: int) -> np.ndarray:
    """``(p, n, dims)`` numbers in [0, 1): a rank-1 lattice ``((k + 1/2)/n, k a_1, k a_2, ...) mod 1`` randomly shifted
    per point (Cranley-Patterson rotation). ``a_j`` are Roberts' R-sequence constants ``phi^-j`` with ``phi`` the root
    of ``x^dims = x + 1`` (the golden ratio for two dimensions, the plastic number for three), so every projection
    onto two of the dimensions is evenly spread."""
    phi = 2.0
    for _ in range(60):  # Newton-free fixed point of x = (1 + x)^(1/dims)
        phi = (1.0 + phi) ** (1.0 / dims)
    alpha = phi ** -np.arange(1, dims)
    k = np.arange(n)[:, None]
    base = np.concatenate([(k + 0.5) / n, (k * alpha) % 1.0], axis=1)  # (n, dims)
    return (base[None] + rng.random((p, 1, dims))) % 1.0


def _cosine_dirs(normals: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``(P, n, 3)`` cosine-distributed directions about ``normals`` from ``(P, n, 2)`` uniform numbers (Malley)."""
    r, phi = np.sqrt(u[..., 0]), 2.0 * np.pi * u[..., 1]
    t, b = _frame(normals)
    z = np.sqrt(np.clip(1.0 - u[..., 0], 0.0, 1.0))
    return (r * np.cos(phi))[..., None] * t[:, None] + (r * np.sin(phi))[..., None] * b[:, None] + \
        z[..., None] * normals[:, None]


def _environment_samples(light, points, normals, rng):
    """``(directions (P,n,3), distance None, weight (P,n,C))``: radiance over the mixture density, over ``n``."""
    env, n = light.environment, int(light.samples)
    n_env = (n + 1) // 2
    n_cos = n - n_env
    dirs_e, _ = env.sample(_stratified(rng, len(points), n_env, 3))
    dirs = dirs_e
    if n_cos:
        dirs = np.concatenate([dirs_e, _cosine_dirs(normals, _stratified(rng, len(points), n_cos, 2))], axis=1)
    cos = np.einsum("pnk,pk->pn", dirs, normals)
    # Balance heuristic over the two strategies: f / (n_env p_env + n_cos p_cos), summed over all n samples.
    mix = n_env * env.pdf(dirs) + n_cos * np.clip(cos, 0.0, None) / np.pi
    radiance = env.radiance(dirs) * np.asarray(light.intensity, dtype=np.float64)
    return dirs, None, radiance / np.maximum(mix, 1e-300)[..., None]


def _sphere_samples(light, points, normals, rng):
    """Uniform in the solid angle of the sphere (cone sampling): weight ``L / pdf / n``, pdf = 1/(2 pi (1 - cos a))."""
    n = int(light.samples)
    centre, radius = np.asarray(light.position, dtype=np.float64), float(light.radius)
    delta = centre - points
    dist = np.linalg.norm(delta, axis=1)
    outside = dist > radius * (1.0 + 1e-9)
    # Inside the sphere (or at its centre) nothing arrives from outside it: any frame will do, the weight is zero.
    w = np.where(outside[:, None], delta / np.maximum(dist, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
    sin2_a = np.where(outside, (radius / np.maximum(dist, radius))**2, 1.0)
    # 1 - cos(a) without cancellation for small spheres: sin^2 a / (1 + cos a).
    one_minus = sin2_a / (1.0 + np.sqrt(np.clip(1.0 - sin2_a, 0.0, 1.0)))
    u = _stratified(rng, len(points), n, 2)
    one_minus_ct = u[..., 0] * one_minus[:, None]
    cos_t = 1.0 - one_minus_ct
    sin_t = np.sqrt(np.clip(one_minus_ct * (2.0 - one_minus_ct), 0.0, 1.0))
    phi = 2.0 * np.pi * u[..., 1]
    t, b = _frame(w)
    dirs = (sin_t * np.cos(phi))[..., None] * t[:, None] + (sin_t * np.sin(phi))[..., None] * b[:, None] + \
        cos_t[..., None] * w[:, None]
    # Distance to the near side of the sphere along each direction (the shadow ray stops there).
    d_perp2 = (dist ** 2)[:, None] * sin_t ** 2
    t_hit = dist[:, None] * cos_t - np.sqrt(np.clip(radius * radius - d_perp2, 0.0, None))
    # Cone sampling: pdf = 1 / (2 pi (1 - cos a)).
    weight = np.where(outside, 2.0 * np.pi * one_minus, 0.0)[:, None] / n
    radiance = np.asarray(light.intensity, dtype=np.float64)
    return dirs, t_hit, weight[..., None] * radiance


def _rectangle_samples(light, points, normals, rng):
    """Uniform in the rectangle's area: weight ``L A cos_l / d^2 / n`` (pdf in solid angle = d^2 / (A cos_l))."""
    n = int(light.samples)
    centre, normal = np.asarray(light.position, dtype=np.float64), np.asarray(light.direction, dtype=np.float64)
    e_v = np.asarray(light.up, dtype=np.float64)
    e_u = np.cross(e_v, normal)  # Mitsuba's look_at: x = up x dir, y = up, z = dir
    width, height = (float(s) for s in light.size)
    u = _stratified(rng, len(points), n, 2)
    y = centre + ((u[..., :1] - 0.5) * width) * e_u + ((u[..., 1:2] - 0.5) * height) * e_v
    delta = y - points[:, None]
    dist = np.linalg.norm(delta, axis=-1)
    dirs = delta / np.maximum(dist, 1e-300)[..., None]
    cos_l = -np.einsum("pnk,k->pn", dirs, normal)
    # Area sampling: E += L cos cos_l A / d^2 per sample (cos applied by the caller).
    weight = np.where(cos_l > 0, width * height * cos_l / np.maximum(dist, 1e-300) ** 2, 0.0) / n
    return dirs, dist, weight[..., None] * np.asarray(light.intensity, dtype=np.float64)


_SAMPLERS = {"environment": _environment_samples, "sphere": _sphere_samples, "rectangle": _rectangle_samples}


def _stream_id(light) -> int:
    """A light's sample stream: a checksum of its kind and placement, so that its samples do not depend on which
    other lights the scene has (images stay additive in the lights, test)."""
    parts = [light.kind, light.position, light.direction, light.radius, light.size, light.up]
    if light.environment is not None:
        parts += [light.environment.rotation, light.environment.image.shape]
    text = repr([None if a is None else np.asarray(a, dtype=np.float64).round(12).tolist() if not isinstance(a, str)
                 else a for a in parts])
    return zlib.crc32(text.encode())


def _extended(light, points, normals, geometry, seed: int, n_channels: int):
    """``(cos (P,B), irradiance (P,B,C), to_light (P,B,3))`` of one extended light, binned by cosine."""
    p = len(points)
    cos_out = np.zeros((p, COS_BINS))
    irr_out = np.zeros((p, COS_BINS, n_channels))
    to_out = np.repeat(normals[:, None, :], COS_BINS, axis=1)
    chunk = max(1, _CHUNK_RAYS // max(int(light.samples), 1))
    for c, start in enumerate(range(0, p, chunk)):
        sl = slice(start, min(start + chunk, p))
        pts, nrm = points[sl], normals[sl]
        rng = np.random.default_rng([int(seed), _stream_id(light), c])
        dirs, dist, weight = _SAMPLERS[light.kind](light, pts, nrm, rng)
        weight = np.broadcast_to(weight, (*dirs.shape[:2], n_channels))
        cos = np.einsum("pnk,pk->pn", dirs, nrm)
        lit = (cos > 0) & (weight.max(axis=-1) > 0)
        if geometry is not None and lit.any():
            pi_, ni_ = np.nonzero(lit)
            vis = geometry.visible(pts[pi_], nrm[pi_], dirs[pi_, ni_], None if dist is None else dist[pi_, ni_])
            lit[pi_, ni_] = vis
        # Sums per (point, bin) as bincounts over the lit samples (flat index point * B + bin).
        pi_, ni_ = np.nonzero(lit)
        cos_lit = cos[pi_, ni_]
        flat = pi_ * COS_BINS + np.minimum((cos_lit * COS_BINS).astype(np.int64), COS_BINS - 1)
        size = len(pts) * COS_BINS

        def per_bin(values):
            return np.bincount(flat, weights=values, minlength=size).reshape(len(pts), COS_BINS)

        # Irradiance: E = sum over samples of L cos V / pdf / n.
        c_lit = weight[pi_, ni_] * cos_lit[:, None]
        wt = c_lit.mean(axis=-1)  # channel-mean weight of each sample
        irr = np.stack([per_bin(c_lit[:, c]) for c in range(n_channels)], axis=-1)
        wsum = per_bin(wt)
        mean_cos = per_bin(wt * cos_lit) / np.maximum(wsum, 1e-300)
        mean_dir = np.stack([per_bin(wt * dirs[pi_, ni_, k]) for k in range(3)], axis=-1)
        # The bin's direction: its mean cosine to the normal, at the azimuth of its mean direction (an average over
        # azimuths would tilt it towards the normal and give single scattering and GGX the wrong cosine).
        mean_cos = np.clip(mean_cos, 0.0, 1.0)
        tangent = mean_dir - np.einsum("pbk,pk->pb", mean_dir, nrm)[..., None] * nrm[:, None]
        t_norm = np.linalg.norm(tangent, axis=-1, keepdims=True)
        fallback = np.broadcast_to(_frame(nrm)[0][:, None], tangent.shape)
        tangent = np.where(t_norm > 1e-12, tangent / np.maximum(t_norm, 1e-300), fallback)
        direction = np.sqrt(1.0 - mean_cos**2)[..., None] * tangent + mean_cos[..., None] * nrm[:, None]
        has = wsum > 0
        cos_out[sl] = np.where(has, mean_cos, 0.0)
        irr_out[sl] = irr
        to_out[sl] = np.where(has[..., None], direction, to_out[sl])
    return cos_out, irr_out, to_out


def light_field(lights: Sequence, points: np.ndarray, normals: np.ndarray, geometry=None, *,
                seed: int = 0) -> LightField:
    """Direct irradiance from every light at surface points.

    Args:
        lights: the scene's lights (:class:`jaxsss.render.scene.Light`).
        points: ``(P, 3)`` surface points, mm.
        normals: ``(P, 3)`` unit outward normals.
        geometry: a :class:`~jaxsss.render.rays.SceneGeometry` for shadow rays, or ``None`` to skip them (the plan
            decides; a point is then lit whenever the light is above its horizon).
        seed: the sample streams of area and environment lights (deterministic per seed, light and point).

    Returns:
        The :class:`LightField` (columns: :func:`light_columns` per light, in order).
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    n_channels = light_channels(lights)
    n_cols = sum(light_columns(light) for light in lights)
    cos = np.zeros((len(points), n_cols))
    irr = np.zeros((len(points), n_cols, n_channels))
    to = np.zeros((len(points), n_cols, 3))
    col = 0
    for light in lights:
        if light.kind in EXTENDED_KINDS:
            sl = slice(col, col + COS_BINS)
            if len(points):
                cos[:, sl], irr[:, sl], to[:, sl] = _extended(light, points, normals, geometry, seed, n_channels)
            col += COS_BINS
            continue
        to_light, dist, factor = _one_light(light, points)
        c = np.clip(np.einsum("ij,ij->i", normals, to_light), 0.0, 1.0)
        lit = (c > 0) & (factor.max(axis=1) > 0)
        if geometry is not None and lit.any():
            idx = np.flatnonzero(lit)
            vis = geometry.visible(points[idx], normals[idx], to_light[idx], None if dist is None else dist[idx])
            lit[idx] = vis
        cos[:, col] = c
        irr[:, col, :] = np.where(lit[:, None], factor * c[:, None], 0.0)
        to[:, col, :] = to_light
        col += 1
    return LightField(cos, irr, to)

