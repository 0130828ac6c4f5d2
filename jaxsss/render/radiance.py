"""The material-dependent half of the renderer: pure JAX functions of arrays, differentiable in the medium.

Everything geometric (positions, normals, cosines, light irradiance, interaction lists) arrives as arrays computed
once in NumPy; everything that depends on ``sigma_a``, ``sigma_s'``, ``eta`` or ``g`` is here. Channels are the
trailing axis ``C``. Units: mm, 1/mm, W, sr.

Normalisation (DESIGN.md, trap 1), the choice made for every term below:

- **Entry.** The flux entering at an irradiance sample ``p`` is ``Phi_p = A_p t_p sum_l F_t(eta, cos_lp) E_lp`` with
  the exact Fresnel transmittance of each light's direction (the hierarchical paper uses the diffuse ``F_dt`` instead,
  its Eq. 13; for a light of known direction the exact transmittance is the better estimate), plus
  ``F_dt,ext(eta) E_ind`` for diffuse indirect irradiance. ``t_p`` is the texture multiplier.
- **Transport.** ``M_o(x) = sum_p Phi_p R_d(|x - P_p|)``, with ``R_d`` the dipole per unit *entering* flux (alpha'
  /(4 pi) kept; :func:`jaxsss.dipole_profile`).
- **Near field** (our addition to the paper). The dipole's peak (width ``z_r = l_u``) is narrower than the paper's
  sample spacing (``A / (pi l_u^2)`` samples are about ``1.8 l_u`` apart), so point sums there are noisy. Each
  (query, sample) pair closer than ``rho_0`` (a few sample radii) is split by a smooth weight
  ``w(r) = 1 - 3 t^2 + 2 t^3``, ``t = r / rho_0``: the part ``w`` is spread evenly over the neighbourhood and
  integrated exactly, the part ``1 - w`` is summed point by point,
  ``M_near = (sum w_p Phi_p / sum w_p A_p) I_w + sum (1 - w_p) Phi_p R_d(r_p)`` with
  ``I_w = int_0^rho_0 w(r) 2 pi r R_d(r) dr`` (:func:`weighted_disc_integral`). ``(1 - w) R_d`` vanishes at ``r = 0``
  and joins the far field smoothly at ``rho_0``, so what is left to point sampling is smooth. On a uniformly lit plane
  at the paper's density the pixel-to-pixel error of ``M_o`` is 8-12% with point sums and about 1% with this split
  (stratified samples, ``rho_0`` = 4 sample radii), falling with density (docs/architecture.md).
- **Exit.** ``L_o(x, w) = F_t(eta, cos_o) M_o(x) / (pi F_dt,ext(eta))`` where ``F_dt,ext = 1 - F_dr(1/eta)`` is the
  cosine-weighted hemispherical average of the outside transmittance, so that ``int L_o cos dw = M_o`` exactly (a
  tested identity). The hierarchical paper's Eq. 14 divides by ``F_dr``; that is a misprint.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss.fresnel import fresnel_unpolarised, refract, resolve_fresnel_method, snell_cosine
from jaxsss.medium import Medium
from jaxsss.phase import hg_phase
from jaxsss.profiles.dipole import dipole_depths
from jaxsss.profiles.point_sources import point_source_exitance
from jaxsss.reflectance import medium_total_diffuse_reflectance

__all__ = [
    "DipoleKernel",
    "F_dt_external",
    "diffuse_albedo",
    "dipole_gradient_factor",
    "disc_integral",
    "entity_flux",
    "exit_radiance",
    "exitance_direct",
    "exitance_gradient_pairs",
    "exitance_near",
    "exitance_near_gradient",
    "exitance_pairs",
    "hg_phase",
    "near_weight",
    "near_weight_gradient_factor",
    "scan_pairs",
    "single_scattering",
    "single_scattering_share",
    "specular_ggx",
    "transmitted_flux",
    "weighted_disc_integral",
]


def _dipole(r, medium: Medium):
    """The dipole profile ``R_d(r)`` (:func:`jaxsss.profiles.dipole_profile`) without its input check, for the
    sums' inner loops (``r`` is a distance, never negative)."""
    z_r, z_v = dipole_depths(medium)
    # Hierarchical paper Eq. 8-9: the real source at z_r and its image at z_v.
    return medium.alpha_prime * (point_source_exitance(z_r, r, medium.sigma_tr)
                                 + point_source_exitance(z_v, r, medium.sigma_tr))


