"""Oblique incidence: diffusion sources spread along the refracted beam (photon-diffusion paper, Section 2.1).

A collimated pencil beam enters a half-space at the origin, at angle ``theta_i`` from the normal in the outside
medium, travelling towards ``+x``. Inside it is refracted (Snell, ``eta = n_inside / n_outside``:
``sin theta_t = sin theta_i / eta``) and its flux decays as ``exp(-sigma_t' x)`` along the path (Eq. 4). Each length
``dx`` scatters ``sigma_s' exp(-sigma_t' x) dx`` of the entering flux (Eq. 5): a source at lateral position
``x sin theta_t`` and depth ``z_r = x cos theta_t``, each the real source of a dipole whose negative image sits at
height ``z_v = z_r + 2 z_b`` above it (Eq. 8, the depth of the source following the beam). The exitance at surface
point ``(X, Y)`` per unit flux *entering* the medium (DESIGN.md trap 1 and 2: ``sigma_s' = alpha' sigma_t'``
carries the ``alpha'``) is

    R(X, Y) = alpha' int_0^inf sigma_t' e^{-sigma_t' x} kappa(d_r) [E(z_r, rho) + E(z_v, rho)] dx       (Eq. 8)

with ``rho^2 = (X - x sin theta_t)^2 + Y^2``, ``d_r = sqrt(rho^2 + z_r^2)`` and ``E`` the point-source exitance
(:mod:`jaxsss.profiles._sources`, Eq. 6). Per *incident* flux multiply by ``1 - fresnel_reflectance(eta, cos
theta_i)``.

The attenuation kernel (Eq. 9). The paper writes ``kappa(x) = 1 - exp(-sigma_r x)``, evaluated at ``d_r`` in Eq. 8,
and describes it as "the approximate probability that light is not scattered before exiting": ``sigma_r`` is not
defined anywhere (DESIGN.md trap 6). The candidates are registered in :data:`KAPPA_COEFFICIENTS`:

- ``"sigma_t_prime"`` (default): ``kappa = 1 - exp(-sigma_t' d_r)``, the probability that light travelling ``d_r``
  from the source interacts on the way -- the reading of the sentence above;
- ``"sigma_tr"``: ``kappa = 1 - exp(-sigma_tr d_r)``, with the effective transport coefficient;
- ``"none"``: ``kappa = 1`` (plain Eq. 8).

The default was chosen against the Monte Carlo multiply-scattered profile (``R_xy_order[2]`` and ``R_r_order[2]``
of :func:`jaxsss.mc.simulate`) in ``benchmarks/photon_diffusion.py``; the numbers are in ``docs/photon_diffusion.md``.

The integral has no closed form. :func:`oblique_profile` integrates it by a fixed, graded Gauss-Legendre rule
(:mod:`jaxsss.profiles._beam`): noise-free and differentiable. :func:`oblique_profile_sampled` is the paper's
estimator: sources sampled along the beam with the PDF ``sigma_t' e^{-sigma_t' x}`` (:func:`sample_beam_sources`).

The point of entry is singular: without ``kappa`` the profile grows like ``1 / (4 pi r)`` as ``r -> 0`` and with the
``sigma_t'`` kernel like ``log(1/r)``; ``X = Y = 0`` is rejected. With ``kappa = 1`` the plane integral has a closed
form (:func:`oblique_total`), a tested identity.

Units: mm, 1/mm, angles in radians. Shapes: ``x`` and ``y`` broadcast against the medium's arrays; for ``N`` points
and ``C`` channels pass ``(N, 1)`` arrays.
"""

from __future__ import annotations

import operator

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range, require
from jaxsss.fresnel import snell_cosine
from jaxsss.medium import Medium
from jaxsss.profiles._beam import DEFAULT_NODES, beam_nodes, check_nodes
from jaxsss.profiles._sources import point_source_exitance
from jaxsss.profiles.point_sources import safe_sqrt

__all__ = [
    "DEFAULT_KAPPA",
    "KAPPA_COEFFICIENTS",
    "attenuated_dipole_profile",
    "attenuation_kernel",
    "kappa_unchecked",
    "beam_integral",
    "oblique_profile",
    "oblique_profile_sampled",
    "oblique_total",
    "refracted_direction",
    "sample_beam_sources",
]

# Eq. 9's coefficient: name -> function of the medium (None: no attenuation). See the module docstring.
KAPPA_COEFFICIENTS = {
    "sigma_t_prime": lambda m: m.sigma_t_prime,
    "sigma_tr": lambda m: m.sigma_tr,
    "none": None,
}
DEFAULT_KAPPA = "sigma_t_prime"


