"""Direct irradiance from the scene's lights at surface points (NumPy), with optional shadow rays.

Units: positions in mm; a point or spot light's ``intensity`` is radiant intensity in W/sr, a directional light's is
the irradiance in W/mm^2 on a surface facing it. The irradiance returned is on the surface, cosine included and
*before* any Fresnel transmittance (the material-dependent entry Fresnel is applied in JAX, so an image stays
differentiable in eta).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["LightField", "light_field", "spot_factor"]


class LightField(NamedTuple):
    """Each light's contribution at ``P`` surface points.

    Attributes:
        cos: ``(P, L)`` cosine between the normal and the direction *towards* the light, clipped at 0.
        irradiance: ``(P, L, C)`` incident irradiance on the surface, W/mm^2 (cosine, falloff and shadowing
            included; zero where the light is below the horizon or blocked).
        to_light: ``(P, L, 3)`` unit direction from the point towards the light.
    """

    cos: np.ndarray
    irradiance: np.ndarray
    to_light: np.ndarray


def spot_factor(cos_axis: np.ndarray, cone_deg: float, falloff_deg: float) -> np.ndarray:
    """A spot light's angular factor: 1 inside ``cone_deg - falloff_deg``, smoothstep to 0 at ``cone_deg``."""
    theta = np.degrees(np.arccos(np.clip(cos_axis, -1.0, 1.0)))
    inner = cone_deg - falloff_deg
    if falloff_deg <= 0:
        return (theta <= cone_deg).astype(np.float64)
    s = np.clip((cone_deg - theta) / (cone_deg - inner), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _one_light(light, points: np.ndarray):
    """``(to_light (P,3), distance (P,) or None, radiant factor (P,C))`` for one light, before the cosine."""
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


def light_field(lights: Sequence, points: np.ndarray, normals: np.ndarray, geometry=None) -> LightField:
    """Direct irradiance from every light at surface points.

    Args:
        lights: the scene's lights (:class:`jaxsss.render.scene.Light`).
        points: ``(P, 3)`` surface points, mm.
        normals: ``(P, 3)`` unit outward normals.
        geometry: a :class:`~jaxsss.render.rays.SceneGeometry` for shadow rays, or ``None`` to skip them (the plan
            decides; a point is then lit whenever the light is above its horizon).

    Returns:
        The :class:`LightField`.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    n_channels = max(np.asarray(light.intensity).size for light in lights)
    cos = np.zeros((len(points), len(lights)))
    irr = np.zeros((len(points), len(lights), n_channels))
    to = np.zeros((len(points), len(lights), 3))
    for k, light in enumerate(lights):
        to_light, dist, factor = _one_light(light, points)
        c = np.clip(np.einsum("ij,ij->i", normals, to_light), 0.0, 1.0)
        lit = (c > 0) & (factor.max(axis=1) > 0)
        if geometry is not None and lit.any():
            idx = np.flatnonzero(lit)
            vis = geometry.visible(points[idx], normals[idx], to_light[idx], None if dist is None else dist[idx])
            lit[idx] = vis
        cos[:, k] = c
        irr[:, k, :] = np.where(lit[:, None], factor * c[:, None], 0.0)
        to[:, k, :] = to_light
    return LightField(cos, irr, to)