class DipoleKernel(eqx.Module):
    """The dipole as a kernel of the sums (the interface :mod:`jaxsss.render.bssrdf` kernels share):
    ``pair(delta, flux)`` is ``R_d(|delta|) Phi`` per pair, ``(P, C)``, for the offsets ``delta = x - P`` ``(P, 3)``
    mm; ``disc(spread, rho0)`` the near field's ``E I_w``, ``(Q, C)``; ``value_shape(flux_shape)`` the trailing shape
    of one pair's value."""

    medium: Medium

    def sources(self, flux):
        """What the sums gather per entity: the flux itself."""
        return flux

    def pair(self, delta, flux, normals=None, weights=None):
        """``R_d(|delta|) Phi``; ``normals`` (the white kernels' curvature) are ignored (the dipole stays flat) and exit
        ``weights`` refused (:meth:`value_shape`)."""
        _no_weights(weights)
        r = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))
        return _dipole(r[:, None], self.medium) * flux

    def disc(self, spread, rho0):
        return spread * weighted_disc_integral(rho0, self.medium)

    def near_terms(self, delta, flux, area, rho0, normals=None, weights=None):
        """A near pair's ``(point, w Phi, w A)`` (module docstring's split): the point part ``(1 - w) R_d Phi`` and the
        weighted flux and area the disc averages."""
        _no_weights(weights)
        r = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))
        w = near_weight(r, rho0)
        return self.pair(delta, _per_pair(1.0 - w, flux) * flux), _per_pair(w, flux) * flux, w * area

    def value_shape(self, flux_shape, weighted: bool = False):
        """One pair's value: the flux's trailing shape (``weighted``: the sums pass exit weights; the dipole takes
        none, :meth:`jaxsss.render.bssrdf.WhiteKernel.value_shape`)."""
        if weighted:
            raise ValueError(_NO_WEIGHTS)
        return tuple(flux_shape[1:])


_NO_WEIGHTS = "DipoleKernel: exit weights are for the white kernels' nodes; the dipole sums exitance"


def _no_weights(weights) -> None:
    if weights is not None:
        raise ValueError(_NO_WEIGHTS)


def _kernel(medium: Medium, kernel, shared_channel: bool):
    """``kernel``, or the dipole of ``medium`` (one channel when the plan shares it)."""
    return DipoleKernel(_kernel_medium(medium, shared_channel)) if kernel is None else kernel


def _per_pair(v, flux):
    """``v`` (``(P,)``, or already with some of the flux's trailing axes) broadcast against a pair flux ``(P, ...)``."""
    return v.reshape(v.shape + (1,) * (flux.ndim - v.ndim))


def _transmittance(eta, cos_outside):
    """Fresnel transmittance ``1 - F(eta, cos)`` for light crossing the boundary at outside angle ``cos``."""
    return 1.0 - fresnel_unpolarised(jnp.clip(cos_outside, 0.0, 1.0), eta)


def F_dt_external(eta, fresnel: str = "poly"):
    """``1 - F_dr(1/eta)``: diffuse transmittance for light arriving from outside (cosine-weighted average of
    ``F_t``), equal to ``eta^2 (1 - F_dr(eta))`` by reciprocity (exactly so for ``fresnel="exact"``)."""
    return 1.0 - resolve_fresnel_method(fresnel)(1.0 / eta)


def diffuse_albedo(medium: Medium):
    """``rho = F_dt,ext Rd``: the fraction of diffuse irradiance on the surface that the medium sends back out
    diffusely (Eq. 15's total diffuse reflectance, entered through the boundary's hemispherical transmittance); the
    object's bounce off itself (:func:`jaxsss.render.samples.self_irradiance`) reaches it again with this albedo."""
    return F_dt_external(medium.eta, medium.fresnel) * medium_total_diffuse_reflectance(medium)


def transmitted_flux(medium: Medium, areas, light_cos, light_irradiance, indirect=None, texture=None):
    """Flux entering the medium at each irradiance sample, W.

    Args:
        medium: the :class:`~jaxsss.medium.Medium` (its ``eta`` is used).
        areas: ``(N,)`` sample areas, mm^2.
        light_cos: ``(N, L)`` cosine towards each light.
        light_irradiance: ``(N, L, C)`` incident irradiance per light, W/mm^2 (cosine and shadowing included).
        indirect: optional ``(N, C)`` diffuse indirect irradiance, W/mm^2.
        texture: optional ``(N, C)`` multiplier.

    Returns:
        ``(N, C)``.
    """
    eta = medium.eta
    # Entry: exact Fresnel transmittance per light direction.
    e_t = jnp.sum(_transmittance(eta, light_cos)[..., None] * light_irradiance, axis=1)
    if indirect is not None:
        # Diffuse indirect light enters with the hemispherical average F_dt,ext.
        e_t = e_t + F_dt_external(eta, medium.fresnel) * indirect
    if texture is not None:
        e_t = e_t * texture
    return areas[:, None] * e_t


