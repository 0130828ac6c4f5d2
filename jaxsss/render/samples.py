"""Pass 1 of the hierarchical method: irradiance samples on the translucent surface (NumPy, trimesh, embreex).

Density (hierarchical paper, "Pass 1"): the mean free path ``l_u`` is the largest spacing, so an object of area ``A``
gets about ``A / (pi l_u^2)`` points, times the scene's ``density`` multiplier. Each carries the area ``A / N``.

Placement (:data:`SAMPLERS`). The paper uses Turk's point repulsion; what matters for the sums is that the number of
points in any patch is proportional to its area, since every point carries the same area. ``"stratified"``
(default) walks the triangles along a Z-order (Morton) curve and places the points at jittered equal steps of the
accumulated area, so every stretch of the curve gets its exact share; inside a triangle they follow a randomly
shifted rank-1 (golden-ratio) lattice mapped area-preservingly onto the triangle. ``"even"`` is trimesh's
Poisson-disk rejection of random points: blue noise at the point scale, but its patch counts fluctuate like a
random sample's, which on a uniformly lit plane gives 8-17% pixel noise at the paper's density where
``"stratified"`` gives 1-8% (before the near-field split of :mod:`jaxsss.render.radiance`).

Each sample stores the geometry of its light (:class:`~jaxsss.render.lights.LightField`), an optional one-bounce
indirect irradiance off opaque occluders, an optional one-bounce irradiance off the object itself (before its diffuse
albedo, which depends on the material: :func:`self_irradiance`), and an optional texture multiplier. The entry Fresnel
that turns these into flux depends on the material and is applied in JAX
(:func:`jaxsss.render.radiance.transmitted_flux`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import trimesh

from jaxsss.render.lights import LightField, capped_samples, light_channels, light_field
from jaxsss.render.octree import MORTON_BITS, morton_codes
from jaxsss.render.strata import unit_square

__all__ = [
    "BOUNCE_RAYS",
    "SAMPLERS",
    "IrradianceSamples",
    "indirect_irradiance",
    "irradiance_samples",
    "lit_positions",
    "sample_count",
    "sample_surface",
    "self_irradiance",
    "texture_lookup",
]


class IrradianceSamples(NamedTuple):
    """``N`` irradiance samples.

    Attributes:
        positions: ``(N, 3)`` mm.
        normals: ``(N, 3)`` unit outward (smooth) normals.
        areas: ``(N,)`` mm^2 (each ``A / N``).
        face: ``(N,)`` face of the translucent mesh each sample lies on.
        light: direct light at the samples (``cos (N, L)``, ``irradiance (N, L, C)`` in W/mm^2).
        indirect: ``(N, C)`` diffuse indirect irradiance, W/mm^2, or ``None``.
        texture: ``(N, C)`` texture multiplier, or ``None``.
        chord: ``(N, L)`` mm, each light column's refracted path inside the object
            (:func:`jaxsss.render.passage.entry_chords`), or ``None`` (not traced).
        self_indirect: ``(N, C)`` W/mm^2, the direct irradiance of the object's own surface seen from each sample
            (:func:`self_irradiance`; times the surface's diffuse albedo it is the one-bounce irradiance), or ``None``.
    """

    positions: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    face: np.ndarray
    light: LightField
    indirect: np.ndarray | None
    texture: np.ndarray | None
    chord: np.ndarray | None = None
    self_indirect: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.positions)


def sample_count(area: float, l_u: float, density: float = 1.0, max_samples: int | None = None) -> tuple[int, str]:
    """``(N, reason)``: the paper's count ``density * A / (pi l_u^2)``, capped at ``max_samples``.

    Args:
        area: surface area, mm^2.
        l_u: the smallest mean free path over channels, mm.
    """
    want = max(math.ceil(density * area / (math.pi * l_u * l_u)), 16)
    reason = f"density {density:g} x A/(pi l_u^2) with A = {area:.4g} mm^2, l_u = {l_u:.4g} mm"
    if max_samples is not None and want > max_samples:
        return int(max_samples), f"{reason} asks for {want}; capped at max_samples = {max_samples}"
    return want, reason


_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
INDIRECT_LIGHT_SAMPLES = 4
"""Samples of an area or environment light at each occluder hit of the indirect bounce."""


def _stratified(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator):
    """``(positions, face)``: ``n`` points, jittered equal steps of area along a Z-order curve of the triangles."""
    tri = mesh.triangles
    centres = tri.mean(axis=1)
    lo = centres.min(axis=0)
    side = max(float((centres.max(axis=0) - lo).max()), 1e-300)
    top = (1 << MORTON_BITS) - 1
    cells = np.clip(((centres - lo) / side * top).astype(np.int64), 0, top)
    order = np.argsort(morton_codes(cells), kind="stable")
    cum = np.cumsum(mesh.area_faces[order])
    step = cum[-1] / n
    k = np.minimum(np.searchsorted(cum, (np.arange(n) + rng.random(n)) * step, side="right"), len(order) - 1)
    counts = np.bincount(k, minlength=len(order))
    rank = np.arange(n) - (np.cumsum(counts) - counts)[k]  # k is sorted: rank of each point within its triangle
    shift = rng.random((2, len(order)))
    a = (rank + shift[0, k]) / counts[k]
    b = (rank * _GOLDEN + shift[1, k]) % 1.0
    # Area-preserving map of the unit square onto the triangle (Shirley): barycentrics (1 - sqrt a, sqrt a (1 - b),
    # sqrt a b).
    sa = np.sqrt(a)
    t = tri[order[k]]
    pos = (1.0 - sa)[:, None] * t[:, 0] + (sa * (1.0 - b))[:, None] * t[:, 1] + (sa * b)[:, None] * t[:, 2]
    return pos, order[k]


def _even(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator):
    pts, face = trimesh.sample.sample_surface_even(mesh, int(n), seed=int(rng.integers(2**31)))
    if len(pts) < 0.5 * n:  # very uneven meshes: fall back to plain area-weighted sampling
        pts, face = trimesh.sample.sample_surface(mesh, int(n), seed=int(rng.integers(2**31)))
    return pts, face


SAMPLERS = {"stratified": _stratified, "even": _even}
"""Point placements by name (module docstring)."""


def sample_surface(mesh: trimesh.Trimesh, n: int, seed: int = 0, method: str = "stratified"):
    """``(positions, face, areas)``: about ``n`` points on the mesh, each with the area ``A / N``.

    ``method`` is a key of :data:`SAMPLERS`. ``"even"`` can return fewer points than asked; the area per point is the
    total area over the number returned, so the total area is exact either way.
    """
    if method not in SAMPLERS:
        raise ValueError(f"sample_surface(method={method!r}) is not one of {sorted(SAMPLERS)}")
    if int(n) < 1:
        raise ValueError(f"sample_surface(n={n}) is outside the allowed range [1, inf)")
    pts, face = SAMPLERS[method](mesh, int(n), np.random.default_rng(seed))
    areas = np.full(len(pts), float(mesh.area) / len(pts))
    return np.asarray(pts, dtype=np.float64), np.asarray(face, dtype=np.int64), areas


def texture_lookup(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with wrap-around. ``texture`` is ``(H, W, C)``; ``uv`` in ``[0, 1]^2`` with ``v = 1`` at the
    image's top row (the OpenGL convention most mesh files use)."""
    h, w = texture.shape[:2]
    x = (uv[:, 0] % 1.0) * w - 0.5
    y = (1.0 - uv[:, 1] % 1.0) * h - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]

    def at(yy, xx):
        return texture[yy % h, xx % w]

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


