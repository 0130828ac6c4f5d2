"""Reparameterisation between intuitive and physical parameters (hierarchical paper, Section 4 and Eq. 16).

Forward (what an artist gives): total diffuse reflectance ``Rd`` and diffuse mean free path ``l_d`` (mm) per
channel, with ``eta`` (and optionally ``g``) -> ``sigma_a``, ``sigma_s'`` (1/mm), ``alpha'`` (and ``sigma_s``,
``sigma_t``).

Reverse: ``sigma_a``, ``sigma_s'``, ``eta`` -> ``Rd``, ``l_d``.

Both directions use the dipole's ``Rd`` (Eq. 15) and the medium's ``F_dr`` method (``"poly"`` by default,
``"exact"`` available). With ``u = sqrt(3 (1 - alpha')) = sigma_tr / sigma_t'`` from the inversion, Eq. 16 gives

    sigma_t' = sigma_tr / u,    sigma_a = sigma_t' (1 - alpha') = sigma_tr u / 3,    sigma_s' = alpha' sigma_t',

which stays accurate at both stiff ends (``Rd -> 1``: ``u -> 0`` and ``sigma_t' -> infinity``; ``Rd -> 0``:
``alpha' -> 0``).
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import optimistix as optx

from jaxsss.validate import check_range, trusted_traces
from jaxsss.fresnel import A_coefficient, resolve_fresnel_method
from jaxsss.medium import Medium
from jaxsss.reflectance import invert_rd, medium_total_diffuse_reflectance

__all__ = ["Reparameterisation", "from_rd_ld", "to_rd_ld"]


class Reparameterisation(eqx.Module):
    """Result of :func:`from_rd_ld`.

    Attributes:
        medium: the recovered :class:`Medium` (``sigma_a``, ``sigma_s_prime`` in 1/mm; ``eta``; ``g`` if given).
        alpha_prime: reduced albedo.
        rd: the total diffuse reflectance that was inverted.
        ld: the diffuse mean free path (mm).
        result: ``optimistix.RESULTS`` of the Rd inversion, per channel.
    """

    medium: Medium
    alpha_prime: jax.Array
    rd: jax.Array
    ld: jax.Array
    result: optx.RESULTS

    @property
    def converged(self):
        """Boolean per channel: the Rd inversion converged."""
        return self.result == optx.RESULTS.successful


def from_rd_ld(rd, ld, eta, g=None, *, fresnel: str = "poly", rtol: float | None = None) -> Reparameterisation:
    """(Rd, l_d, eta[, g]) -> (sigma_a, sigma_s', alpha'[, sigma_s, sigma_t]) by Eq. 15 inverted and Eq. 16.

    Args:
        rd: total diffuse reflectance per channel, in ``(0, 1)``.
        ld: diffuse mean free path per channel, mm, ``> 0``.
        eta: relative index ``n_inside / n_outside``, ``> 0``.
        g: optional anisotropy in ``(-1, 1)``; the returned medium then also has ``sigma_s`` and ``sigma_t``.
        fresnel: ``F_dr`` method for ``A`` (``"poly"`` or ``"exact"``).
        rtol: tolerance of the Rd inversion (see :func:`jaxsss.reflectance.invert_rd`).

    Returns:
        :class:`Reparameterisation`; differentiable in ``rd``, ``ld``, ``eta`` and ``g``.
    """
    resolve_fresnel_method(fresnel)
    rd = check_range(rd, "rd", 0.0, 1.0, lo_open=True, hi_open=True, owner="from_rd_ld")
    ld = check_range(ld, "ld", 0.0, None, lo_open=True, owner="from_rd_ld")
    eta = check_range(eta, "eta", 0.0, None, lo_open=True, owner="from_rd_ld")
    inv, sigma_a, sigma_s_prime = _eq16(rd, ld, eta, fresnel, rtol)
    medium = Medium(sigma_a, sigma_s_prime, eta, g, fresnel=fresnel)
    return Reparameterisation(medium=medium, alpha_prime=inv.alpha_prime, rd=rd, ld=ld, result=inv.result)


@partial(jax.jit, static_argnums=(3, 4))
def _eq16(rd, ld, eta, fresnel, rtol):
    """The inversion and Eq. 16 as one compiled program (validated inputs): a process that converts one value
    compiles once (and JAX's persistent cache keeps it) instead of dispatching a dozen small eager operations. The
    inputs were checked on the host, so the traced checks are left out (:func:`~jaxsss.validate.trusted_traces`): a
    program with them holds host callbacks, which the persistent cache does not store."""
    with trusted_traces():
        inv = invert_rd(rd, A_coefficient(eta, fresnel), rtol=rtol, atol=rtol)
    sigma_tr = 1.0 / ld
    # Eq. 16: sigma_t' = sigma_tr / sqrt(3 (1 - alpha')) = sigma_tr / u.
    sigma_t_prime = sigma_tr / inv.u
    # sigma_s' = alpha' sigma_t'; sigma_a = sigma_t' - sigma_s' = sigma_tr u / 3 (no cancellation).
    sigma_s_prime = inv.alpha_prime * sigma_t_prime
    sigma_a = sigma_tr * inv.u / 3.0
    return inv, sigma_a, sigma_s_prime


def to_rd_ld(medium: Medium):
    """(sigma_a, sigma_s', eta) -> ``(Rd, l_d)``: Eq. 15 and ``l_d = 1 / sigma_tr``.

    ``l_d`` is infinite (and ``Rd = 1``) for a non-absorbing medium (``sigma_a = 0``).
    """
    return medium_total_diffuse_reflectance(medium), medium.l_d
