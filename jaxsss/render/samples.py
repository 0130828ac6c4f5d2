"""Pass 1 of the hierarchical method: irradiance samples on the translucent surface (NumPy, trimesh, embreex).

Density (hierarchical paper, "Pass 1"): the mean free path ``l_u`` is the largest spacing, so an object of area ``A``
gets about ``A / (pi l_u^2)`` points, times the scene's ``density`` multiplier. Points are blue-noise-like
(trimesh's even sampling, a Poisson-disk rejection pass) and each carries the area ``A / N``.

Each sample stores the geometry of its light (:class:`~jaxsss.render.lights.LightField`), an optional one-bounce
indirect irradiance off opaque occluders, and an optional texture multiplier. The entry Fresnel that turns these into
flux depends on the material and is applied in JAX (:func:`jaxsss.render.radiance.transmitted_flux`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import trimesh

from jaxsss.render.lights import LightField, light_field

__all__ = [
    "IrradianceSamples",
    "indirect_irradiance",
    "irradiance_samples",
    "sample_count",
    "sample_surface",
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
    """

    positions: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    face: np.ndarray
    light: LightField
    indirect: np.ndarray | None
    texture: np.ndarray | None

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


def sample_surface(mesh: trimesh.Trimesh, n: int, seed: int = 0):
    """``(positions, face, areas)``: about ``n`` evenly spread points on the mesh (trimesh's Poisson-disk pass).

    The even sampler can return fewer points than asked; the area per point is the total area over the number
    returned, so the total area is exact.
    """
    pts, face = trimesh.sample.sample_surface_even(mesh, int(n), seed=seed)
    if len(pts) < 0.5 * n:  # very uneven meshes: fall back to plain area-weighted sampling
        pts, face = trimesh.sample.sample_surface(mesh, int(n), seed=seed)
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


def _cosine_directions(normals: np.ndarray, n_rays: int, rng: np.random.Generator) -> np.ndarray:
    """``(P, n_rays, 3)`` cosine-distributed unit directions about each normal (Malley's method)."""
    u1, u2 = rng.random((2, len(normals), n_rays))
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.clip(1.0 - u1, 0.0, 1.0))], axis=-1)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t = np.cross(normals, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    return local[..., :1] * t[:, None] + local[..., 1:2] * b[:, None] + local[..., 2:] * normals[:, None]


def indirect_irradiance(scene, geometry, points, normals, *, n_rays: int = 16, seed: int = 0) -> np.ndarray:
    """One-bounce diffuse irradiance off the scene's opaque (Lambertian) occluders, ``(P, C)`` W/mm^2.

    Cosine-weighted rays: ``E = pi * mean(L)``, with ``L = albedo / pi * E_direct(y)`` at an occluder hit ``y``.
    Rays that hit the translucent object itself or nothing add zero (self inter-reflection is not modelled).
    """
    rng = np.random.default_rng(seed)
    dirs = _cosine_directions(normals, n_rays, rng).reshape(-1, 3)
    origins = np.repeat(points + geometry.offset * normals, n_rays, axis=0)
    hits = geometry.first_hit(origins, dirs)
    n_c = max(np.asarray(light.intensity).size for light in scene.lights)
    radiance = np.zeros((len(dirs), n_c))
    on_occ = hits.obj >= 1
    if on_occ.any():
        idx = np.flatnonzero(on_occ)
        y = hits.position[idx]
        ny = geometry.combined.face_normals[hits.face[idx]]
        ny = np.where(np.einsum("ij,ij->i", ny, dirs[idx])[:, None] > 0, -ny, ny)  # face the incoming ray
        direct = light_field(scene.lights, y, ny, geometry).irradiance.sum(axis=1)
        albedo = np.stack([scene.occluders[k - 1].albedo for k in hits.obj[idx]])
        radiance[idx] = albedo / np.pi * direct
    return np.pi * radiance.reshape(len(points), n_rays, n_c).mean(axis=1)


def irradiance_samples(scene, geometry, n: int, *, shadows: bool, indirect: bool, seed: int = 0,
                       indirect_rays: int = 16) -> IrradianceSamples:
    """Pass 1: ``n`` samples on the translucent mesh with their direct (and optionally indirect) irradiance.

    Args:
        scene: the :class:`~jaxsss.render.scene.Scene`.
        geometry: its :class:`~jaxsss.render.rays.SceneGeometry`.
        n: number of samples to ask for (see :func:`sample_count`).
        shadows: cast shadow rays (the plan leaves them out for a convex object alone in the scene).
        indirect: add one-bounce indirect irradiance off occluders.
    """
    positions, face, areas = sample_surface(scene.mesh, n, seed)
    normals = geometry.shading_normals(face, positions)
    light = light_field(scene.lights, positions, normals, geometry if shadows else None)
    ind = indirect_irradiance(scene, geometry, positions, normals, n_rays=indirect_rays, seed=seed + 1) \
        if indirect else None
    tex = None
    if scene.material.texture is not None:
        from jaxsss.render.meshes import uv_at

        tex = texture_lookup(scene.material.texture, uv_at(scene.mesh, positions, face))
    return IrradianceSamples(positions, normals, areas, face, light, ind, tex)
