"""The multipole diffusion profile of a finite slab (Donner and Jensen 2005; photon-diffusion paper Eq. 12-13).

A slab of thickness ``d`` (mm) with the same relative index ``eta`` on both faces. Light enters at the origin of the
top face; :func:`multipole_profile` returns the radiant exitance leaving the top face, ``R(r)``, and the bottom face,
``T(r)``, at radial distance ``r`` (mm) from the axis of entry, per unit flux *entering* the medium, in 1/mm^2.
This is the dipole's normalisation (DESIGN.md, trap 1): the factor ``alpha'`` is kept, so the plane integrals of
``R`` and ``T`` are the totals of :func:`multipole_totals`, a tested identity. Per *incident* flux multiply by the
entry transmittance ``1 - fresnel_reflectance(eta, cos_theta_i)``.

Sources (photon-diffusion Eq. 12, DESIGN.md trap 4). Both extrapolated boundaries, at ``z = -z_b`` and
``z = d + z_b`` with ``z_b = 2 A D``, must carry zero fluence (Eq. 10-11). Mirroring the dipole about both, ad
infinitum, gives ``2n + 1`` pairs, ``i = -n..n``, with period ``2L``, ``L = d + 2 z_b = d + 4AD``:

    z_{r,i} = 2 i L + l_u,        z_{v,i} = 2 i L - l_u - 2 z_b.

``i = 0`` is exactly the dipole. With ``E(z, r)`` the exitance of a unit point source at height ``z`` above a
plane (:func:`~jaxsss.profiles._sources.point_source_exitance`, odd in ``z``):

    R(r) = alpha' sum_i [E(z_{r,i}, r) - E(z_{v,i}, r)]                  (Eq. 13)
    T(r) = alpha' sum_i [E(d - z_{r,i}, r) - E(d - z_{v,i}, r)]          (Eq. 13 seen from the bottom face)

Totals. The plane integral of ``E`` is ``sign(z) exp(-sigma_tr |z|) / 2``, so the infinite sums are geometric. For
``|a| < 2L``, ``S(a) = sum_i sign(2iL + a) exp(-sigma_tr |2iL + a|) = sign(a) sinh(sigma_tr (L - |a|)) /
sinh(sigma_tr L)`` (equal to ``sign(a) e^{-sigma_tr |a|} - 2 sinh(sigma_tr a) / expm1(2 sigma_tr L)``), and

    R_total = alpha'/2 [S(l_u) - S(-l_u - 2 z_b)],   T_total = alpha'/2 [S(d - l_u) - S(d + l_u + 2 z_b)].

The sinh ratio is evaluated without overflow or cancellation for any ``sigma_tr L`` (a series below 1e-2), so the
non-absorbing limit is exact: ``R_total = 1 - (l_u + z_b)/L`` and ``T_total = (l_u + z_b)/L`` (``R + T = 1``) for
``d > l_u``.

Truncation. The sums are truncated at a static number of pairs ``n_pairs`` (:func:`multipole_n_pairs` picks it on
the host). Convergence is:

- pointwise, exponential ``~exp(-2 n sigma_tr L)`` with absorption and algebraic ``~1/n^2`` without it;
- slower in the far field: at ``r >> n L`` the pairs do not yet cancel and the truncated profile is too large by
  about ``(2n + 1)(l_u + z_b) / (pi r^3)``, so radii ``r`` need roughly ``r / L`` pairs or more;
- for the totals of the *truncated* profile only like ``(l_u + z_b)/L exp(-2 n sigma_tr L)``: about
  ``log(1/rtol) / (2 sigma_tr L)`` pairs. At ``sigma_a = 0`` every image pair but ``i = 0`` integrates to zero, so
  the truncated profile's totals are the dipole's for every ``n`` (the missing energy sits at ``r ~ nL``): the
  truncated totals never converge there, and :func:`multipole_n_pairs` says so.

Thin slabs, ``d < l_u`` (a limitation of the published model, kept as published). The real source at depth ``l_u``
then lies *below* the bottom face. Values stay finite but: ``T(r)`` is the net flux through the bottom face, to which
the real source now contributes *inward* flux, so ``T(r)`` can take either sign (e.g. ``T(0) < 0`` for
``eta = 1.3, d = 0.5 l_u``); ``T_total`` jumps by ``-alpha'`` as ``d`` falls through ``l_u`` (at ``d = l_u`` exactly the source sits in the plane and contributes zero); in the non-absorbing
limit ``R_total + T_total = 0`` instead of 1 (no source inside the slab), and ``R_total = (d + z_b - l_u)/L`` is
negative for ``d < l_u - z_b``. Use the multipole only for ``d >= l_u`` when energy matters.

Infinite thickness is rejected with an error pointing to :func:`~jaxsss.profiles.dipole.dipole_profile`, the
``d -> infinity`` limit (tested with a large finite ``d``).

Units: mm, 1/mm; ``eta = n_inside / n_outside``. Every function broadcasts over a trailing channel axis: ``r`` of
shape ``(N, 1)`` with a 3-channel medium gives ``(N, 3)``; ``thickness`` broadcasts like the medium's arrays.
"""