def disc_integral(rho0, medium: Medium):
    """``int_0^rho0 2 pi r R_d(r) dr``: the dipole integrated over a disc of radius ``rho0`` (mm) about the point of
    entry, dimensionless; tends to ``Rd`` (Eq. 15) as ``rho0 -> inf``.

    Each source at depth ``z`` contributes ``alpha'/(4 pi) 2 pi z (e^{-s z}/z - e^{-s d0}/d0)`` with ``s = sigma_tr``
    and ``d0 = sqrt(rho0^2 + z^2)``, since ``d/dd (-e^{-s d}/d) = (1 + s d) e^{-s d}/d^2`` and ``r dr = d dd``.
    """
    from jaxsss.profiles.dipole import dipole_depths

    z_r, z_v = dipole_depths(medium)
    s = medium.sigma_tr

    def term(z):
        d0 = jnp.sqrt(rho0 * rho0 + z * z)
        gap = rho0 * rho0 / (d0 + z)  # d0 - z without cancellation
        # Hierarchical paper Eq. 8 integrated over the disc, one source at a time:
        # e^{-s z} - (z/d0) e^{-s d0} = e^{-s z} [(1 - z/d0) + (z/d0)(1 - e^{-s (d0 - z)})], both parts >= 0.
        return 2.0 * jnp.pi * jnp.exp(-s * z) * (gap / d0 - (z / d0) * jnp.expm1(-s * gap))

    return medium.alpha_prime / (4.0 * jnp.pi) * (term(z_r) + term(z_v))


def entity_flux(sample_flux_sorted, start, stop):
    """Flux of every octree entity (samples then internal nodes): sums over each entity's contiguous sample range.

    Args:
        sample_flux_sorted: ``(N, C)`` per-sample flux in the octree's (Morton) order.
        start, stop: ``(N + M,)`` sample ranges of the entities.
    """
    zero = jnp.zeros((1,) + sample_flux_sorted.shape[1:], sample_flux_sorted.dtype)
    cs = jnp.concatenate([zero, jnp.cumsum(sample_flux_sorted, axis=0)])
    n = sample_flux_sorted.shape[0]
    # Samples take their own value (exact); internal nodes the cumulative-sum difference.
    return jnp.concatenate([sample_flux_sorted, cs[stop[n:]] - cs[start[n:]]])


def _safe_distance(a, b):
    d2 = jnp.sum((a - b) ** 2, axis=-1)
    return jnp.sqrt(jnp.maximum(d2, 1e-300))


def _kernel_medium(medium: Medium, shared_channel: bool) -> Medium:
    """The medium whose profile is evaluated: one channel when all channels share parameters (the plan says so)."""
    if not shared_channel:
        return medium
    return eqx.tree_at(
        lambda m: (m.sigma_a, m.sigma_s_prime),
        medium,
        (medium.sigma_a[..., :1], medium.sigma_s_prime[..., :1]),
    )


def near_weight(r, rho0):
    """The near-field split weight ``w = 1 - 3 t^2 + 2 t^3`` with ``t = min(r / rho0, 1)`` (1 at 0, 0 beyond rho0)."""
    positive = rho0 > 0
    t = jnp.where(positive, jnp.clip(r / jnp.where(positive, rho0, 1.0), 0.0, 1.0), 1.0)  # rho0 = 0: no near field
    return 1.0 - t * t * (3.0 - 2.0 * t)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)
_GL_T, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W  # nodes and weights on [0, 1]


def weighted_disc_integral(rho0, medium: Medium):
    """``I_w = int_0^rho0 w(r) 2 pi r R_d(r) dr`` with the split weight of :func:`near_weight`, dimensionless.

    By parts with the closed-form cumulative ``F(r) = int_0^r 2 pi r' R_d dr'`` (:func:`disc_integral`):
    ``I_w = -int_0^rho0 F(r) w'(r) dr = int_0^1 F(rho0 t) 6 t (1 - t) dt``, a smooth integrand (24-node
    Gauss-Legendre, accurate to ~1e-12 relative).
    """
    t = jnp.asarray(_GL_T).reshape((-1,) + (1,) * jnp.ndim(medium.sigma_tr))
    w = jnp.asarray(_GL_W).reshape(t.shape)
    return jnp.sum(w * 6.0 * t * (1.0 - t) * disc_integral(rho0 * t, medium), axis=0)


