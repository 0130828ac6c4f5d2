"""Dipole and multipole exitance of one diffusion source at an arbitrary depth (photon diffusion, Sections 2-3).

Photon diffusion stores sources wherever photons first scatter, not at one mean free path, and evaluates each with
the depth it has below the *viewed* face. These functions are the profiles of :mod:`jaxsss.profiles.dipole` and
:mod:`jaxsss.profiles.multipole` with the real source's depth ``ell`` as an argument, **per unit source power**: the
source power already carries ``alpha'`` (DESIGN.md trap 2), so ``alpha' * dipole_exitance(r, l_u, m)`` is
:func:`~jaxsss.profiles.dipole.dipole_profile`.

Sources (photon-diffusion Eq. 6 and 12): real source at depth ``ell``, negative image at height ``ell + 2 z_b``
above the surface; for a slab of thickness ``d``, the pairs ``z_{r,i} = 2 i L + ell``, ``z_{v,i} = 2 i L - ell -
2 z_b``, ``L = d + 2 z_b``, ``i = -n..n``. Units mm, 1/mm^2; arguments broadcast (trailing channel axis from the
medium).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range
from jaxsss.medium import Medium
from jaxsss.profiles._sources import point_source_exitance
from jaxsss.profiles.multipole import _check_n_pairs, _check_thickness

__all__ = ["DEFAULT_N_PAIRS", "dipole_exitance", "multipole_exitance"]

DEFAULT_N_PAIRS = 16


def safe_sqrt(s):
    """``sqrt(s)`` for ``s >= 0`` whose derivative at ``s = 0`` is 0 instead of inf (distances in a plane: every
    profile is even in the in-plane offset, so 0 is the right derivative there; without this, 0 * inf = NaN)."""
    pos = s > 0.0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, s, 1.0)), 0.0)


def dipole_exitance(r, depth, medium: Medium):
    """Dipole exitance at distance ``r`` (mm, in the surface) from a unit source at ``depth`` (mm) below it.

    ``E(ell, r) + E(ell + 2 z_b, r)`` (photon-diffusion Eq. 6 without ``alpha'``), in 1/mm^2 per unit source power.
    ``r >= 0``, ``depth >= 0``; broadcast shape of the arguments and the medium.
    """
    r = check_range(r, "r", 0.0, None, owner="dipole_exitance")
    depth = check_range(depth, "depth", 0.0, None, owner="dipole_exitance")
    return _dipole(r, depth, medium)


@eqx.filter_jit
def _dipole(r, ell, medium):
    # Photon-diffusion Eq. 6: real source at ell, negative image at height ell + 2 z_b (E is odd in z).
    return point_source_exitance(ell, r, medium.sigma_tr) + point_source_exitance(ell + 2.0 * medium.z_b, r,
                                                                                  medium.sigma_tr)


def multipole_exitance(r, depth, medium: Medium, thickness, *, n_pairs: int = DEFAULT_N_PAIRS):
    """Multipole exitance through the face a unit source lies ``depth`` below, in a slab of ``thickness`` (Eq. 12-13).

    Args:
        r: distance in the viewed face from the foot of the source, mm, ``>= 0``.
        depth: depth ``ell`` of the source below the viewed face, mm, ``>= 0``.
        medium: the :class:`~jaxsss.medium.Medium`.
        thickness: slab thickness ``d``, mm, finite ``> 0``.
        n_pairs: image pairs on each side of the dipole (static int ``>= 0``). The truncation error falls like
            ``exp(-2 n sigma_tr L)`` with absorption and like ``1/n^2`` without, and radii ``r`` need about ``r / L``
            pairs (see :mod:`jaxsss.profiles.multipole`).

    Returns:
        1/mm^2 per unit source power; the broadcast shape. ``n_pairs = 0`` is :func:`dipole_exitance`.
    """
    owner = "multipole_exitance"
    n = _check_n_pairs(n_pairs, owner)
    r = check_range(r, "r", 0.0, None, owner=owner)
    depth = check_range(depth, "depth", 0.0, None, owner=owner)
    d = _check_thickness(thickness, owner)
    return _multipole(r, depth, medium, d, n)


def _multipole_sum(r, ell, medium, d, n_pairs):
    sigma_tr, z_b = medium.sigma_tr, medium.z_b
    # L = d + 2 z_b = d + 4 A D (trap 4).
    L = d + 2.0 * z_b
    shape = jnp.broadcast_shapes(jnp.shape(r), jnp.shape(ell), jnp.shape(L), jnp.shape(sigma_tr))

    def add_pair(k, acc):
        i = (k - n_pairs).astype(jnp.result_type(L))
        # Photon-diffusion Eq. 12 with ell the depth of the real source.
        z_r = 2.0 * i * L + ell
        z_v = 2.0 * i * L - ell - 2.0 * z_b
        # Eq. 13: real sources minus virtual (negative) sources.
        return acc + point_source_exitance(z_r, r, sigma_tr) - point_source_exitance(z_v, r, sigma_tr)

    return jax.lax.fori_loop(0, 2 * n_pairs + 1, add_pair, jnp.zeros(shape, jnp.result_type(r, ell, L)))


_multipole = eqx.filter_jit(_multipole_sum)