from __future__ import annotations

import math
import operator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range, is_concrete
from jaxsss.medium import Medium
from jaxsss.profiles._sources import point_source_exitance_sq

__all__ = ["multipole_depths", "multipole_n_pairs", "multipole_profile", "multipole_totals"]

# Below this sigma_tr L the sinh ratio uses its Taylor series (truncation error (sigma_tr L)^6 / 5040 < 2e-16).
_SERIES_BELOW = 1e-2
# Pair-terms the host-side pair selection holds at once (per array, ~32 MB in float64).
_HOST_CHUNK_ELEMENTS = 1 << 22
_DEFAULT_MAX_PAIRS = 1 << 17


# --- Validation ---------------------------------------------------------------------------------------------------
def _check_thickness(thickness, owner: str):
    # Checked on the raw value: inside jit even a Python float becomes a tracer once converted.
    if is_concrete(thickness) and np.any(np.isposinf(np.asarray(thickness, dtype=np.float64))):
        raise ValueError(
            f"{owner}(thickness=inf) is outside the allowed range (0, inf): a semi-infinite medium is the dipole, "
            "use jaxsss.dipole_profile (the multipole's d -> infinity limit)"
        )
    return check_range(thickness, "thickness", 0.0, None, lo_open=True, owner=owner)


def _check_n_pairs(n_pairs, owner: str) -> int:
    try:
        n = operator.index(n_pairs)
    except TypeError as err:
        raise TypeError(f"{owner}(n_pairs={n_pairs!r}): must be a Python int >= 0 (it is static)") from err
    if n < 0:
        raise ValueError(f"{owner}(n_pairs={n}) is outside the allowed range [0, inf)")
    return n


def _all_concrete(*trees) -> bool:
    return all(is_concrete(leaf) for leaf in jax.tree_util.tree_leaves(trees))


# --- Eq. 12: source depths ----------------------------------------------------------------------------------------
def multipole_depths(medium: Medium, thickness, n_pairs: int):
    """Depths ``(z_r, z_v)`` of the ``2 n_pairs + 1`` real and virtual sources, in mm (photon-diffusion Eq. 12).

    Args:
        medium: the :class:`~jaxsss.medium.Medium`.
        thickness: slab thickness ``d``, mm, ``> 0`` and finite.
        n_pairs: number of image pairs on each side, a Python int ``>= 0``.

    Returns:
        ``z_r, z_v`` of shape ``(2 n_pairs + 1, *S)``, the leading axis running over ``i = -n..n`` and ``S`` the
        broadcast shape of the medium and the thickness. Positive values lie below the top face. Row ``n_pairs``
        (``i = 0``) is the dipole: ``z_r = l_u`` and ``z_v = -(l_u + 2 z_b)``.
    """
    n = _check_n_pairs(n_pairs, "multipole_depths")
    d = _check_thickness(thickness, "multipole_depths")
    return _depths(medium, d, jnp.arange(-n, n + 1))


def _depths(medium, d, i):
    l_u, z_b = medium.l_u, medium.z_b
    # L = d + 2 z_b = d + 4 A D, the distance between the two extrapolated boundaries.
    L = d + 2.0 * z_b
    shape = jnp.broadcast_shapes(jnp.shape(L), jnp.shape(l_u))
    i = i.astype(jnp.result_type(L)).reshape((-1,) + (1,) * len(shape))
    # Photon-diffusion Eq. 12.
    z_r = 2.0 * i * L + l_u
    z_v = 2.0 * i * L - l_u - 2.0 * z_b
    return z_r, z_v


