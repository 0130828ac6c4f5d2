"""The one building block of every image-source diffusion profile: the exitance of a point source below a plane.

A unit isotropic point source at height ``z`` below (``z > 0``) or above (``z < 0``) the surface plane, in an
infinite medium with transport extinction ``sigma_tr``, drives a diffusive flux ``-D dphi/dz`` through the plane at
radial distance ``r`` of

    E(z, r) = z (1 + sigma_tr d) exp(-sigma_tr d) / (4 pi d^3),   d = sqrt(r^2 + z^2)   [1/mm^2]

(hierarchical paper Eq. 8-9 without alpha'; photon-diffusion Eq. 6). Its integral over the plane is
``sign(z) exp(-sigma_tr |z|) / 2``: every profile built from these terms has a closed-form total.

Non-absorbing media (``sigma_a = 0``). ``sigma_tr = sqrt(3 sigma_a sigma_t')`` has an infinite derivative in
``sigma_a`` at 0, but ``E`` depends on ``sigma_tr`` only through the damping ``(1 + x) e^{-x}``, ``x = sigma_tr d``,
which is ``1 - x^2/2 + x^3/3 - ...``: a smooth function of ``x^2 = sigma_tr^2 d^2`` to first order, with
``d/d(x^2) = -e^{-x}/2`` (finite, ``-1/2`` at 0). :func:`point_source_exitance_sq` therefore takes
``sigma_tr^2 = 3 sigma_a sigma_t'`` (:attr:`jaxsss.medium.Medium.sigma_tr_sq`), and every profile evaluated through
it has a finite gradient at ``sigma_a = 0``: ``dE/d sigma_a = -z e^{-x} / (8 pi d) * d(sigma_tr^2)/d sigma_a``, the
one-sided derivative (the profile is defined for ``sigma_a >= 0`` only). Second derivatives in ``sigma_tr^2`` are
infinite at 0 (the ``x^3`` term), as they truly are.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["point_source_exitance", "point_source_exitance_sq", "point_source_total"]

# Beyond x = sigma_tr d = 1e3 the damping e^{-x} (1 + x) underflows in float64 (and float32): x^2 is clamped there so
# that x^2 never overflows to inf (inf * 0 = nan).
_X2_MAX = 1e6


@jax.custom_jvp
def _damping(x2):
    """``(1 + x) e^{-x}``, ``x = sqrt(x2)``, ``x2 >= 0``; differentiable at ``x2 = 0`` (derivative ``-e^{-x}/2``)."""
    x = jnp.sqrt(x2)
    return (1.0 + x) * jnp.exp(-x)


@_damping.defjvp
def _damping_jvp(primals, tangents):
    (x2,), (t,) = primals, tangents
    x = jnp.sqrt(x2)
    e = jnp.exp(-x)
    # d/d(x^2) [(1 + x) e^{-x}] = (-x e^{-x}) / (2x) = -e^{-x} / 2, finite at x = 0.
    return (1.0 + x) * e, -0.5 * e * t


def point_source_exitance_sq(z, r, sigma_tr_sq):
    """``E(z, r)`` above from ``sigma_tr^2`` (1/mm^2), in 1/mm^2 per unit source power; broadcasts. Zero for a source
    in the plane (``z = 0``). Finite gradients at ``sigma_tr = 0`` (module docstring)."""
    d2 = r * r + z * z
    in_plane = d2 == 0.0
    d2_safe = jnp.where(in_plane, 1.0, d2)
    d = jnp.sqrt(d2_safe)
    # Photon-diffusion Eq. 6, written as (z/d) / d^2 so that float32 does not overflow at d ~ 1e13 mm; the damping
    # (1 + sigma_tr d) exp(-sigma_tr d) is a function of (sigma_tr d)^2.
    x2 = jnp.minimum(sigma_tr_sq * d2_safe, _X2_MAX)
    E = (z / d) * _damping(x2) / (4.0 * jnp.pi * d2_safe)
    return jnp.where(in_plane, 0.0, E)


def point_source_exitance(z, r, sigma_tr):
    """``E(z, r)`` above, in 1/mm^2 per unit source power; broadcasts. Zero for a source in the plane (``z = 0``).

    Differentiable in ``sigma_tr`` everywhere (``dE/d sigma_tr = 0`` at ``sigma_tr = 0``); a caller that derives
    ``sigma_tr`` from ``sigma_a`` should pass ``sigma_tr^2`` to :func:`point_source_exitance_sq` instead, whose
    gradient in ``sigma_a`` stays finite at ``sigma_a = 0``."""
    return point_source_exitance_sq(z, r, sigma_tr * sigma_tr)


def point_source_total(z, sigma_tr):
    """Plane integral of :func:`point_source_exitance`: ``sign(z) exp(-sigma_tr |z|) / 2``."""
    return 0.5 * jnp.sign(z) * jnp.exp(-sigma_tr * jnp.abs(z))