def exitance_near(medium: Medium, query_pos, sample_pos, sample_area, sample_flux, near_query, near_sample, rho0,
                  *, shared_channel=False, kernel=None, normals=None, weights=None):
    """The near-field part of ``M_o`` (module docstring), ``(Q, C)`` (``(Q, K, C)`` for a kernel with incidence
    nodes, :class:`jaxsss.render.bssrdf.WhiteKernel`).

    Args:
        query_pos: ``(Q, 3)`` mm.
        sample_pos, sample_area, sample_flux: ``(N, 3)``, ``(N,)`` and ``(N, C)``.
        near_query, near_sample: ``(K,)`` the (query, sample) pairs closer than ``rho0`` (padding: query ``Q``),
            query indices ascending.
        rho0: the near-field radius, mm.
        kernel: the profile (:class:`DipoleKernel` of ``medium`` by default; :mod:`jaxsss.render.bssrdf`), whose
            sample flux may carry extra axes (``(N, K, C)``).
        normals: optional ``(query normals (Q, 3), sample normals (N, 3))``: the pairs' curvature for a kernel that
            corrects for it (:mod:`jaxsss.render.curvature`; the dipole ignores them).
        weights: optional ``(Q, J, C)`` exit weights of a white kernel's nodes
            (:func:`jaxsss.render.bssrdf.exit_weights`): the result is then the diffusion radiance ``(Q, C)``,
            W/(mm^2 sr), each pair's nodes added as radiance (:meth:`jaxsss.render.bssrdf.WhiteKernel.pair`).
    """
    n_q = query_pos.shape[0]
    kernel = _kernel(medium, kernel, shared_channel)
    query = jnp.minimum(near_query, n_q - 1)
    delta = query_pos[query] - sample_pos[near_sample]

    def seg(v):
        return jax.ops.segment_sum(v, near_query, num_segments=n_q + 1, indices_are_sorted=True)[:n_q]

    pair_normals = None if normals is None else (normals[0][query], normals[1][near_sample])
    point, w_flux, w_area = kernel.near_terms(delta, kernel.sources(sample_flux)[near_sample],
                                              sample_area[near_sample], rho0, pair_normals,
                                              None if weights is None else weights[query])
    area = seg(w_area)
    spread = seg(w_flux) / _per_pair(jnp.where(area > 0, area, 1.0), w_flux)
    return _weighted(kernel, kernel.disc(spread, rho0), weights) + _parts(seg(point))


def _parts(summed):
    """A white kernel's sums with the exit's current, one complex value per channel (the exitance's part real, the
    current's imaginary; :meth:`jaxsss.render.bssrdf.WhiteKernel.pair`), as the ``(Q, 2, C)`` parts the renderer
    takes (:func:`jaxsss.render.bssrdf.current_radiance`); real sums unchanged. Unpacked after the sum over the pairs,
    so that each pair's profile is evaluated once."""
    return jnp.stack([summed.real, summed.imag], axis=1) if jnp.iscomplexobj(summed) else summed


def _weighted(kernel, exitance, weights):
    """``(Q, J, C)`` node exitances as radiance by the exit ``weights`` (None: unchanged;
    :meth:`jaxsss.render.bssrdf.WhiteKernel.rows_radiance`)."""
    return exitance if weights is None else kernel.rows_radiance(exitance, weights)


