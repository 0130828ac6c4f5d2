"""The dipole's profile and its derivatives in ``(log sigma_a, log sigma_s')`` by hand, for the fit's Jacobian.

``jax.jacfwd`` of the dipole pushes one tangent per parameter through every radius (the exponentials and square
roots are recomputed for each); here they are computed once and shared by the value and both derivatives. Used by
:func:`fitting._kernel._linearise` for ``model="dipole"`` with fixed ``eta`` (the common fit); checked against
``jax.jacfwd`` of the registered model in ``tests/fitting/test_dipole_jac.py``.

Physics (the same as :func:`jaxsss.dipole_profile` times the entry transmittance, :mod:`fitting.models`):
``R(r) = T_entry alpha' [E(z_r, r) + E(z_v, r)]`` with ``E(z, r) = z (1 + s d) e^{-s d} / (4 pi d^3)``,
``d = sqrt(r^2 + z^2)``, ``s = sigma_tr = sqrt(3 sigma_a sigma_t')``, ``z_r = 1 / sigma_t'`` and
``z_v = z_r (1 + 4 A / 3)`` (``A`` depends on ``eta`` only, so ``z_v / z_r`` is a constant of the fit).
"""

from __future__ import annotations

import jax.numpy as jnp

import jaxsss
from jaxsss.profiles.dipole import dipole_depths


def dipole_value_and_jac(r, sigma_a, sigma_s_prime, eta, fresnel="poly"):
    """``(R, dR/dlog sigma_a, dR/dlog sigma_s')``, each ``(N,)`` in 1/mm^2 per incident photon, for radii ``r``
    ``(N,)`` mm and one channel's scalars (1/mm; ``eta`` = n_inside / n_outside, fixed). ``sigma_a > 0`` (the fit's
    log-parameters guarantee it)."""
    medium = jaxsss.Medium(sigma_a, sigma_s_prime, eta, fresnel=fresnel)
    z_r, z_v = dipole_depths(medium)
    t_entry = 1.0 - jaxsss.fresnel_reflectance(eta, 1.0)
    sa, ss = sigma_a, sigma_s_prime
    st = sa + ss
    alpha = ss / st
    # sigma_tr = sqrt(3 sigma_a sigma_t') (Jensen et al. 2001, Eq. 5 of the hierarchical paper)
    s = jnp.sqrt(3.0 * sa * st)

    def source(z):
        # Photon-diffusion Eq. 6: E = z (1 + s d) e^{-s d} / (4 pi d^3); and its partial derivatives in z and s.
        d2 = r * r + z * z
        d = jnp.sqrt(d2)
        e = jnp.exp(-s * d)
        damp = (1.0 + s * d) * e
        inv = 1.0 / (4.0 * jnp.pi * d2 * d)
        E = z * damp * inv
        # dE/dz = [g + z^2 g'(d) / d] / (4 pi), g = damp / d^3, g'(d) = -e (s^2 d^2 + 3 (1 + s d)) / d^4
        dE_dz = (damp - z * z * e * (s * s * d2 + 3.0 * (1.0 + s * d)) / d2) * inv
        # dE/ds = -z s e^{-s d} / (4 pi d)
        dE_ds = -z * s * e * d2 * inv
        return E, dE_dz, dE_ds

    E_r, Ez_r, Es_r = source(z_r)
    E_v, Ez_v, Es_v = source(z_v)
    total = E_r + E_v
    Es = Es_r + Es_v

    def d_log(dsa, dst, dalpha):
        # Chain rule for one log-parameter: d(s^2) = 3 (dsa st + sa dst); dz = -z dst / st (z_r, z_v ~ 1 / sigma_t').
        ds = 1.5 * (dsa * st + sa * dst) / s
        dz = -dst / st
        return t_entry * (dalpha * total + alpha * (dz * (z_r * Ez_r + z_v * Ez_v) + ds * Es))

    ratio = alpha * sa / st  # = sigma_a sigma_s' / sigma_t'^2
    dR_dla = d_log(sa, sa, -ratio)  # d/d log sigma_a: d sigma_a = d sigma_t' = sigma_a, d alpha' = -alpha' sa / st
    dR_dls = d_log(0.0, ss, ratio)  # d/d log sigma_s': d sigma_t' = sigma_s', d alpha' = alpha' sa / st
    return t_entry * alpha * total, dR_dla, dR_dls


__all__ = ["dipole_value_and_jac"]
