"""Lights as arrays for the JAX march: direction towards each light and the flux density it delivers at a point.

Point and spot lights of radiant intensity ``I`` (W/sr) deliver ``I / |S - M|^2`` (W/mm^2, on a surface facing
them) at a point ``M`` along the straight line from ``S`` -- the paper ignores refraction at the boundary, and so do
we; directional lights deliver their irradiance ``E``. A spot light's cone factor is the renderer's linear falloff
(:func:`jaxsss.render.lights.spot_factor`). The attenuation inside the medium is applied by the caller. All of it is
geometry: it carries no gradient with respect to the layer coefficients.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

__all__ = ["LightArrays", "light_arrays", "lights_at"]


class LightArrays(eqx.Module):
    """``L`` lights: ``position``/``direction`` ``(L, 3)`` (zeros where unused), ``intensity`` ``(L, C)``,
    ``directional``/``spot`` ``(L,)`` flags, ``cone_deg``/``falloff_deg`` ``(L,)``."""

    position: jnp.ndarray
    direction: jnp.ndarray
    intensity: jnp.ndarray
    directional: jnp.ndarray
    spot: jnp.ndarray
    cone_deg: jnp.ndarray
    falloff_deg: jnp.ndarray

    @property
    def n_lights(self) -> int:
        return self.position.shape[0]


def light_arrays(lights: Sequence, n_channels: int = 3) -> LightArrays:
    """Pack a scene's lights (:class:`jaxsss.render.scene.Light`) into :class:`LightArrays`."""
    if len(lights) == 0:
        raise ValueError("light_arrays(lights=()): give at least one light")
    pos, dirn, inten, is_dir, is_spot, cone, fall = [], [], [], [], [], [], []
    for light in lights:
        pos.append(np.zeros(3) if light.position is None else np.asarray(light.position, dtype=np.float64))
        dirn.append(np.zeros(3) if light.direction is None else np.asarray(light.direction, dtype=np.float64))
        inten.append(np.broadcast_to(np.asarray(light.intensity, dtype=np.float64), (n_channels,)))
        is_dir.append(light.kind == "directional")
        is_spot.append(light.kind == "spot")
        cone.append(float(light.cone_deg))
        fall.append(float(light.falloff_deg))
    return LightArrays(jnp.asarray(np.stack(pos)), jnp.asarray(np.stack(dirn)), jnp.asarray(np.stack(inten)),
                       jnp.asarray(is_dir), jnp.asarray(is_spot), jnp.asarray(cone), jnp.asarray(fall))


def lights_at(lights: LightArrays, points):
    """``(w_in (..., L, 3), E (..., L, C), distance (..., L))`` at ``points`` ``(..., 3)``: the unit vector towards
    each light, the flux density it delivers there before attenuation (W/mm^2), and the distance to it (mm; inf for
    directional lights)."""
    delta = lights.position - points[..., None, :]
    dist = jnp.sqrt(jnp.sum(delta * delta, axis=-1))
    safe = jnp.maximum(dist, 1e-300)
    d_dir = lights.directional[:, None]
    w_in = jnp.where(d_dir, -lights.direction, delta / safe[..., None])
    # Inverse-square law for point and spot lights: E = I / d^2.
    falloff = jnp.where(lights.directional, 1.0, 1.0 / (safe * safe))
    cos_axis = jnp.clip(jnp.sum(-w_in * lights.direction, axis=-1), -1.0, 1.0)
    theta = jnp.degrees(jnp.arccos(cos_axis))
    width = jnp.maximum(lights.falloff_deg, 1e-12)
    s = jnp.clip((lights.cone_deg - theta) / width, 0.0, 1.0)
    smooth = jnp.where(lights.falloff_deg > 0, s * s * (3.0 - 2.0 * s), (theta <= lights.cone_deg).astype(s.dtype))
    cone = jnp.where(lights.spot, smooth, 1.0)
    E = lights.intensity * (falloff * cone)[..., None]
    return w_in, E, jnp.where(lights.directional, jnp.inf, dist)