def exitance_pairs(medium: Medium, query_pos, ent_pos, ent_flux, pair_query, pair_entity, *, shared_channel=False,
                   kernel=None, normals=None, weights=None):
    """Radiant exitance ``M_o`` (W/mm^2) at every query point, summed over an interaction list.

    ``M_o(x_q) = sum_{k: q_k = q} Phi_{e_k} R_d(|x_q - P_{e_k}|)`` (hierarchical paper Eq. 8 and 13, with the
    normalisation in the module docstring).

    Args:
        medium: the medium.
        query_pos: ``(Q, 3)`` mm.
        ent_pos: ``(E, 3)`` entity positions (sample positions or node centroids), mm.
        ent_flux: ``(E, C)`` entity flux, W.
        pair_query, pair_entity: ``(B, K)`` int32 pair lists in ``B`` blocks of ``K`` (padding pairs have
            ``pair_query = Q``); query indices ascending.
        shared_channel: evaluate the profile once for all channels (identical channel parameters).
        kernel: the profile (default the dipole of ``medium``; see :func:`exitance_near`).
        normals: optional ``(query normals (Q, 3), entity normals (E, 3))`` (see :func:`exitance_near`).
        weights: optional ``(Q, J, C)`` exit weights of a white kernel (see :func:`exitance_near`): the result is
            then radiance ``(Q, C)``.

    Returns:
        ``(Q, C)`` (``(Q,) + kernel.value_shape``). The blocks are summed in a ``lax.scan`` whose body is
        rematerialised in reverse mode, so memory stays at one block.
    """
    n_q = query_pos.shape[0]
    kernel = _kernel(medium, kernel, shared_channel)
    sources = kernel.sources(ent_flux)

    def contrib(q, e):
        # Hierarchical paper Eq. 13: each entity contributes Phi_v R_d(|x - P_v|).
        return kernel.pair(query_pos[q] - ent_pos[e], sources[e],
                           None if normals is None else (normals[0][q], normals[1][e]),
                           None if weights is None else weights[q])

    # One pair's value as the kernel gives it (one complex value per channel with the exit's current, _parts).
    value = jax.eval_shape(contrib, pair_query[0], pair_entity[0])
    return _parts(scan_pairs(contrib, n_q, value.shape[1:], value.dtype, pair_query, pair_entity))


def scan_pairs(contrib, n_queries: int, value_shape: tuple, dtype, pair_query, pair_entity):
    """``sum_{k: q_k = q} contrib(q_k, e_k)`` for every query: an interaction list in ``B`` blocks of ``K`` pairs,
    summed block by block in a ``lax.scan`` whose body is rematerialised in reverse mode (memory: one block).

    Args:
        contrib: ``(q, e) -> (K, *value_shape)``, the pairs' values (``q`` already clipped to valid queries).
        n_queries: ``Q``.
        value_shape: trailing shape of one pair's value (e.g. ``(C,)`` or ``(3, C)``).
        dtype: of the result.
        pair_query, pair_entity: ``(B, K)`` int32; padding pairs have ``pair_query = Q`` (they land in a dropped
            extra row); query indices ascending within each block.

    Returns:
        ``(Q, *value_shape)``.
    """

    @jax.checkpoint
    def block(q, e):
        return jax.ops.segment_sum(contrib(jnp.minimum(q, n_queries - 1), e), q, num_segments=n_queries + 1,
                                   indices_are_sorted=True)

    def step(acc, qe):
        return acc + block(*qe), None

    init = jnp.zeros((n_queries + 1, *value_shape), dtype)
    acc, _ = jax.lax.scan(step, init, (pair_query, pair_entity))
    return acc[:n_queries]


def dipole_gradient_factor(r, medium: Medium):
    """``g(r)`` with ``grad_x R_d(|x - p|) = g(r) (x - p)``, in 1/mm^4 (caching paper Eq. 9 for the dipole kernel):

    ``g = -alpha'/(4 pi) sum_{z in (z_r, z_v)} z e^{-sigma_tr d} (sigma_tr^2 d^2 + 3 sigma_tr d + 3) / d^5`` with
    ``d = sqrt(r^2 + z^2)``, from ``d/dd[(1 + s d) e^{-s d} / d^3] = -e^{-s d} (s^2 d^2 + 3 s d + 3) / d^4`` and
    ``dd/dr = r / d``. (The caching paper's Eq. 6 prints ``p_y - x`` for ``p_y - y``; trap 7.)
    """
    from jaxsss.profiles.dipole import dipole_depths

    z_r, z_v = dipole_depths(medium)
    s = medium.sigma_tr

    def term(z):
        d2 = r * r + z * z
        d = jnp.sqrt(d2)
        sd = s * d
        return z * jnp.exp(-sd) * (sd * sd + 3.0 * sd + 3.0) / (d2 * d2 * d)

    return -medium.alpha_prime / (4.0 * jnp.pi) * (term(z_r) + term(z_v))


def near_weight_gradient_factor(r, rho0):
    """``h(r)`` with ``grad_x w(|x - p|) = h(r) (x - p)`` for :func:`near_weight`: ``-6 (1 - t) / rho0^2`` inside
    ``rho0``, 0 outside (finite at ``r = 0``)."""
    positive = rho0 > 0
    safe = jnp.where(positive, rho0, 1.0)
    t = r / safe
    return jnp.where(positive & (t < 1.0), -6.0 * (1.0 - t) / (safe * safe), 0.0)


