"""The compiled pieces of a profile fit, for ONE problem (one channel of one profile); callers vmap them.

Three stages, each a pure traceable function of arrays with a static :class:`Config`:

1. :func:`data_guess` -- from the data alone: ``l_d`` from the far-field log-slope of ``r^2 R(r)`` (the dipole's far
   field falls like ``exp(-sigma_tr r) / r^2``) and ``Rd`` from the plane integral ``int 2 pi r R(r) dr`` divided by
   the entry transmittance (absolute data only).
2. :func:`initial_guess` -- candidates ``Rd`` (the integral's and a fixed grid) at that ``l_d`` are turned into
   ``(sigma_a, sigma_s')`` by :func:`jaxsss.from_rd_ld`; the forward model scores each (weighted mean squared
   residual over ``r >= l_u`` of the candidate, with the scale profiled out for relative data) and the best is the
   start. The fit range is then set from the start's ``l_u``.
3. :func:`solve` -- Optimistix least squares in the log-parameters, then the covariance from ``J^T J``.

Residuals: ``w (scale * model(r) - data)`` on the points inside the fit range (zero elsewhere), with
``w = 1 / stderr`` when standard errors are given and ``w = 1 / data`` (relative residuals) otherwise; without
standard errors points with ``data <= 0`` are left out. The weights depend on the data; the gradient with respect to
the data (:func:`fitting.fit_jacobian_wrt_data`) differentiates through them.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optimistix as optx

import jaxsss
from fitting.models import entry_transmittance, model_profiles, resolve_model
from fitting.solvers import resolve_solver

# Candidate total diffuse reflectances for the start (dense near 1, where high-albedo materials live).
RD_GRID = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995,
           0.998, 0.999, 0.9995, 0.9999)
RD_CLAMP = (1e-4, 1.0 - 1e-4)  # the integral's Rd is clamped into this range (from_rd_ld needs (0, 1))
LD_CLAMP = (1e-6, 1e6)  # mm


class Config(NamedTuple):
    """Static settings of a fit (hashable: they select code, not values)."""

    model: str
    static: object  # the model's prepared static value (the multipole's n_pairs), or None
    outputs: tuple  # which outputs the data hold, e.g. ("R",), ("R", "T"), ("T",)
    relative: bool  # free scale
    free_eta: bool
    solver: str
    rtol: float
    atol: float
    max_steps: int
    fresnel: str

    @property
    def n_params(self) -> int:
        return 2 + int(self.relative) + int(self.free_eta)


TRACES = {"solve": 0, "initial_guess": 0, "data_guess": 0}
"""How often each stage was traced (a test checks that a second call with new values does not retrace)."""


def unpack(theta, eta, cfg: Config):
    """Physical parameters from the log-parameters ``theta = [log sigma_a, log sigma_s', (log scale), (log eta)]``."""
    sa, ss = jnp.exp(theta[0]), jnp.exp(theta[1])
    i = 2
    scale = jnp.exp(theta[i]) if cfg.relative else jnp.ones_like(sa)
    i += int(cfg.relative)
    eta = jnp.exp(theta[i]) if cfg.free_eta else eta
    return sa, ss, scale, eta


def predict(r, sa, ss, eta, d, cfg: Config):
    """Model outputs stacked as ``(K, N)`` in the order of ``cfg.outputs``, per incident photon."""
    prof = model_profiles(resolve_model(cfg.model), r, sa, ss, eta, d, cfg.static, fresnel=cfg.fresnel)
    return jnp.stack([prof[o] for o in cfg.outputs])


def weights(y, se, cfg: Config):
    """``(w, usable)``: residual weights and the points that can enter a fit, each ``(K, N)``.

    ``se > 0`` is a given standard error (weight ``1 / se``); ``se == 0`` marks "no standard error" (relative
    weight ``1 / y``, and only points with ``y > 0`` are usable). The choice is data, not code, so fits with and
    without standard errors share one compilation."""
    given = se > 0.0
    ok = given | (y > 0.0)
    w = jnp.where(given, 1.0 / jnp.where(given, se, 1.0), jnp.where(y > 0.0, 1.0 / jnp.where(y > 0.0, y, 1.0), 0.0))
    return w, ok


def _scaled_prediction(theta, extra, cfg: Config):
    r, eta, d = extra
    sa, ss, scale, eta_ = unpack(theta, eta, cfg)
    return scale * predict(r, sa, ss, eta_, d, cfg)


def residuals(theta, args):
    r, y, w, mask, eta, d, cfg = args
    pred = _scaled_prediction(theta, (r, eta, d), cfg)
    return jnp.where(mask, w * (pred - y), 0.0).reshape(-1)


# --- Stage 1 ------------------------------------------------------------------------------------------------------
def data_guess(r, y, se, eta, r_lo, r_hi, cfg: Config):
    """``(rd, ld, rd_clamped, slope_failed)`` from the data alone (see the module docstring)."""
    TRACES["data_guess"] += 1
    w, usable = weights(y, se, cfg)
    y0, w0 = y[0], w[0]
    in_range = (r >= r_lo) & (r <= r_hi)
    pos = usable[0] & in_range & (y0 > 0.0) & (r > 0.0)
    big = jnp.finfo(r.dtype).max
    r_first = jnp.min(jnp.where(pos, r, big))
    r_last = jnp.max(jnp.where(pos, r, -big))
    # Far field: the outer half of the radii with positive data. log(r^2 R) ~ const - sigma_tr r there.
    far = pos & (r >= 0.5 * (r_first + r_last))
    q = jnp.where(far, (w0 * y0) ** 2, 0.0)  # log-space weights: (R / stderr)^2, or 1 for relative weighting
    z = jnp.log(jnp.where(far, r * r * y0, 1.0))
    qs = jnp.sum(q)
    rm = jnp.sum(q * r) / qs
    zm = jnp.sum(q * z) / qs
    slope = jnp.sum(q * (r - rm) * (z - zm)) / jnp.sum(q * (r - rm) ** 2)
    sigma_tr = -slope
    slope_failed = (jnp.sum(far) < 2) | ~jnp.isfinite(sigma_tr) | (sigma_tr <= 0.0)
    # Fallback: a decay length of the span of the data.
    span = jnp.where(jnp.isfinite(r_last - r_first) & (r_last > r_first), r_last - r_first, 1.0)
    sigma_tr = jnp.where(slope_failed, 1.0 / span, sigma_tr)
    ld = jnp.clip(1.0 / sigma_tr, *LD_CLAMP)
    slope_failed = slope_failed | (ld != 1.0 / sigma_tr)
    # Rd: the plane integral of the first output over the data range, per entering photon.
    if cfg.relative:
        rd_raw = jnp.asarray(0.5, dtype=r.dtype)
    else:
        yy = jnp.where(in_range, y0, 0.0)
        f = 2.0 * jnp.pi * r * yy
        rd_raw = jnp.sum(0.5 * (f[1:] + f[:-1]) * jnp.diff(r)) / entry_transmittance(eta)
    rd = jnp.clip(rd_raw, *RD_CLAMP)
    rd_clamped = (rd != rd_raw) & (not cfg.relative)
    return rd, ld, rd_clamped, slope_failed


# --- Stage 2 ------------------------------------------------------------------------------------------------------
def candidates(rd, ld, eta, fresnel):
    """``(sigma_a, sigma_s')`` of the start candidates: the data's ``Rd`` and :data:`RD_GRID`, at ``l_d``."""
    rds = jnp.concatenate([jnp.reshape(rd, (1,)), jnp.asarray(RD_GRID, dtype=jnp.result_type(rd))])
    med = jaxsss.from_rd_ld(rds, ld, eta, fresnel=fresnel).medium
    return med.sigma_a, med.sigma_s_prime


def initial_guess(r, y, se, eta, d, r_lo, r_hi, auto, rd, ld, cfg: Config):
    """``(theta0, mask, r_cut, range_fallback)``: the start and the fit range (see the module docstring)."""
    TRACES["initial_guess"] += 1
    w, usable = weights(y, se, cfg)
    in_range = usable & ((r >= r_lo) & (r <= r_hi))[None, :]
    sa_c, ss_c = candidates(rd, ld, eta, cfg.fresnel)
    p = cfg.n_params

    r_min_lu = resolve_model(cfg.model).r_min_lu  # the default range starts at r_min_lu * l_u (model-specific)

    def score(sa, ss):
        pred = predict(r, sa, ss, eta, d, cfg)
        m = in_range & (r >= r_min_lu / (sa + ss))[None, :]
        if cfg.relative:  # least-squares scale, profiled out
            scale = jnp.sum(jnp.where(m, (w * pred) * (w * y), 0.0)) / jnp.sum(jnp.where(m, (w * pred) ** 2, 0.0))
        else:
            scale = jnp.ones_like(sa)
        res = jnp.where(m, w * (scale * pred - y), 0.0)
        n = jnp.sum(m).astype(res.dtype)
        s = jnp.sum(res**2) / jnp.maximum(n, 1.0)
        s = jnp.where((n > p) & jnp.isfinite(s) & (scale > 0.0), s, jnp.inf)
        return s, scale

    scores, scales = jax.vmap(score)(sa_c, ss_c)
    best = jnp.argmin(scores)  # all inf -> 0, the data's own Rd
    sa0, ss0, scale0 = sa_c[best], ss_c[best], jnp.where(jnp.isfinite(scales[best]) & (scales[best] > 0),
                                                         scales[best], 1.0)
    theta0 = [jnp.log(sa0), jnp.log(ss0)]
    if cfg.relative:
        theta0.append(jnp.log(scale0))
    if cfg.free_eta:
        theta0.append(jnp.log(eta))
    theta0 = jnp.stack(theta0)
    # Fit range: r >= r_min_lu * l_u at the start (the diffusion models, r_min_lu = 1, fail nearer the source) when
    # ``auto``, else the user's r_min (a traced flag, so both share one compilation).
    r_cut = jnp.where(auto, r_min_lu / (sa0 + ss0), r_lo)
    mask = in_range & (r >= r_cut)[None, :]
    fallback = jnp.sum(mask) <= p
    mask = jnp.where(fallback, in_range, mask)
    return theta0, mask, r_cut, fallback


# --- Stage 3 ------------------------------------------------------------------------------------------------------
def solve(theta0, mask, r, y, se, eta, d, cfg: Config):
    """Least squares from ``theta0`` on ``mask``; returns a dict of per-problem arrays (estimates, errors, status)."""
    TRACES["solve"] += 1
    w, _ = weights(y, se, cfg)
    args = (r, y, w, mask, eta, d, cfg)
    solver = resolve_solver(cfg.solver).make(rtol=cfg.rtol, atol=cfg.atol)
    fn = lambda th, a: residuals(th, (*a, cfg))  # noqa: E731  (cfg is static, not an argument leaf)
    sol = optx.least_squares(fn, solver, theta0, args=args[:-1], max_steps=cfg.max_steps, throw=False)
    theta = sol.value
    sa, ss, scale, eta_hat = unpack(theta, eta, cfg)
    out = {"sigma_a": sa, "sigma_s_prime": ss, "scale": scale, "eta": eta_hat, "result": sol.result,
           "iterations": sol.stats["num_steps"]}
    out.update(covariance(theta, args, cfg))
    return out


def covariance(theta, args, cfg: Config):
    """Standard errors from ``J^T J`` at the solution, scaled by the residual variance ``SSR / (n - p)``."""
    th = jax.lax.stop_gradient(theta)
    res = residuals(th, args)
    J = jax.jacfwd(residuals)(th, args)  # (K N, p), in the log-parameters
    ssr = jnp.sum(res**2)
    n = jnp.sum(args[3]).astype(res.dtype)
    p = cfg.n_params
    dof = jnp.maximum(n - p, 1.0)
    s2 = ssr / dof
    JTJ = J.T @ J
    # Normalised (unit-diagonal) J^T J: its condition number is independent of the parameters' scales.
    dn = jnp.sqrt(jnp.diag(JTJ))
    dn_safe = jnp.where(dn > 0, dn, 1.0)
    M = JTJ / jnp.outer(dn_safe, dn_safe)
    eig = jnp.linalg.eigvalsh(M)
    cond = jnp.where((eig[0] > 0) & jnp.all(dn > 0), eig[-1] / eig[0], jnp.inf)
    Minv = jnp.linalg.inv(M)
    cov_log = s2 * Minv / jnp.outer(dn_safe, dn_safe)
    se_log = jnp.sqrt(jnp.diag(cov_log))
    singular = ~jnp.isfinite(cond) | (cond > 1e15)
    se_log = jnp.where(singular | ~jnp.isfinite(se_log), jnp.inf, se_log)
    corr = Minv[0, 1] / jnp.sqrt(Minv[0, 0] * Minv[1, 1])
    corr = jnp.where(singular | ~jnp.isfinite(corr), jnp.sign(Minv[0, 1]) * 1.0, jnp.clip(corr, -1.0, 1.0))
    # Physical standard errors through the log-parameter Jacobian: d x / d log x = x.
    values = jnp.exp(th)
    out = {
        "sigma_a_stderr": values[0] * se_log[0],
        "sigma_s_prime_stderr": values[1] * se_log[1],
        "correlation": corr,
        "condition_number": cond,
        "residual_norm": jnp.sqrt(ssr),
        "reduced_chi2": s2,
        "n_points": n,
    }
    i = 2
    if cfg.relative:
        out["scale_stderr"] = values[i] * se_log[i]
        i += 1
    if cfg.free_eta:
        out["eta_stderr"] = values[i] * se_log[i]
    big = jnp.finfo(args[0].dtype).max
    m = jnp.any(args[3], axis=0)
    out["r_min"] = jnp.min(jnp.where(m, args[0], big))
    out["r_max"] = jnp.max(jnp.where(m, args[0], -big))
    return out


def solve_params(theta0, mask, r, y, se, eta, d, cfg: Config):
    """The fitted ``(sigma_a, sigma_s')`` only: what :func:`fitting.fit_jacobian_wrt_data` differentiates."""
    w, _ = weights(y, se, cfg)
    solver = resolve_solver(cfg.solver).make(rtol=cfg.rtol, atol=cfg.atol)
    fn = lambda th, a: residuals(th, (*a, cfg))  # noqa: E731
    sol = optx.least_squares(fn, solver, theta0, args=(r, y, w, mask, eta, d), max_steps=cfg.max_steps, throw=False)
    sa, ss, _, _ = unpack(sol.value, eta, cfg)
    return jnp.stack([sa, ss])


__all__ = ["Config", "TRACES", "data_guess", "initial_guess", "predict", "solve", "solve_params"]
