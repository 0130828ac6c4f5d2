"""Fitting the anisotropy ``g`` together with ``sigma_a`` and ``sigma_s'`` (issue 15, item 3).

Far from the source a half-space's reflectance depends on ``g`` only through ``sigma_s' = sigma_s (1 - g)``
(similarity); within about one transport mean free path ``l_u`` of the point of entry the low orders of scattering
show the phase function, so near-source data can carry ``g``. :func:`fit_free_g` fits ``(sigma_a, sigma_s', g)`` to
a radial profile with the white Monte Carlo family (:func:`jaxsss.mc.white_family.white_family_profile`, smooth and
differentiable in ``g`` over its grid, ``g`` in [0, 0.95]), reports standard errors from the Jacobian at the solution,
and says when ``g`` is not constrained (:data:`G_STDERR_LIMIT`): then fit with ``g`` fixed (``fit_profile(...,
model="mc", g=...)``), whose ``sigma_a`` and ``sigma_s'`` the data do fix.

Parameterisation: ``theta = (log sigma_a, log sigma_s', z)`` with ``g = g_lo + (g_hi - g_lo) sigmoid(z)`` over the
family's range, so every step stays inside it. Starts: the dipole fit of the same data (``sigma_a``, ``sigma_s'``)
combined with each ``g`` of :data:`G_STARTS`, solved together (one vmapped Levenberg-Marquardt); the lowest cost
wins. Residuals ``(model - R) / R_stderr``; with no standard errors, relative residuals ``(model - R) / R`` and the
errors scaled by the residual variance.

Slabs (R and T) would carry ``g`` too, but replay Monte Carlo reweights absorption and scattering coefficients, not
the phase function: a free ``g`` there is not supported.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxsss._exported import compiled_program
from jaxsss.validate import check_range, trusted_traces

__all__ = ["FreeGFit", "G_R_MIN_LU", "G_STARTS", "G_STDERR_LIMIT", "G_SYSTEMATIC", "MODEL_REL_ERROR", "fit_free_g"]

G_STARTS = (0.05, 0.5, 0.8, 0.9, 0.93)
"""Anisotropies the solver starts from (with the dipole fit's sigma_a and sigma_s')."""
MODEL_REL_ERROR = 0.01
"""Relative error of the white Monte Carlo family between its nodes (its interpolation in g and n; measured by
``benchmarks/white_interpolation.py``), added in quadrature to the data's standard errors so that ``g``'s error
covers the model's: the near-source bins of a 1e6-photon run are measured to ~0.3%, finer than the family's
interpolation, and would otherwise pin g to a biased value with a tiny error."""
G_SYSTEMATIC = 0.04
"""Systematic error of the fitted ``g``, added in quadrature to its statistical error. Measured (2026-11-23):
free-g fits to this engine's own half-space runs at six off-grid ``(g, n)`` (4e5 photons, bins of 0.05 l_u to
10 l_u) miss g by +0.012, -0.009, -0.025, -0.001, +0.014, +0.030 (rms 0.018; 0.4-4.5 statistical errors), and fits
to the shared MCML 1.2.2 half-spaces by 0.001 (n 1.0, g 0.7), 0.000 (1.44, 0.8), -0.034 (1.37, 0.9) and -0.061
(1.5, 0.5). The near-source bins that carry ``g`` are where the family's interpolation (and the two codes) differ by
a few tenths of a percent; their statistical errors alone would pin ``g`` to a biased value."""
G_R_MIN_LU = 1.0
"""``g`` is reported as constrained only when the fitted range starts within this many transport lengths ``l_u`` of
the source (at the solution). Beyond it the profile depends on ``g`` only through small differences that the
family's far-field error swamps: the shared MCML half-space (g = 0.7) fitted from 3.3 l_u gave g = 0.94 with a
statistical error of 0.01."""
G_STDERR_LIMIT = 0.05
"""``g`` is reported as constrained when its standard error is at most this (absolute)."""


class FreeGFit(NamedTuple):
    """Result of :func:`fit_free_g` (1/mm; ``g`` dimensionless).

    ``covariance``: 3 x 3 of ``(sigma_a, sigma_s', g)``; ``identifiable``: ``g`` constrained (``g_stderr <=
    G_STDERR_LIMIT``) and the three not degenerate; ``warnings``: what the data do not fix; ``starts``: per start
    ``(g_start, cost, g_end)``; ``r_min``, ``r_max``: the range fitted (mm); ``reduced_chi2``; ``seconds``.
    """

    sigma_a: float
    sigma_s_prime: float
    g: float
    sigma_a_stderr: float
    sigma_s_prime_stderr: float
    g_stderr: float
    covariance: np.ndarray
    converged: bool
    identifiable: bool
    reduced_chi2: float
    n_points: int
    r_min: float
    r_max: float
    starts: tuple
    warnings: tuple
    seconds: float

    def to_dict(self) -> dict:
        d = self._asdict()
        d["covariance"] = self.covariance.tolist()
        d["starts"] = [list(s) for s in self.starts]
        d["warnings"] = list(self.warnings)
        return d


def _g_of(z, lo, hi):
    return lo + (hi - lo) * jax.nn.sigmoid(z)


def _residuals(theta, args):
    r, R, weight, eta, lo, hi, family = args
    from jaxsss.mc.white_family import white_family_profile

    model = white_family_profile(r, jnp.exp(theta[0]), jnp.exp(theta[1]), _g_of(theta[2], lo, hi), eta, family)
    return (model - R) * weight


@eqx.filter_jit
def _solve_all(thetas, args, max_steps):
    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10)

    def one(theta0):
        sol = optx.least_squares(_residuals, solver, theta0, args=args, max_steps=max_steps, throw=False)
        res = _residuals(sol.value, args)
        return sol.value, jnp.sum(res**2), sol.result == optx.RESULTS.successful

    # One start after another (lax.map), not vmapped: a vmapped while loop steps every start until the slowest stops,
    # and a start that creeps to max_steps made the other four take 200 steps too (test_g_fit's 3.3 l_u fit: 7.2 s
    # -> 2.7 s).
    return jax.lax.map(one, thetas)


@eqx.filter_jit
def _jacobian(theta, args):
    return jax.jacfwd(_residuals)(theta, args), _residuals(theta, args)


def _default_range(r):
    """Every radius, except a first bin that straddles the source (centres of equal bins from r = 0)."""
    from fitting.io import equal_bin_edges

    return float(r[1] if equal_bin_edges(r) is not None else r[0]), float(r[-1])


def fit_free_g(r, R=None, *, R_stderr=None, eta: float, r_min: float | None = None, r_max: float | None = None,
               model_rel_error: float = MODEL_REL_ERROR, max_steps: int = 200) -> FreeGFit:
    """Fit ``sigma_a``, ``sigma_s'`` and ``g`` of a half-space to its radial reflectance (module docstring).

    Args:
        r: radii, mm, ``(N,)`` increasing; or a :class:`fitting.ProfileData` (then ``R`` and ``R_stderr`` from it).
        R: reflectance per incident photon per mm^2 (specular excluded), ``(N,)``.
        R_stderr: standard errors, ``(N,)`` (recommended: they weigh the near-source bins that carry ``g``).
        eta: index of the medium under air, in the family's range [1, 1.6].
        r_min, r_max: fit range (mm); default every radius but a first bin over the source.
        model_rel_error: the family's relative error, added in quadrature to ``R_stderr`` (:data:`MODEL_REL_ERROR`).
        max_steps: Levenberg-Marquardt steps per start.
    """
    from jaxsss.mc import white_family as wf
    from fitting.profile_fit import fit_profile

    t0 = time.perf_counter()
    if hasattr(r, "R") and R is None:
        r, R, R_stderr = r.r, r.R, r.R_stderr
    r, R = np.asarray(r, dtype=np.float64), np.asarray(R, dtype=np.float64)
    if R.shape != r.shape or r.ndim != 1 or r.size < 4:
        raise ValueError(f"fit_free_g(r, R): need two 1-D arrays of the same length >= 4, got {r.shape}, {R.shape}")
    check_range(r, "r", 0.0, None, owner="fit_free_g")  # on the host: the traced model is not checked (below)
    wf.check_covered(wf.G_NODES[0], eta, owner="fit_free_g")
    lo_default, hi_default = _default_range(r)
    r_min = lo_default if r_min is None else float(r_min)
    r_max = hi_default if r_max is None else float(r_max)
    keep = (r >= r_min) & (r <= r_max) & (R > 0)
    if keep.sum() < 4:
        raise ValueError(f"fit_free_g(r_min={r_min:g}, r_max={r_max:g}): fewer than 4 positive points in range")
    # Points outside the range keep their place with weight 0: one compilation per profile length, whatever the range.
    R_safe = np.where(keep, R, 1.0)
    if R_stderr is None:
        weight, absolute = np.where(keep, 1.0 / R_safe, 0.0), False
    else:
        se = np.asarray(R_stderr, dtype=np.float64)
        if se.shape != r.shape or np.any(~(se[keep] > 0)):
            raise ValueError("fit_free_g(R_stderr=...) must have r's shape and be > 0 in the fit range")
        # The data's errors and the model's (module docstring), in quadrature.
        weight, absolute = np.where(keep, 1.0 / np.hypot(np.where(keep, se, 1.0), model_rel_error * R_safe), 0.0), True
    # Start: the dipole fit's sigma_a and sigma_s' (g-free far field), with each g of G_STARTS.
    dip = fit_profile(r, R, R_stderr=R_stderr, eta=eta, model="dipole", r_min=r_min, r_max=r_max, warn=False)
    sa0, ssp0 = float(np.ravel(dip.sigma_a)[0]), float(np.ravel(dip.sigma_s_prime)[0])
    lo, hi = float(wf.G_NODES[0]), float(wf.G_NODES[-1])
    z0 = [math.log((g - lo) / (hi - g)) for g in G_STARTS]
    thetas = jnp.asarray([[math.log(sa0), math.log(ssp0), z] for z in z0])
    family = wf.load_white_family()
    args = (jnp.asarray(r), jnp.asarray(np.where(keep, R, 0.0)), jnp.asarray(weight), float(eta), lo, hi, family)
    # Inputs checked on the host, parameters valid by construction (exp, the sigmoid in g): no traced checks, so no
    # host callbacks and the persistent cache stores the programs (they compiled for 20 s in every process).
    # Through jaxsss._exported: a new process loads both programs instead of tracing them (the solve's trace is most of
    # a warm first fit's overhead).
    with trusted_traces():
        solve_all = compiled_program("free-g-solve", _solve_all, (thetas, args), (max_steps,))
        values, costs, ok = (np.asarray(a) for a in solve_all(thetas, args))
        best = int(np.nanargmin(np.where(np.isfinite(costs), costs, np.inf)))
        theta = values[best]
        at_theta = (jnp.asarray(theta), args)
        jac, res = (np.asarray(a) for a in compiled_program("free-g-jacobian", _jacobian, at_theta)(*at_theta))
    m, p = int(keep.sum()), 3
    s2 = float(res @ res) / max(m - p, 1)
    cov_theta = (max(1.0, s2) if absolute else s2) * np.linalg.pinv(jac.T @ jac)
    g = float(_g_of(theta[2], lo, hi))
    # Delta method to (sigma_a, sigma_s', g).
    dg = (g - lo) * (hi - g) / (hi - lo)
    D = np.diag([math.exp(theta[0]), math.exp(theta[1]), dg])
    cov = D @ cov_theta @ D
    cov[2, 2] += G_SYSTEMATIC**2
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    degenerate = bool(np.any(np.abs(corr[np.triu_indices(3, 1)]) > 0.999))
    l_u = 1.0 / (math.exp(theta[0]) + math.exp(theta[1]))
    r_first = float(r[keep][0])
    near = r_first <= G_R_MIN_LU * l_u
    identifiable = bool(se[2] <= G_STDERR_LIMIT and not degenerate and near)
    warnings = []
    if not near:
        warnings.append(f"g is not constrained by these data: the fit range starts at {r_first / l_u:.2g} l_u "
                        f"(l_u = {l_u:.3g} mm), and only data within about {G_R_MIN_LU:g} l_u of the source carry g "
                        f"(fitted g = {g:.3f}); fit with g fixed, or include near-source data")
    elif not identifiable:
        warnings.append(f"g is not constrained by these data (g = {g:.3f} +- {se[2]:.2g}, limit {G_STDERR_LIMIT}): "
                        "beyond about one l_u the profile fixes sigma_a and sigma_s' = sigma_s (1 - g) only; use "
                        "near-source data with standard errors, or fit with g fixed")
    starts = tuple((float(gs), float(c), float(_g_of(v[2], lo, hi))) for gs, c, v in zip(G_STARTS, costs, values))
    return FreeGFit(sigma_a=math.exp(theta[0]), sigma_s_prime=math.exp(theta[1]), g=g, sigma_a_stderr=float(se[0]),
                    sigma_s_prime_stderr=float(se[1]), g_stderr=float(se[2]), covariance=cov,
                    converged=bool(ok[best]), identifiable=identifiable, reduced_chi2=s2, n_points=m, r_min=r_min,
                    r_max=r_max, starts=starts, warnings=tuple(warnings), seconds=time.perf_counter() - t0)