def exitance_gradient_pairs(medium: Medium, query_pos, ent_pos, ent_flux, pair_query, pair_entity):
    """Analytic gradient of the far-field sum of :func:`exitance_pairs` with respect to the query position,
    ``(Q, 3, C)`` W/mm^3: ``sum_k Phi_{e_k} g(r_k) (x_q - P_{e_k})`` (caching paper Eq. 9, summed through the same
    hierarchical interaction list)."""
    n_q = query_pos.shape[0]

    def contrib(q, e):
        delta = query_pos[q] - ent_pos[e]
        r = _safe_distance(query_pos[q], ent_pos[e])
        g = dipole_gradient_factor(r[:, None], medium) * ent_flux[e]  # (K, C)
        return delta[:, :, None] * g[:, None, :]

    return scan_pairs(contrib, n_q, (3, ent_flux.shape[-1]), ent_flux.dtype, pair_query, pair_entity)


def exitance_near_gradient(medium: Medium, query_pos, sample_pos, sample_area, sample_flux, near_query, near_sample,
                           rho0):
    """Analytic gradient of :func:`exitance_near` with respect to the query position, ``(Q, 3, C)``.

    With ``E = sum w Phi / sum w A``: ``grad = I_w (sum grad(w) Phi - E sum grad(w) A) / sum w A
    + sum Phi [-grad(w) R_d + (1 - w) g (x - p)]``.
    """
    n_q = query_pos.shape[0]
    x = query_pos[jnp.minimum(near_query, n_q - 1)]
    delta = x - sample_pos[near_sample]
    r = _safe_distance(x, sample_pos[near_sample])
    w = near_weight(r, rho0)
    dw = near_weight_gradient_factor(r, rho0)[:, None] * delta  # (K, 3)
    flux = sample_flux[near_sample]  # (K, C)
    area = sample_area[near_sample]

    def seg(v):
        return jax.ops.segment_sum(v, near_query, num_segments=n_q + 1, indices_are_sorted=True)[:n_q]

    wa = seg(w * area)
    safe_wa = jnp.where(wa > 0, wa, 1.0)
    e_mean = seg(w[:, None] * flux) / safe_wa[:, None]  # (Q, C)
    grad_e = (seg(dw[:, :, None] * flux[:, None, :]) - e_mean[:, None, :] * seg(dw * area[:, None])[:, :, None]) \
        / safe_wa[:, None, None]
    prof = _dipole(r[:, None], medium)  # (K, C)
    g = dipole_gradient_factor(r[:, None], medium)  # (K, C)
    point = seg(flux[:, None, :] * (-dw[:, :, None] * prof[:, None, :] + (1.0 - w)[:, None, None]
                                    * g[:, None, :] * delta[:, :, None]))
    return grad_e * weighted_disc_integral(rho0, medium) + point


DIRECT_PAIRS = 1 << 18
"""The direct sum's (query, sample) pairs per block at most (:func:`exitance_direct`)."""