# --- Eq. 13: profiles ---------------------------------------------------------------------------------------------
def _profile_sums(r, medium, d, n_pairs):
    # In sigma_tr^2, not sigma_tr: finite gradients at sigma_a = 0 (profiles/_sources.py).
    s2 = medium.sigma_tr_sq
    out_shape = jnp.broadcast_shapes(
        jnp.shape(r), jnp.shape(d), jnp.shape(medium.l_u), jnp.shape(s2), jnp.shape(medium.z_b)
    )
    dtype = jnp.result_type(r, s2)

    # One pair per iteration, accumulated in place: memory stays at the output's size for any n_pairs, and on CPU
    # it runs ~5x faster than materialising a (2n+1, *out) block and summing it (benchmarks/profile_throughput.py).
    @jax.checkpoint
    def add_pair(k, carry):
        z_r, z_v = (z[0] for z in _depths(medium, d, jnp.reshape(k - n_pairs, (1,))))
        # Eq. 13 at the top face: real sources minus virtual (negative) sources.
        R = point_source_exitance_sq(z_r, r, s2) - point_source_exitance_sq(z_v, r, s2)
        # Eq. 13 at the bottom face, z' = d - z measured upward from it.
        T = point_source_exitance_sq(d - z_r, r, s2) - point_source_exitance_sq(d - z_v, r, s2)
        return carry[0] + R, carry[1] + T

    zero = jnp.zeros(out_shape, dtype)
    R, T = jax.lax.fori_loop(0, 2 * n_pairs + 1, add_pair, (zero, zero))
    alpha_prime = medium.alpha_prime
    return alpha_prime * R, alpha_prime * T


_profile_kernel = eqx.filter_jit(_profile_sums)


def multipole_profile(r, medium: Medium, thickness, *, n_pairs: int | None = None, rtol: float = 1e-8):
    """Multipole reflectance and transmittance profiles ``R(r), T(r)`` of a slab, per unit flux entering it.

    Args:
        r: distance from the axis of entry, mm, ``>= 0``. Broadcasts against the medium and ``thickness``: for
            ``N`` radii and ``C`` channels pass ``r`` of shape ``(N, 1)``.
        medium: the :class:`~jaxsss.medium.Medium` (same ``eta`` above and below the slab).
        thickness: slab thickness ``d``, mm, ``> 0`` and finite (see the module docstring for ``d < l_u``).
        n_pairs: image pairs on each side of the dipole (static int ``>= 0``; 0 gives the dipole and its
            transmittance). ``None`` (default) lets :func:`multipole_n_pairs` choose it from the concrete values,
            which is not possible inside ``jit``/``vmap``/``grad``: there pass it explicitly.
        rtol: tolerance handed to :func:`multipole_n_pairs` when ``n_pairs`` is ``None``.

    Returns:
        ``(R, T)`` in 1/mm^2 (photon-diffusion Eq. 13 times ``alpha'``), each of the broadcast shape.

    Raises:
        ValueError: bad ``r`` or ``thickness``; ``n_pairs=None`` with traced inputs; or the automatic choice did not
            converge within its ``max_pairs`` (see :func:`multipole_n_pairs`).
    """
    owner = "multipole_profile"
    r = check_range(r, "r", 0.0, None, owner=owner)
    d = _check_thickness(thickness, owner)
    if n_pairs is None:
        if not _all_concrete(r, medium, d):
            raise ValueError(
                "multipole_profile(n_pairs=None): inside jit/vmap/grad the number of image pairs cannot be chosen "
                "from the values; pass a static n_pairs=..., e.g. n_pairs=multipole_n_pairs(r, medium, thickness) "
                "computed outside the transformation"
            )
        n_pairs = multipole_n_pairs(r, medium, d, rtol=rtol)
    else:
        n_pairs = _check_n_pairs(n_pairs, owner)
    return _profile_kernel(r, medium, d, n_pairs)