BOUNCE_RAYS = 8
"""Rays per irradiance sample for the one-bounce terms (:func:`indirect_irradiance`, :func:`self_irradiance`),
stratified over the hemisphere. On the marble teapot (161,017 samples, 64 x 64) 8 stratified rays gave the same image
error against Mitsuba as 16 (mare_lit 0.034 / 0.031 / 0.032 against 0.034 / 0.032 / 0.032, band 0.091 / 0.093 / 0.104
against 0.091 / 0.099 / 0.112) with pass 1 0.39 s against 0.67-0.98 s; 4 gave 0.035 / 0.032 / 0.033, band 0.095 /
0.104 / 0.118 (docs/path_tracer.md, "Dark pixels are areas too"). Each sample's estimate is noisy; the profile's sum
over the many samples within ``l_d`` of a pixel averages it."""


def _cosine_directions(normals: np.ndarray, n_rays: int, rng: np.random.Generator) -> np.ndarray:
    """``(P, n_rays, 3)`` cosine-distributed unit directions about each normal (Malley's method), each point's rays
    stratified over the unit square (:func:`jaxsss.render.strata.unit_square`)."""
    u = unit_square(rng, len(normals), n_rays)
    u1, u2 = u[..., 0], u[..., 1]
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.clip(1.0 - u1, 0.0, 1.0))], axis=-1)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t = np.cross(normals, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    return local[..., :1] * t[:, None] + local[..., 1:2] * b[:, None] + local[..., 2:] * normals[:, None]


def _bounce(scene, geometry, points, normals, n_rays: int, seed: int, weight) -> np.ndarray:
    """``(P, C)``: the cosine-weighted mean, over ``n_rays`` rays per point, of the direct irradiance (W/mm^2) at each
    ray's first hit times ``weight(obj)`` ``(R, C)``, the hit object's diffuse albedo (``obj``: 0 the translucent
    object, 1.. the occluders, negative a miss; a zero row leaves the ray out). With Lambertian reflection at the hits,
    ``E = pi mean(L) = mean(albedo E_direct)``. Area and environment lights are sampled with at most
    :data:`INDIRECT_LIGHT_SAMPLES` directions at each hit (the ``n_rays`` hits per point already average them)."""
    rng = np.random.default_rng(seed)
    dirs = _cosine_directions(normals, n_rays, rng).reshape(-1, 3)
    origins = np.repeat(points + geometry.offset * normals, n_rays, axis=0)
    hits = geometry.first_hit(origins, dirs)
    n_c = light_channels(scene.lights)
    out = np.zeros((len(dirs), n_c))
    albedo = weight(hits.obj)
    idx = np.flatnonzero(hits.hit & np.any(albedo > 0, axis=-1))
    if len(idx):
        y = hits.position[idx]
        ny = geometry.combined.face_normals[hits.face[idx]]
        ny = np.where(np.einsum("ij,ij->i", ny, dirs[idx])[:, None] > 0, -ny, ny)  # face the incoming ray
        direct = light_field(capped_samples(scene.lights, INDIRECT_LIGHT_SAMPLES), y, ny, geometry,
                             seed=seed + 1).irradiance.sum(axis=1)
        out[idx] = albedo[idx] * direct
    return out.reshape(len(points), n_rays, n_c).mean(axis=1)


def indirect_irradiance(scene, geometry, points, normals, *, n_rays: int = BOUNCE_RAYS, seed: int = 0) -> np.ndarray:
    """One-bounce diffuse irradiance off the scene's opaque (Lambertian) occluders, ``(P, C)`` W/mm^2.

    Cosine-weighted rays: ``E = pi * mean(L)``, with ``L = albedo / pi * E_direct(y)`` at an occluder hit ``y``.
    Rays that hit the translucent object itself (:func:`self_irradiance`) or nothing add zero.
    """
    n_c = light_channels(scene.lights)
    albedo = np.stack([np.zeros(n_c)] + [np.broadcast_to(np.asarray(o.albedo, dtype=np.float64), (n_c,))
                                         for o in scene.occluders])

    def occluders(obj):
        return np.where((obj >= 1)[:, None], albedo[np.clip(obj, 0, len(albedo) - 1)], 0.0)

    return _bounce(scene, geometry, points, normals, n_rays, seed, occluders)


def self_irradiance(scene, geometry, points, normals, *, n_rays: int = BOUNCE_RAYS, seed: int = 0) -> np.ndarray:
    """The translucent object's own lit surface seen from points on it: ``(P, C)`` W/mm^2, the cosine-weighted mean
    of the direct irradiance at the first hits on the object (zero for a convex object, whose surface a ray leaving it
    never meets again).

    Times the surface's diffuse albedo ``rho`` (material-dependent, applied in JAX: ``F_dt,ext Rd``,
    :meth:`jaxsss.render.renderer.Prepared.sample_flux`) it is the one-bounce irradiance of light that leaves the
    object and enters it again elsewhere: the lit spout and handle of a marble teapot light its shadowed body.
    Local approximation: the exitance at a hit is ``rho`` times its own irradiance, not the profile-blurred
    irradiance around it (right where the light varies slowly over ``l_d``; too sharp at shadow edges).
    """
    n_c = light_channels(scene.lights)
    return _bounce(scene, geometry, points, normals, n_rays, seed,
                   lambda obj: np.where((obj == 0)[:, None], np.ones(n_c), 0.0))


def lit_positions(samples: IrradianceSamples) -> np.ndarray:
    """``(M, 3)`` mm: the samples that some light reaches directly (the lit surface, from which light creeps into
    the dark parts; :func:`jaxsss.render.shading.dark_pixel_grid`)."""
    return samples.positions[samples.light.irradiance.sum(axis=tuple(range(1, samples.light.irradiance.ndim))) > 0.0]


def irradiance_samples(scene, geometry, n: int, *, shadows: bool, indirect: bool, seed: int = 0,
                       indirect_rays: int = BOUNCE_RAYS, chords: bool = False,
                       self_bounce: bool = False) -> IrradianceSamples:
    """Pass 1: ``n`` samples on the translucent mesh with their direct (and optionally indirect) irradiance.

    Args:
        scene: the :class:`~jaxsss.render.scene.Scene`.
        geometry: its :class:`~jaxsss.render.rays.SceneGeometry`.
        n: number of samples to ask for (see :func:`sample_count`).
        shadows: cast shadow rays (the plan leaves them out for a convex object alone in the scene).
        indirect: add one-bounce indirect irradiance off occluders.
        chords: trace each light column's refracted ray through the object (:mod:`jaxsss.render.passage`; the white
            kernels weight the flux by the probability of interacting along it).
        self_bounce: trace :func:`self_irradiance` (light that leaves the object and reaches it again).
    """
    positions, face, areas = sample_surface(scene.mesh, n, seed)
    normals = geometry.shading_normals(face, positions)
    light = light_field(scene.lights, positions, normals, geometry if shadows else None, seed=seed + 2)
    ind = indirect_irradiance(scene, geometry, positions, normals, n_rays=indirect_rays, seed=seed + 1) \
        if indirect else None
    tex = None
    if scene.material.texture is not None:
        from jaxsss.render.meshes import uv_at

        tex = texture_lookup(scene.material.texture, uv_at(scene.mesh, positions, face))
    chord = None
    if chords:
        from jaxsss.render.passage import entry_chords

        chord = entry_chords(geometry, positions, normals, light.to_light, light.cos, float(scene.material.medium.eta))
    own = self_irradiance(scene, geometry, positions, normals, n_rays=indirect_rays, seed=seed + 3) \
        if self_bounce else None
    return IrradianceSamples(positions, normals, areas, face, light, ind, tex, chord, own)
