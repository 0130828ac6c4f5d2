"""The one building block of every image-source diffusion profile: the exitance of a point source below a plane.

A unit isotropic point source at height ``z`` below (``z > 0``) or above (``z < 0``) the surface plane, in an
infinite medium with transport extinction ``sigma_tr``, drives a diffusive flux ``-D dphi/dz`` through the plane at
radial distance ``r`` of

    E(z, r) = z (1 + sigma_tr d) exp(-sigma_tr d) / (4 pi d^3),   d = sqrt(r^2 + z^2)   [1/mm^2]

(hierarchical paper Eq. 8-9 without alpha'; photon-diffusion Eq. 6). Its integral over the plane is
``sign(z) exp(-sigma_tr |z|) / 2``: every profile built from these terms has a closed-form total.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["point_source_exitance", "point_source_total"]


def point_source_exitance(z, r, sigma_tr):
    """``E(z, r)`` above, in 1/mm^2 per unit source power; broadcasts. Zero for a source in the plane (``z = 0``)."""
    d2 = r * r + z * z
    in_plane = d2 == 0.0
    d = jnp.sqrt(jnp.where(in_plane, 1.0, d2))
    # Photon-diffusion Eq. 6, written as (z/d) / d^2 so that float32 does not overflow at d ~ 1e13 mm.
    E = (z / d) * (1.0 + sigma_tr * d) * jnp.exp(-sigma_tr * d) / (4.0 * jnp.pi * jnp.where(in_plane, 1.0, d2))
    return jnp.where(in_plane, 0.0, E)


def point_source_total(z, sigma_tr):
    """Plane integral of :func:`point_source_exitance`: ``sign(z) exp(-sigma_tr |z|) / 2``."""
    return 0.5 * jnp.sign(z) * jnp.exp(-sigma_tr * jnp.abs(z))