# --- Closed-form totals -------------------------------------------------------------------------------------------
def _sinh_ratio(x, L, sigma_tr_sq):
    """``sinh(sigma_tr x) / sinh(sigma_tr L)`` for ``|x| <= L``, from ``sigma_tr^2``: finite with finite gradients for
    all ``sigma_tr L >= 0``. The ratio is even in ``sigma_tr``, so its derivative in ``sigma_tr^2`` -- and hence in
    ``sigma_a`` -- is finite at ``sigma_a = 0`` (the series branch; ``d/d(s^2) = xi (xi^2 - 1) / 6`` there)."""
    s2 = sigma_tr_sq * L * L
    xi = x / L
    small = s2 < _SERIES_BELOW**2
    # Small sigma_tr L: Taylor series of both sinh in s^2; the limit sigma_tr -> 0 is x / L.
    b2 = jnp.where(small, s2, 0.0)
    a2 = b2 * xi * xi
    series = xi * (1.0 + a2 / 6.0 + a2 * a2 / 120.0) / (1.0 + b2 / 6.0 + b2 * b2 / 120.0)
    # Otherwise e^{s(u - 1)} expm1(-2 s u) / expm1(-2 s) with u = |xi| <= 1: no overflow, no cancellation. The
    # double where keeps sqrt away from 0 (an infinite derivative times zero would be nan).
    s_hi = jnp.sqrt(jnp.where(small, 1.0, s2))
    positive = xi >= 0.0
    u = jnp.where(positive, xi, -xi)
    f = jnp.exp(s_hi * (u - 1.0)) * jnp.expm1(-2.0 * s_hi * u) / jnp.expm1(-2.0 * s_hi)
    return jnp.where(small, series, jnp.where(positive, f, -f))


@eqx.filter_jit
def _totals_kernel(medium, d):
    s2, l_u, z_b = medium.sigma_tr_sq, medium.l_u, medium.z_b
    L = d + 2.0 * z_b
    alpha_prime = medium.alpha_prime
    # S(a) = sign(a) sinh(sigma_tr (L - |a|)) / sinh(sigma_tr L); each L - |a| is written out below so that it
    # carries no cancellation when d >> l_u.
    # Top face: R_total = alpha'/2 [S(l_u) - S(-l_u - 2 z_b)], with L - l_u = d + 2 z_b - l_u and
    # L - l_u - 2 z_b = d - l_u.
    R_total = 0.5 * alpha_prime * (_sinh_ratio(d + 2.0 * z_b - l_u, L, s2) + _sinh_ratio(d - l_u, L, s2))
    # Bottom face: T_total = alpha'/2 [S(d - l_u) - S(d + l_u + 2 z_b)], with L - |d - l_u| = 2 z_b + l_u (d >= l_u)
    # or 2 d + 2 z_b - l_u (d < l_u), and L - (d + l_u + 2 z_b) = -l_u. S(0) = 0 at d = l_u.
    below = jnp.where(d >= l_u, 2.0 * z_b + l_u, 2.0 * d + 2.0 * z_b - l_u)
    T_total = 0.5 * alpha_prime * (jnp.sign(d - l_u) * _sinh_ratio(below, L, s2) + _sinh_ratio(l_u, L, s2))
    return R_total, T_total


def multipole_totals(medium: Medium, thickness):
    """Total diffuse reflectance and transmittance of the slab: the plane integrals of :func:`multipole_profile`.

    Closed form of the infinite multipole (geometric series; see the module docstring), per unit flux entering the
    medium. Exact in the non-absorbing limit, ``R_total + T_total = 1`` for ``d > l_u``.

    Args:
        medium: the :class:`~jaxsss.medium.Medium`.
        thickness: slab thickness ``d``, mm, ``> 0`` and finite.

    Returns:
        ``(R_total, T_total)``, dimensionless, broadcast shape of the medium and ``thickness``; each in ``[0, 1]``
        for ``d >= l_u`` (see the module docstring for thinner slabs).
    """
    d = _check_thickness(thickness, "multipole_totals")
    return _totals_kernel(medium, d)


# --- Choosing n_pairs on the host ---------------------------------------------------------------------------------
def _np_exitance(z, r, sigma_tr):
    """NumPy mirror of :func:`point_source_exitance` (photon-diffusion Eq. 6) for the host-side search."""
    d2 = r * r + z * z
    in_plane = d2 == 0.0
    d2 = np.where(in_plane, 1.0, d2)
    dist = np.sqrt(d2)
    with np.errstate(under="ignore"):
        E = (z / dist) * (1.0 + sigma_tr * dist) * np.exp(-sigma_tr * dist) / (4.0 * np.pi * d2)
    return np.where(in_plane, 0.0, E)