def _resolve_kappa(kappa: str, owner: str):
    if kappa not in KAPPA_COEFFICIENTS:
        raise ValueError(f"{owner}(kappa={kappa!r}) is not a known coefficient; valid names: {sorted(KAPPA_COEFFICIENTS)}")
    return KAPPA_COEFFICIENTS[kappa]


def attenuation_kernel(d_r, medium: Medium, kappa: str = DEFAULT_KAPPA):
    """Eq. 9: ``kappa(d_r) = 1 - exp(-sigma d_r)``, the share of a source's diffusion counted as multiple scattering.

    Args:
        d_r: distance from the (real) source to the shading point, mm, ``>= 0``.
        medium: the :class:`~jaxsss.medium.Medium`.
        kappa: the coefficient ``sigma``, a name in :data:`KAPPA_COEFFICIENTS` (static).

    Returns:
        ``kappa`` in ``[0, 1]``, the broadcast shape of ``d_r`` and the medium.
    """
    coeff = _resolve_kappa(kappa, "attenuation_kernel")
    d_r = check_range(d_r, "d_r", 0.0, None, owner="attenuation_kernel")
    return kappa_unchecked(coeff, d_r, medium)


def kappa_unchecked(coeff, d_r, medium):
    """Eq. 9 without checks: ``coeff`` is a value of :data:`KAPPA_COEFFICIENTS` (a function of the medium, or None
    for no attenuation), ``d_r`` in mm, already validated (the kernel of :func:`attenuation_kernel`)."""
    if coeff is None:
        return jnp.ones(jnp.broadcast_shapes(jnp.shape(d_r), jnp.shape(medium.sigma_t_prime)), jnp.result_type(d_r))
    # Eq. 9, as -expm1 so that it stays accurate (and its gradient finite) for sigma d_r << 1.
    return -jnp.expm1(-coeff(medium) * d_r)


def refracted_direction(theta_i, eta):
    """``(sin theta_t, cos theta_t)`` of a beam refracted into the medium (Snell: ``sin theta_t = sin theta_i / eta``).

    Args:
        theta_i: angle of incidence in the outside medium, radians, in ``[0, pi/2)``.
        eta: ``n_inside / n_outside``, ``> 0``; for ``eta < 1`` angles beyond the critical angle are rejected.
    """
    theta_i = check_range(theta_i, "theta_i", 0.0, jnp.pi / 2, hi_open=True, owner="refracted_direction")
    sin_t = jnp.sin(theta_i) / eta
    sin_t = require(sin_t, sin_t >= 1.0, "refracted_direction(theta_i=...): at or beyond the critical angle for "
                    "eta < 1 no light enters; allowed range sin(theta_i) < eta")
    # Snell's law (jaxsss.fresnel.snell_cosine).
    return sin_t, snell_cosine(jnp.cos(theta_i), eta)[0]


# --- Eq. 8: the deterministic quadrature --------------------------------------------------------------------------
def beam_integral(f, closest, spread, medium: Medium, *, length=jnp.inf, n_nodes: int = DEFAULT_NODES):
    """``int_0^ell sigma_t' e^{-sigma_t' x} f(x) dx`` by a graded Gauss-Legendre rule (the quadrature of Eq. 8).

    Args:
        f: function of ``x`` (mm along the beam, shape ``(2 n_nodes, *S)``) giving the exitance of the sources
            there, per unit source power.
        closest: ``x`` where ``f`` peaks (mm), usually where the beam passes closest to the shading point.
        spread: width of the peak (mm, ``> 0``), usually that closest distance.
        medium: the :class:`~jaxsss.medium.Medium` (its ``sigma_t'``).
        length: beam length inside the medium (mm, ``> 0``; ``inf`` for a half-space).
        n_nodes: Gauss-Legendre nodes per panel (static int ``>= 2``).

    Returns:
        The integral, shape ``S`` (no ``alpha'``: multiply by it for flux entering). See :mod:`jaxsss.profiles._beam`.
    """
    n = check_nodes(n_nodes, "beam_integral")
    x, w = beam_nodes(closest, spread, medium.sigma_t_prime, length, n)
    return jnp.sum(w * f(x), axis=0)


def _sources_exitance(x, X, Y, sin_t, cos_t, medium, coeff):
    """Exitance at ``(X, Y)`` of the dipole whose real source lies at distance ``x`` along the beam (Eq. 8 bracket)."""
    z_r = x * cos_t
    rho2 = (X - x * sin_t) ** 2 + Y * Y
    rho = safe_sqrt(rho2)
    # Eq. 8: the depth follows the beam, z_r = x cos theta; z_v = z_r + 2 z_b = z_r + 4 A D.
    z_v = z_r + 2.0 * medium.z_b
    E = point_source_exitance(z_r, rho, medium.sigma_tr) + point_source_exitance(z_v, rho, medium.sigma_tr)
    # Eq. 9 at d_r, the distance from the real source.
    return kappa_unchecked(coeff, jnp.sqrt(rho2 + z_r * z_r), medium) * E


