"""The classical dipole diffusion profile for a semi-infinite medium (Jensen et al. 2001).

Normalisation (DESIGN.md, trap 1). :func:`dipole_profile` returns the radiant exitance ``dM_o(r)`` leaving the
surface per unit flux ``dPhi_i`` *entering* the medium at the origin, in 1/mm^2 -- hierarchical paper Eq. 8 with its
``alpha' / (4 pi)`` factor kept (Eq. 13 of that paper divides by alpha'; we never do). Its integral over the plane
is the closed-form total diffuse reflectance ``Rd`` of Eq. 15 (:func:`jaxsss.reflectance.total_diffuse_reflectance`),
a tested identity. Two consequences for users:

- Per *incident* flux (what a measurement of a collimated beam sees), multiply by the entry transmittance
  ``1 - fresnel_reflectance(eta, cos_theta_i)``.
- A renderer turns exitance into radiance so that the radiance integrated over the hemisphere equals ``M_o``
  (the energy-consistent form): ``L_o = F_t(omega) M_o / (pi * F_dt_ext)``, where ``F_dt_ext`` is the cosine-weighted
  hemispherical average of ``F_t``; it is not ``M_o / pi`` divided by ``F_dr`` (a misprint in Eq. 14).

Sources: real source at depth ``z_r = l_u``; virtual (negative) source at height ``z_v = l_u (1 + 4A/3) = l_u + 2 z_b``
above the surface (hierarchical paper, after Eq. 9).
"""

from __future__ import annotations

import equinox as eqx

from jaxsss.validate import check_range
from jaxsss.medium import Medium
from jaxsss.profiles._sources import point_source_exitance_sq

__all__ = ["dipole_profile", "dipole_depths"]


def dipole_depths(medium: Medium):
    """``(z_r, z_v)`` in mm: the real source depth ``l_u`` and the virtual source height ``l_u + 2 z_b``."""
    z_r = medium.l_u
    # Hierarchical paper, after Eq. 9: z_v = l_u (1 + 4A/3) = z_r + 4 A D.
    z_v = z_r + 2.0 * medium.z_b
    return z_r, z_v


def dipole_profile(r, medium: Medium):
    """Dipole diffuse reflectance profile ``R_d(r)`` per unit flux entering the medium.

    Args:
        r: distance from the point of entry, mm, ``>= 0``. Broadcasts against the medium's arrays: for a profile
            over ``N`` radii and ``C`` channels pass ``r`` of shape ``(N, 1)``.
        medium: the :class:`~jaxsss.medium.Medium`.

    Returns:
        ``R_d(r)`` in 1/mm^2, the broadcast shape of ``r`` and the medium.
    """
    # Checked outside the compiled kernel: eagerly for concrete r, by equinox.error_if under a caller's jit.
    return _dipole_profile(check_range(r, "r", 0.0, None, owner="dipole_profile"), medium)


@eqx.filter_jit
def _dipole_profile(r, medium: Medium):
    z_r, z_v = dipole_depths(medium)
    # In sigma_tr^2 = 3 sigma_a sigma_t', not sigma_tr: finite gradients at sigma_a = 0 (profiles/_sources.py).
    s2 = medium.sigma_tr_sq
    # Hierarchical paper Eq. 8-9 (photon-diffusion Eq. 6): real source at depth z_r, negative image at height z_v
    # (E is odd in z, so -E(-z_v) = +E(z_v)).
    return medium.alpha_prime * (point_source_exitance_sq(z_r, r, s2) + point_source_exitance_sq(z_v, r, s2))