def exitance_direct(medium: Medium, query_pos, sample_pos, sample_flux, sample_area, rho0, *, block: int = 64,
                    shared_channel=False, kernel=None, normals=None, weights=None):
    """Brute-force ``M_o`` at every query point from every sample (the reference method), ``(Q, C)`` (``(Q,) +
    kernel.value_shape``), with the same
    near-field split (radius ``rho0``, mm; 0 for pure point sums) as the hierarchical method.

    Queries are processed in blocks of ``block`` against all ``N`` samples (memory ``block * N`` times the size of
    one sample's flux). ``kernel``, ``normals`` and ``weights``: as in :func:`exitance_near`.
    """
    n_q = query_pos.shape[0]
    # At most DIRECT_PAIRS (query, sample) pairs per block: a white kernel keeps a few dozen (P, K, C) arrays per
    # pair (profile, curvature, the cut beam's lookups), and 64 queries against the teapot's samples took 23 GB.
    block = max(1, min(block, DIRECT_PAIRS // max(sample_pos.shape[0], 1)))
    pad = (-n_q) % block
    qp = jnp.concatenate([query_pos, jnp.broadcast_to(query_pos[:1], (pad, 3))]).reshape(-1, block, 3)
    width = None if normals is None else normals[0].shape[1]  # 3, or 7 with the eye's chord (bssrdf.WhiteKernel)
    qn = None if normals is None else jnp.concatenate(
        [normals[0], jnp.broadcast_to(normals[0][:1], (pad, width))]).reshape(-1, block, width)
    qw = None if weights is None else jnp.concatenate(
        [weights, jnp.broadcast_to(weights[:1], (pad,) + weights.shape[1:])]).reshape((-1, block) + weights.shape[1:])
    kernel = _kernel(medium, kernel, shared_channel)
    n_s = sample_pos.shape[0]
    sources = kernel.sources(sample_flux)

    @jax.checkpoint
    def one(args):
        q, n, w = args
        delta = (q[:, None, :] - sample_pos[None, :, :]).reshape(-1, 3)  # (block * N, 3)
        flux = jnp.broadcast_to(sources[None], (q.shape[0],) + sources.shape)
        area = jnp.broadcast_to(sample_area[None], (q.shape[0], n_s)).reshape(-1)
        pair_normals = None if n is None else (jnp.repeat(n, n_s, axis=0),
                                               jnp.tile(normals[1][:n_s], (q.shape[0], 1)))
        point, w_flux, w_area = kernel.near_terms(delta, flux.reshape((-1,) + sources.shape[1:]), area, rho0,
                                                  pair_normals, None if w is None else jnp.repeat(w, n_s, axis=0))

        def per_query(v):
            return jnp.sum(v.reshape((q.shape[0], n_s) + v.shape[1:]), axis=1)

        w_area = per_query(w_area)
        spread = per_query(w_flux) / _per_pair(jnp.where(w_area > 0, w_area, 1.0), per_query(w_flux))
        return _parts(per_query(point)) + _weighted(kernel, kernel.disc(spread, rho0), w)

    shape = kernel.value_shape(sample_flux.shape, weights is not None)
    return jax.lax.map(one, (qp, qn, qw)).reshape((-1,) + shape)[:n_q]


def exit_radiance(medium: Medium, exitance, cos_o):
    """Diffuse radiance leaving the surface towards the eye, W/(mm^2 sr): ``F_t(cos_o) M_o / (pi F_dt,ext)``.

    Args:
        exitance: ``(Q, C)`` radiant exitance ``M_o``.
        cos_o: ``(Q,)`` cosine between the normal and the direction to the eye.
    """
    # Energy-consistent exit (module docstring; hierarchical paper Eq. 14 corrected).
    scale = _transmittance(medium.eta, cos_o) / (jnp.pi * F_dt_external(medium.eta, medium.fresnel))
    return scale[:, None] * exitance


def _refract_in(to_source, normal, eta):
    """``(t, cos_t, ok)``: direction of travel inside the medium of light arriving from ``to_source`` (unit vector
    from the surface towards where the light comes from), the cosine of the refracted angle, and False under total
    internal reflection (possible for ``eta < 1``)."""
    cos_i = jnp.clip(jnp.sum(to_source * normal, axis=-1), 0.0, 1.0)
    cos_t, ok = snell_cosine(cos_i, eta)
    return refract(-to_source, normal, cos_i, cos_t, eta), cos_t, ok


def _phase_params(medium: Medium):
    """``(g, single-scattering albedo sigma_s / sigma_t)``; ``g = 0`` when the medium has none."""
    g = jnp.zeros_like(medium.sigma_s_prime) if medium.g is None else medium.g * jnp.ones_like(medium.sigma_s_prime)
    sigma_s = medium.sigma_s_prime / (1.0 - g)
    return g, sigma_s / (medium.sigma_a + sigma_s)


def single_scattering(medium: Medium, normal, to_eye, to_light, light_irradiance):
    """Single-scattering radiance, W/(mm^2 sr), by the Hanrahan-Krueger BRDF of a semi-infinite medium.

    ``f_r^(1) = alpha F_t(cos_i) F_t(cos_o) p(w_i' . w_o') / (cos_i' + cos_o')`` with primes for the refracted
    directions and ``alpha = sigma_s / sigma_t`` (Hanrahan and Krueger 1993; Jensen et al. 2001 Eq. 5 integrated
    along the refracted ray for a flat boundary). ``L^(1) = sum_l f_r^(1) E_l``.

    Args:
        normal, to_eye: ``(Q, 3)`` unit vectors.
        to_light: ``(Q, L, 3)`` unit vectors towards each light.
        light_irradiance: ``(Q, L, C)`` irradiance per light (cosine and shadowing included).
    """
    eta = medium.eta
    g, albedo = _phase_params(medium)
    n = normal[:, None, :]
    t_i, cos_ti, ok_i = _refract_in(to_light, n, eta)
    t_o, cos_to, ok_o = _refract_in(to_eye[:, None, :], n, eta)
    # Light travels along t_i, scatters, and travels along -t_o towards the exit point.
    cos_scatter = jnp.sum(t_i * (-t_o), axis=-1)
    cos_i = jnp.sum(to_light * n, axis=-1)
    cos_o = jnp.sum(to_eye[:, None, :] * n, axis=-1)
    fres = _transmittance(eta, cos_i) * _transmittance(eta, cos_o)
    denom = jnp.maximum(cos_ti + cos_to, 1e-12)
    ok = ok_i & ok_o & (cos_i > 0) & (cos_o > 0)
    # Hanrahan-Krueger single-scattering BRDF (semi-infinite layer).
    f = jnp.where(ok, fres / denom, 0.0)[..., None] * albedo * hg_phase(cos_scatter[..., None], g)
    return jnp.sum(f * light_irradiance, axis=1)


def specular_ggx(medium: Medium, normal, to_eye, to_light, light_irradiance, roughness):
    """Specular highlights off the smooth-ish boundary, W/(mm^2 sr): GGX microfacets with Smith masking and the
    exact Fresnel reflectance ``F(eta, h . l)``; ``L_s = sum_l D G F / (4 cos_l cos_o) E_l``."""
    a2 = roughness**2
    n = normal[:, None, :]
    v = to_eye[:, None, :]
    h = to_light + v
    h = h / jnp.maximum(jnp.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    cos_l = jnp.clip(jnp.sum(to_light * n, axis=-1), 0.0, 1.0)
    cos_v = jnp.clip(jnp.sum(v * n, axis=-1), 0.0, 1.0)
    cos_h = jnp.clip(jnp.sum(h * n, axis=-1), 0.0, 1.0)
    # GGX (Trowbridge-Reitz) normal distribution.
    D = a2 / (jnp.pi * (cos_h**2 * (a2 - 1.0) + 1.0) ** 2)

    def g1(c):
        return 2.0 * c / jnp.maximum(c + jnp.sqrt(a2 + (1.0 - a2) * c * c), 1e-12)

    F = fresnel_unpolarised(jnp.clip(jnp.sum(h * to_light, axis=-1), 0.0, 1.0), medium.eta)
    f = jnp.where((cos_l > 0) & (cos_v > 0), D * g1(cos_l) * g1(cos_v) * F / jnp.maximum(4.0 * cos_l * cos_v, 1e-12),
                  0.0)
    return jnp.sum(f[..., None] * light_irradiance, axis=1)


@eqx.filter_jit
def single_scattering_share(medium: Medium, mus=(1.0, 0.7, 0.4, 0.15)):
    """Conservative share of single scattering in the radiance leaving the surface, per channel.

    For uniform light from direction ``mu_i`` on a flat surface, the diffuse radiance towards ``mu_o`` is
    ``F_t(mu_i) mu_i Rd F_t(mu_o) / (pi F_dt,ext)`` and the single-scattering radiance is the Hanrahan-Krueger
    ``f_r^(1) mu_i``. The share is ``L1 / (L1 + Ld)``, maximised over ``mu_i, mu_o`` in ``mus`` and the azimuths 0 and
    pi (backward and forward), since the term peaks at grazing angles. The scene plan leaves the term out when this is
    below its tolerance.
    """
    mu = jnp.asarray(mus)
    sin = jnp.sqrt(1.0 - mu**2)
    # All (mu_i, mu_o, azimuth) combinations, flattened into Q points with one light each.
    mi, mo, az = (a.reshape(-1) for a in jnp.meshgrid(jnp.arange(mu.shape[0]), jnp.arange(mu.shape[0]),
                                                       jnp.array([1.0, -1.0]), indexing="ij"))
    to_light = jnp.stack([sin[mi], jnp.zeros_like(mi, dtype=mu.dtype), mu[mi]], axis=-1)[:, None, :]
    to_eye = jnp.stack([az * sin[mo], jnp.zeros_like(mo, dtype=mu.dtype), mu[mo]], axis=-1)
    q = to_eye.shape[0]
    normal = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (q, 3))
    n_c = jnp.broadcast_shapes(jnp.shape(medium.sigma_a), jnp.shape(medium.sigma_s_prime), (1,))[-1]
    irradiance = jnp.broadcast_to(mu[mi][:, None, None], (q, 1, n_c))  # E = mu_i for unit radiant flux density
    l1 = single_scattering(medium, normal, to_eye, to_light, irradiance)
    m_o = (_transmittance(medium.eta, mu[mi]) * mu[mi])[:, None] * medium_total_diffuse_reflectance(medium)
    ld = exit_radiance(medium, m_o * jnp.ones((q, n_c)), mu[mo])
    total = l1 + ld
    # A channel with no scattering (sigma_s' = 0) reflects nothing either way: share 0, not 0/0.
    return jnp.max(jnp.where(total > 0, l1 / jnp.where(total > 0, total, 1.0), 0.0), axis=0)