@eqx.filter_jit
def _oblique_kernel(X, Y, medium, theta_i, coeff, n_nodes):
    # Snell's law into the medium (eta = n_inside / n_outside).
    sin_t = jnp.sin(theta_i) / medium.eta
    cos_t, _ = snell_cosine(jnp.cos(theta_i), medium.eta)
    # Closest approach of the beam line to (X, Y, 0): at x0 = X sin theta_t, distance b = sqrt(X^2 cos^2 + Y^2).
    x0 = X * sin_t
    b = jnp.sqrt((X * cos_t) ** 2 + Y * Y)
    x, w = beam_nodes(x0, b, medium.sigma_t_prime, jnp.inf, n_nodes)
    # Eq. 8 times sigma_s' = alpha' sigma_t' (the source power, DESIGN.md trap 2).
    return medium.alpha_prime * jnp.sum(w * _sources_exitance(x, X, Y, sin_t, cos_t, medium, coeff), axis=0)


def _check_point(x, y, theta_i, medium, owner):
    x = check_range(x, "x", None, None, owner=owner)
    y = check_range(y, "y", None, None, owner=owner)
    theta_i = check_range(theta_i, "theta_i", 0.0, jnp.pi / 2, hi_open=True, owner=owner)
    x = require(x, (x == 0.0) & (y == 0.0), f"{owner}(x=0, y=0): the profile diverges at the point of entry "
                "(like 1/(4 pi r) without kappa, log(1/r) with it); allowed: any other point")
    x = require(x, jnp.sin(theta_i) >= medium.eta, f"{owner}(theta_i=...): at or beyond the critical angle "
                "(eta < 1) no light enters; allowed range sin(theta_i) < eta")
    return x, y, theta_i


def oblique_profile(x, y, medium: Medium, theta_i=0.0, *, kappa: str = DEFAULT_KAPPA, n_nodes: int = DEFAULT_NODES):
    """Exitance ``R(x, y)`` of an oblique pencil beam on a half-space, sources spread along it (Eq. 8, quadrature).

    Args:
        x: surface coordinate along the beam's in-plane direction (mm; the beam enters at the origin travelling
            towards ``+x``).
        y: the other surface coordinate (mm). ``x = y = 0`` is rejected (the profile diverges there).
        medium: the :class:`~jaxsss.medium.Medium`.
        theta_i: angle of incidence in the outside medium, radians, ``[0, pi/2)``.
        kappa: coefficient of the attenuation kernel (Eq. 9), a name in :data:`KAPPA_COEFFICIENTS` (static).
        n_nodes: Gauss-Legendre nodes per panel of the quadrature (static; two panels).

    Returns:
        ``R`` in 1/mm^2 per unit flux entering the medium, the broadcast shape of ``x``, ``y``, ``theta_i`` and the
        medium.
    """
    coeff = _resolve_kappa(kappa, "oblique_profile")
    n = check_nodes(n_nodes, "oblique_profile")
    x, y, theta_i = _check_point(x, y, theta_i, medium, "oblique_profile")
    return _oblique_kernel(x, y, medium, theta_i, coeff, n)


def attenuated_dipole_profile(r, medium: Medium, *, kappa: str = DEFAULT_KAPPA):
    """The dipole with its single source at ``l_u`` modulated by Eq. 9: ``kappa(d_r) R_d(r)`` (paper's Figure 3).

    Args:
        r: distance from the point of entry, mm, ``>= 0``.
        medium: the :class:`~jaxsss.medium.Medium`.
        kappa: coefficient of Eq. 9, a name in :data:`KAPPA_COEFFICIENTS` (static).

    Returns:
        1/mm^2 per unit flux entering (the normalisation of :func:`~jaxsss.profiles.dipole.dipole_profile`).
    """
    coeff = _resolve_kappa(kappa, "attenuated_dipole_profile")
    r = check_range(r, "r", 0.0, None, owner="attenuated_dipole_profile")
    return _attenuated_dipole(r, medium, coeff)


@eqx.filter_jit
def _attenuated_dipole(r, medium, coeff):
    z_r = medium.l_u
    z_v = z_r + 2.0 * medium.z_b
    E = point_source_exitance(z_r, r, medium.sigma_tr) + point_source_exitance(z_v, r, medium.sigma_tr)
    # Eq. 9 at d_r = sqrt(r^2 + z_r^2) times Eq. 6 (alpha' is the source power).
    return medium.alpha_prime * kappa_unchecked(coeff, jnp.sqrt(r * r + z_r * z_r), medium) * E