class _HostSlab:
    """Concrete NumPy copies of the slab's parameters, broadcast to a common shape ``S``."""

    def __init__(self, medium, d):
        arrays = [medium.sigma_tr, medium.l_u, medium.z_b, medium.alpha_prime, d]
        arrays = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
        self.sigma_tr, self.l_u, self.z_b, self.alpha_prime, self.d = arrays
        self.L = self.d + 2.0 * self.z_b
        self.shape = self.d.shape

    def pair_sums(self, i, r):
        """``sum_{i} [R_i(r), T_i(r)]`` (without alpha') over the integer indices ``i``, chunked."""
        out_shape = np.broadcast_shapes(np.shape(r), self.shape)
        pad = (1,) * (len(out_shape) - len(self.shape))
        sig, L, l_u, z_b, d = (x.reshape(pad + self.shape) for x in (self.sigma_tr, self.L, self.l_u, self.z_b, self.d))
        R, T = np.zeros(out_shape), np.zeros(out_shape)
        chunk = max(1, _HOST_CHUNK_ELEMENTS // max(1, math.prod(out_shape)))
        for start in range(0, len(i), chunk):
            ii = np.asarray(i[start : start + chunk], dtype=np.float64).reshape((-1,) + (1,) * len(out_shape))
            # Photon-diffusion Eq. 12-13, as in the kernel.
            z_r = 2.0 * ii * L + l_u
            z_v = 2.0 * ii * L - l_u - 2.0 * z_b
            R += np.sum(_np_exitance(z_r, r, sig) - _np_exitance(z_v, r, sig), axis=0)
            T += np.sum(_np_exitance(d - z_r, r, sig) - _np_exitance(d - z_v, r, sig), axis=0)
        return R, T

    def truncated_totals(self, n):
        """Plane integrals of the profile truncated at ``n`` pairs (sums of ``point_source_total``; no alpha')."""
        i = np.arange(-n, n + 1, dtype=np.float64).reshape((-1,) + (1,) * len(self.shape))
        z_r = 2.0 * i * self.L + self.l_u
        z_v = 2.0 * i * self.L - self.l_u - 2.0 * self.z_b

        def total(z):
            with np.errstate(under="ignore"):
                return 0.5 * np.sign(z) * np.exp(-self.sigma_tr * np.abs(z))

        R = np.sum(total(z_r) - total(z_v), axis=0)
        T = np.sum(total(self.d - z_r) - total(self.d - z_v), axis=0)
        return R, T


def _not_converged(what: str, max_pairs: int, rtol: float, hint: str):
    return ValueError(
        f"multipole_n_pairs(max_pairs={max_pairs}): the {what} did not converge to rtol={rtol:g}; {hint}. "
        "Loosen rtol, raise max_pairs, or pass n_pairs explicitly."
    )


def _profile_pairs(slab: _HostSlab, r, rtol, floor, max_pairs) -> int:
    R, T = slab.pair_sums(np.zeros(1), r)
    R0, T0 = slab.pair_sums(np.zeros(1), np.zeros(()))
    n = 0
    while True:
        m = max(1, 2 * n)
        if m > max_pairs:
            r_max = float(np.max(r)) if np.size(r) else 0.0
            raise _not_converged(
                "profile R(r), T(r)",
                max_pairs,
                rtol,
                f"far-field radii need roughly r/L pairs (largest r = {r_max:g} mm, L = d + 2 z_b = "
                f"{float(np.min(slab.L)):g} mm) and weak absorption converges only like 1/n^2",
            )
        block = np.arange(n + 1, m + 1)
        i = np.concatenate([block, -block])
        dR, dT = slab.pair_sums(i, r)
        dR0, dT0 = slab.pair_sums(i, np.zeros(()))
        R, T, R0, T0 = R + dR, T + dT, R0 + dR0, T0 + dT0
        # Relative change below rtol, or, where the profile is below floor x its peak (r = 0), absolute change
        # below rtol x floor x peak.
        ok_R = np.abs(dR) <= rtol * np.maximum(np.abs(R), floor * np.abs(R0))
        ok_T = np.abs(dT) <= rtol * np.maximum(np.abs(T), floor * np.abs(T0))
        if np.all(ok_R) and np.all(ok_T):
            return m
        n = m


def _totals_pairs(slab: _HostSlab, R_inf, T_inf, rtol, max_pairs) -> int:
    # Truncated totals against the closed form: relative, with an absolute floor of rtol x 1e-12 (entering flux).
    n = 1
    while True:
        if n > max_pairs:
            sL = float(np.min(slab.sigma_tr * slab.L))
            need = "never (sigma_tr = 0)" if sL == 0.0 else f"about {math.log(1.0 / rtol) / (2.0 * sL):.3g}"
            raise _not_converged(
                "plane integral of the truncated profile (against the closed-form totals)",
                max_pairs,
                rtol,
                f"it converges like exp(-2 n sigma_tr L) with min sigma_tr L = {sL:g}, so it needs {need} pairs; "
                "pass check_totals=False to converge only the profile at the given radii",
            )
        R_n, T_n = slab.truncated_totals(n)
        ok = np.abs(slab.alpha_prime * R_n - R_inf) <= rtol * np.maximum(np.abs(R_inf), 1e-12)
        ok &= np.abs(slab.alpha_prime * T_n - T_inf) <= rtol * np.maximum(np.abs(T_inf), 1e-12)
        # Without absorption no finite n matches the totals (module docstring): those elements are judged by the
        # pointwise criterion alone, rather than making every non-absorbing slab an error.
        ok |= np.broadcast_to(slab.sigma_tr == 0.0, np.shape(ok))
        if np.all(ok):
            return n
        n *= 2


def multipole_n_pairs(
    r,
    medium: Medium,
    thickness,
    rtol: float = 1e-8,
    max_pairs: int = _DEFAULT_MAX_PAIRS,
    *,
    floor: float = 1e-6,
    check_totals: bool = True,
) -> int:
    """Choose the number of image pairs ``n`` for :func:`multipole_profile` from concrete values (host side).

    ``n`` doubles (1, 2, 4, ...) until adding the pairs ``n < |i| <= 2n`` changes ``R(r)`` and ``T(r)`` at every
    given radius by at most ``rtol`` relative -- or, where the profile is below ``floor`` times its peak (its value at
    ``r = 0``, per element), by at most ``rtol * floor * peak`` absolute -- and the result is ``2n``. With
    ``check_totals`` it also requires the plane integrals of the truncated profile to match
    :func:`multipole_totals` to ``rtol`` relative, and returns the larger count. The result is a power of two, so a
    jitted caller sees few distinct static values.

    Far-field radii ``r >> L`` (``L = d + 2 z_b``) need roughly ``r / L`` pairs or more; weak absorption needs many
    (the totals need about ``log(1/rtol) / (2 sigma_tr L)`` pairs; at ``sigma_a = 0`` they never converge, so those
    elements are judged by the pointwise criterion alone, which converges only algebraically there). See the module docstring.

    Args:
        r: radii, mm, ``>= 0`` (concrete), broadcasting as in :func:`multipole_profile`.
        medium: the :class:`~jaxsss.medium.Medium` (concrete).
        thickness: slab thickness, mm, ``> 0`` and finite (concrete).
        rtol: tolerance in ``(0, 1)``.
        max_pairs: the largest ``n`` allowed.
        floor: fraction of the peak below which the profile is converged in absolute terms, in ``(0, 1]``.
        check_totals: also converge the truncated profile's plane integrals.

    Returns:
        ``n_pairs``, a Python int ``>= 1``.

    Raises:
        ValueError: bad or traced inputs, or ``max_pairs`` reached (the message says which criterion failed and how
            many pairs it would need).
    """
    owner = "multipole_n_pairs"
    r = check_range(r, "r", 0.0, None, owner=owner)
    d = _check_thickness(thickness, owner)
    rtol = float(check_range(rtol, "rtol", 0.0, 1.0, lo_open=True, hi_open=True, owner=owner))
    floor = float(check_range(floor, "floor", 0.0, 1.0, lo_open=True, owner=owner))
    max_pairs = _check_n_pairs(max_pairs, owner)
    if max_pairs < 1:
        raise ValueError(f"{owner}(max_pairs={max_pairs}) is outside the allowed range [1, inf)")
    if not _all_concrete(r, medium, d):
        raise ValueError(
            f"{owner}: needs concrete r, medium and thickness; call it outside jit/vmap/grad and pass the result "
            "as the static n_pairs"
        )
    slab = _HostSlab(medium, d)
    n = 1
    if check_totals:  # first: it is cheap, and it is the criterion that fails without absorption
        R_inf, T_inf = (np.asarray(x, dtype=np.float64) for x in multipole_totals(medium, d))
        n = _totals_pairs(slab, R_inf, T_inf, rtol, max_pairs)
    return max(n, _profile_pairs(slab, np.asarray(r, dtype=np.float64), rtol, floor, max_pairs))
