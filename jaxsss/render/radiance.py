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
- **Exit.** ``L_o(x, w) = F_t(eta, cos_o) M_o(x) / (pi F_dt,ext(eta))`` where ``F_dt,ext = 1 - F_dr(1/eta)`` is the
  cosine-weighted hemispherical average of the outside transmittance, so that ``int L_o cos dw = M_o`` exactly (a
  tested identity). The hierarchical paper's Eq. 14 divides by ``F_dr``; that is a misprint.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxsss.fresnel import _fresnel_unpolarised, resolve_fresnel_method
from jaxsss.medium import Medium
from jaxsss.profiles.dipole import _dipole_profile
from jaxsss.reflectance import medium_total_diffuse_reflectance

__all__ = [
    "F_dt_external",
    "entity_flux",
    "exit_radiance",
    "exitance_direct",
    "exitance_pairs",
    "hg_phase",
    "single_scattering",
    "single_scattering_share",
    "specular_ggx",
    "transmitted_flux",
]


def _transmittance(eta, cos_outside):
    """Fresnel transmittance ``1 - F(eta, cos)`` for light crossing the boundary at outside angle ``cos``."""
    return 1.0 - _fresnel_unpolarised(jnp.clip(cos_outside, 0.0, 1.0), eta)


def F_dt_external(eta, fresnel: str = "poly"):
    """``1 - F_dr(1/eta)``: diffuse transmittance for light arriving from outside (cosine-weighted average of
    ``F_t``), equal to ``eta^2 (1 - F_dr(eta))`` by reciprocity (exactly so for ``fresnel="exact"``)."""
    return 1.0 - resolve_fresnel_method(fresnel)(1.0 / eta)


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
    import equinox as eqx

    return eqx.tree_at(
        lambda m: (m.sigma_a, m.sigma_s_prime),
        medium,
        (medium.sigma_a[..., :1], medium.sigma_s_prime[..., :1]),
    )


def exitance_pairs(medium: Medium, query_pos, ent_pos, ent_flux, pair_query, pair_entity, *, shared_channel=False):
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

    Returns:
        ``(Q, C)``. The blocks are summed in a ``lax.scan`` whose body is rematerialised in reverse mode, so memory
        stays at one block.
    """
    n_q = query_pos.shape[0]
    kernel_medium = _kernel_medium(medium, shared_channel)

    @jax.checkpoint
    def block(q, e):
        r = _safe_distance(query_pos[jnp.minimum(q, n_q - 1)], ent_pos[e])
        # Hierarchical paper Eq. 13: each entity contributes Phi_v R_d(|x - P_v|).
        contrib = _dipole_profile(r[:, None], kernel_medium) * ent_flux[e]
        return jax.ops.segment_sum(contrib, q, num_segments=n_q + 1, indices_are_sorted=True)

    def step(acc, qe):
        return acc + block(*qe), None

    init = jnp.zeros((n_q + 1, ent_flux.shape[-1]), ent_flux.dtype)
    acc, _ = jax.lax.scan(step, init, (pair_query, pair_entity))
    return acc[:n_q]


def exitance_direct(medium: Medium, query_pos, sample_pos, sample_flux, *, block: int = 64, shared_channel=False):
    """Brute-force ``M_o`` at every query point from every sample (the reference method), ``(Q, C)``.

    Queries are processed in blocks of ``block`` against all ``N`` samples (memory ``block * N * C`` floats).
    """
    n_q = query_pos.shape[0]
    pad = (-n_q) % block
    qp = jnp.concatenate([query_pos, jnp.broadcast_to(query_pos[:1], (pad, 3))]).reshape(-1, block, 3)
    kernel_medium = _kernel_medium(medium, shared_channel)

    @jax.checkpoint
    def one(q):
        r = _safe_distance(q[:, None, :], sample_pos[None, :, :])
        return jnp.sum(_dipole_profile(r[..., None], kernel_medium) * sample_flux[None], axis=1)

    return jax.lax.map(one, qp).reshape(-1, sample_flux.shape[-1])[:n_q]


def exit_radiance(medium: Medium, exitance, cos_o):
    """Diffuse radiance leaving the surface towards the eye, W/(mm^2 sr): ``F_t(cos_o) M_o / (pi F_dt,ext)``.

    Args:
        exitance: ``(Q, C)`` radiant exitance ``M_o``.
        cos_o: ``(Q,)`` cosine between the normal and the direction to the eye.
    """
    # Energy-consistent exit (module docstring; hierarchical paper Eq. 14 corrected).
    scale = _transmittance(medium.eta, cos_o) / (jnp.pi * F_dt_external(medium.eta, medium.fresnel))
    return scale[:, None] * exitance


def hg_phase(cos_theta, g):
    """Henyey-Greenstein phase function, 1/sr: ``(1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^{3/2})``."""
    return (1.0 - g * g) / (4.0 * jnp.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


def _refract_in(to_source, normal, eta):
    """``(t, cos_t, ok)``: direction of travel inside the medium of light arriving from ``to_source`` (unit vector
    from the surface towards where the light comes from), the cosine of the refracted angle, and False under total
    internal reflection (possible for ``eta < 1``)."""
    cos_i = jnp.clip(jnp.sum(to_source * normal, axis=-1), 0.0, 1.0)
    sin2_t = (1.0 - cos_i**2) / eta**2
    ok = sin2_t < 1.0
    cos_t = jnp.sqrt(jnp.clip(1.0 - sin2_t, 0.0, 1.0))
    t = -to_source / eta + (cos_i / eta - cos_t)[..., None] * normal
    return t, cos_t, ok


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

    F = _fresnel_unpolarised(jnp.clip(jnp.sum(h * to_light, axis=-1), 0.0, 1.0), medium.eta)
    f = jnp.where((cos_l > 0) & (cos_v > 0), D * g1(cos_l) * g1(cos_v) * F / jnp.maximum(4.0 * cos_l * cos_v, 1e-12),
                  0.0)
    return jnp.sum(f[..., None] * light_irradiance, axis=1)


def single_scattering_share(medium: Medium, n_nodes: int = 64):
    """Estimated share of single scattering in the light leaving the surface, per channel, at normal incidence.

    ``R1 = 2 pi int_0^1 f_r^(1)(n, mu_o) mu_o dmu_o`` (the Hanrahan-Krueger term, azimuth-independent at normal
    incidence) against the diffuse part ``F_t(1) Rd``. The scene plan leaves the term out when the share is below
    its tolerance.
    """
    x, w = np.polynomial.legendre.leggauss(n_nodes)
    mu = jnp.asarray(0.5 * (x + 1.0))
    wt = jnp.asarray(0.5 * w)
    sin_o = jnp.sqrt(1.0 - mu**2)
    q = mu.shape[0]
    normal = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (q, 3))
    to_eye = jnp.stack([sin_o, jnp.zeros_like(mu), mu], axis=-1)
    to_light = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (q, 1, 3))
    n_c = jnp.broadcast_shapes(jnp.shape(medium.sigma_a), jnp.shape(medium.sigma_s_prime), (1,))[-1]
    unit = jnp.ones((q, 1, n_c))
    f = single_scattering(medium, normal, to_eye, to_light, unit)  # (q, C): BRDF times E = 1
    r1 = 2.0 * jnp.pi * jnp.sum((wt * mu)[:, None] * f, axis=0)
    rd = medium_total_diffuse_reflectance(medium) * _transmittance(medium.eta, jnp.ones(()))
    return r1 / (r1 + rd)