def oblique_total(medium: Medium, theta_i=0.0):
    """Plane integral of :func:`oblique_profile` with ``kappa="none"``, in closed form.

    Each source integrates to ``(e^{-sigma_tr z_r} + e^{-sigma_tr z_v}) / 2`` (:mod:`jaxsss.profiles._sources`), so

        R_total = alpha' / 2 (1 + e^{-2 sigma_tr z_b}) sigma_t' / (sigma_t' + sigma_tr cos theta_t).

    Args:
        medium: the :class:`~jaxsss.medium.Medium`.
        theta_i: angle of incidence outside, radians, ``[0, pi/2)``.

    Returns:
        Dimensionless, per unit flux entering; the broadcast shape of ``theta_i`` and the medium.
    """
    _, cos_t = refracted_direction(theta_i, medium.eta)
    st = medium.sigma_t_prime
    # Eq. 8 integrated over the plane, then over x against sigma_s' e^{-sigma_t' x}.
    return 0.5 * medium.alpha_prime * (1.0 + jnp.exp(-2.0 * medium.sigma_tr * medium.z_b)) * st / (
        st + medium.sigma_tr * cos_t)


# --- Eq. 8 sampled: the paper's estimator ------------------------------------------------------------------------
def _check_count(n_sources, owner: str) -> int:
    try:
        n = operator.index(n_sources)
    except TypeError as err:
        raise TypeError(f"{owner}(n_sources={n_sources!r}): must be a Python int >= 1 (it is static)") from err
    if n < 1:
        raise ValueError(f"{owner}(n_sources={n}) is outside the allowed range [1, inf)")
    return n


def sample_beam_sources(key, medium: Medium, n_sources: int):
    """Distances along the beam of ``n_sources`` sources drawn from the PDF ``sigma_t' e^{-sigma_t' x}`` (mm).

    Stratified inverse-CDF sampling (one uniform per stratum of ``[0, 1)``): ``x = -log(1 - u) / sigma_t'``.
    Returns an array of shape ``(n_sources, *M)``, ``M`` the medium's shape.
    """
    n = _check_count(n_sources, "sample_beam_sources")
    shape = (n,) + jnp.shape(medium.sigma_t_prime)
    dtype = jnp.result_type(medium.sigma_t_prime)
    strata = jnp.arange(n, dtype=dtype).reshape((n,) + (1,) * (len(shape) - 1))
    u = (strata + jax.random.uniform(key, shape, dtype)) / n
    # Inverse CDF of Eq. 3's PDF.
    return -jnp.log1p(-u) / medium.sigma_t_prime


def oblique_profile_sampled(x, y, medium: Medium, theta_i, key, n_sources: int, *, kappa: str = DEFAULT_KAPPA):
    """Monte Carlo estimate of :func:`oblique_profile`: the paper's sources sampled along the beam.

    ``alpha' mean_k kappa(d_r,k) [E(z_r,k, rho_k) + E(z_v,k, rho_k)]`` over ``n_sources`` stratified samples of
    :func:`sample_beam_sources`. Unbiased for every ``(x, y)`` other than the origin; its variance grows without
    bound as ``(x, y)`` approaches the beam's point of entry. Arguments as :func:`oblique_profile`, plus a JAX PRNG
    ``key`` and ``n_sources`` (static int).
    """
    coeff = _resolve_kappa(kappa, "oblique_profile_sampled")
    _check_count(n_sources, "oblique_profile_sampled")
    x, y, theta_i = _check_point(x, y, theta_i, medium, "oblique_profile_sampled")
    xs = sample_beam_sources(key, medium, n_sources)
    return _sampled_kernel(x, y, medium, theta_i, xs, coeff)


@eqx.filter_jit
def _sampled_kernel(X, Y, medium, theta_i, xs, coeff):
    sin_t = jnp.sin(theta_i) / medium.eta
    cos_t = jnp.sqrt((1.0 - sin_t) * (1.0 + sin_t))
    out = jnp.broadcast_shapes(jnp.shape(X), jnp.shape(Y), jnp.shape(theta_i), xs.shape[1:])
    xs = xs.reshape(xs.shape[:1] + (1,) * (len(out) - xs.ndim + 1) + xs.shape[1:])
    # Eq. 8 as an expectation over the source PDF, times the source power alpha'.
    return medium.alpha_prime * jnp.mean(_sources_exitance(xs, X, Y, sin_t, cos_t, medium, coeff), axis=0)
