"""The compiled pieces of a profile fit, for ONE problem (one channel of one profile); callers vmap them.

Pieces, each a pure traceable function of arrays with a static :class:`Config`:

1. :func:`data_guess` -- from the data alone: ``l_d`` from the far-field log-slope of ``r^2 R(r)`` (the dipole's far
   field falls like ``exp(-sigma_tr r) / r^2``).
2. :func:`starts` -- a grid of candidates over the reduced albedo and ``l_d`` (:data:`ONE_MINUS_ALBEDO` times
   :data:`LD_FACTORS` of the data's ``l_d``, in closed form by Eq. 16) is scored in one batched evaluation of the
   forward model (weighted mean squared residual on the fit range, the scale profiled out for relative data). The
   best candidate is the first start; the local minima of the score over the grid (its basins) of lowest and of
   highest albedo (within :data:`LOCAL_MIN_RATIO` of the best score) are the other two. All are solved; the one with
   the lowest cost is the answer and the others tell whether the minimum is unique (:func:`finish`). One start
   from data computed on a cut range can land in a wrong basin (issue 18: skin1 blue with ``r_min`` = 1 mm went to
   sigma_a 0.034, sigma_s' 16.1 against the truth 0.48, 1.01, at 200x the truth's cost).
3. :func:`lm_solve` (the default ``levenberg_marquardt``) -- a small Levenberg-Marquardt loop in the log-parameters
   (Marquardt's diagonal scaling, Nielsen's damping update). It stops when the undamped Gauss-Newton step is below
   ``atol + rtol |theta|`` in every log-parameter: the point is then stationary to that precision (this also ends
   fits that sit on the float64 rounding floor of noisy data), or by MINPACK's relative-reduction test. Other
   solvers go through :func:`optimistix.least_squares`. :func:`lm_block` runs a few iterations of many problems at
   once so that a batch can retire converged problems and refill their slots (``fitting.profile_fit``).
   Rough (tabulated) models then get :func:`with_valley`: scans along the solution's valley and starts from their
   best points (the tables' noise makes local minima there).
4. :func:`finish` -- the covariance from ``J^T J`` at the chosen solution and the suspect-fit checks.

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

from fitting._dipole_jac import dipole_value_and_jac
from fitting.result import CHI2_P
from fitting.models import model_profiles, resolve_model
from fitting.solvers import resolve_solver, results_from_code

# Candidate reduced albedos of the start, as 1 - alpha' = sigma_a / sigma_t': alpha' in factors of 2 from 1e-4 to
# 0.41 (dilute media such as the Narasimhan table's wines have alpha' ~ 1e-3), then 1 - alpha' in factors of 2 from
# 0.25 to 6e-8 (Rd ~ 0.9995 at eta 1.3): the best candidate is within a factor 1.4 of any material's.
ONE_MINUS_ALBEDO = tuple(1.0 - 1e-4 * 2.0**k for k in range(13)) + tuple(0.5**k for k in range(2, 25))
# Multiples of the data's l_d tried with every Rd: the far-field slope is biased on short or cut ranges.
LD_FACTORS = (0.5, 0.7, 1.0, 1.4, 2.0)
SCORE_RADII = 32  # the start candidates are scored on at most this many radii of the fit range (see score_radii)
ALT_MAX_STEPS = 48  # iteration cap of the second and third starts (see step_limits)
LOCAL_MIN_RATIO = 100.0  # the other starts: local minima of the candidates' score within this factor of the best
LD_CLAMP = (1e-6, 1e6)  # mm
N_STARTS = 3
LM_LAMBDA0 = 1e-3  # initial Marquardt damping (relative to diag(J^T J))
# Suspect-fit thresholds (see :func:`finish`).
ALT_DCHI2 = 4.0  # another minimum within this many units of chi^2 (in the fit's own residual variance) is a tie
STRUCTURE_RHO = 0.5  # lag-1 autocorrelation of the residuals above this (no standard errors given) ...
STRUCTURE_RMS = 1e-6  # ... with an rms relative misfit above this: a systematic misfit
ALT_SEPARATION = 1e-3  # ... if it differs by more than this in log sigma_a or log sigma_s' (and 3 standard errors)
# Models tabulated by Monte Carlo (``ForwardModel.rough``): VALLEY_ROUNDS rounds of two more starts along the valley
# of the best solution so far (the covariance's major axis), each the lowest-cost point of a scan at VALLEY_SCAN
# distances in (log sigma_a, log sigma_s') on its side. The mc sweep's fits that stopped in minima of the table noise
# sat 0.25-0.9 from the truth along the valley, some behind two barriers (benchmarks/fit_sweep.py; docs/benchmarks.md).
VALLEY_SCAN = (0.15, 0.3, 0.45, 0.6, 0.75, 0.9)
VALLEY_ROUNDS = 3  # scans from the best solution so far: the noise's minima can form a staircase along the valley
# The covariance of a rough model's fit comes from a central-difference Jacobian of this step in the log-parameters
# (one radial bin of the white-MC tables is 0.115 in log r): the local derivative of an interpolant through noisy
# nodes measures the noise's curvature, not the data's information, and gave standard errors of 1-2% for far-field
# fits 25-35% from the truth along a flat valley (the mc sweep; docs/benchmarks.md).
ROUGH_JACOBIAN_STEP = 0.1


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

    @property
    def native(self) -> bool:
        """The solver is this module's batched Levenberg-Marquardt loop."""
        return resolve_solver(self.solver).native


TRACES = {"fit": 0, "starts": 0, "solve": 0, "lm_block": 0, "finish": 0, "data_guess": 0, "valley": 0}
"""How often each piece was traced (a test checks that a second call with new values does not retrace)."""


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
    # A non-finite or overflowing trial (a near-singular step) gives NaN residuals, not a model evaluated at NaN or
    # inf (whose boundary checks would raise). exp(700) ~ 1e304.
    bad = ~jnp.all(jnp.abs(theta) < 700.0)
    pred = _scaled_prediction(jnp.where(bad, 0.0, theta), (r, eta, d), cfg)
    return jnp.where(bad, jnp.nan, jnp.where(mask, w * (pred - y), 0.0)).reshape(-1)


# --- 1. Data-driven Rd and l_d --------------------------------------------------------------------------------------
def data_guess(r, y, se, r_lo, r_hi, cfg: Config):
    """``(ld, slope_failed)``: ``l_d`` from the far-field log-slope of the first output (see the module docstring)."""
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
    return ld, slope_failed | (ld != 1.0 / sigma_tr)


# --- 2. Multi-start ------------------------------------------------------------------------------------------------
def score_radii(r, r_lo, r_hi, real):
    """``(idx, keep)``, each ``(M,)`` with ``M = min(N, SCORE_RADII)``: indices of radii spread evenly (in index)
    from the first to the last radius in ``[r_lo, r_hi]`` that is ``real`` (not padding, ``(N,)`` bool), and which of
    them are new (repeats, when the range holds fewer than ``M`` radii, are left out)."""
    n = r.shape[0]
    m = min(n, SCORE_RADII)
    inside = (r >= r_lo) & (r <= r_hi) & real
    pos = jnp.arange(n)
    first = jnp.min(jnp.where(inside, pos, n - 1))
    last = jnp.max(jnp.where(inside, pos, 0))
    last = jnp.maximum(last, first)
    frac = jnp.arange(m, dtype=r.dtype) / max(m - 1, 1)
    idx = first + jnp.round(frac * (last - first).astype(r.dtype)).astype(first.dtype)
    keep = jnp.concatenate([jnp.ones((1,), bool), idx[1:] != idx[:-1]])
    return idx, keep


def candidates(ld):
    """``(sigma_a, sigma_s', 1 - alpha')`` of the start candidates, each ``(n_albedo * n_ld,)``: the reduced albedos
    of :data:`ONE_MINUS_ALBEDO` at :data:`LD_FACTORS` times ``l_d``, by the hierarchical paper's Eq. 16 (closed form,
    no Rd inversion in the compiled fit)."""
    dt = jnp.result_type(ld)
    om, lds = jnp.meshgrid(jnp.asarray(ONE_MINUS_ALBEDO, dtype=dt), ld * jnp.asarray(LD_FACTORS, dtype=dt),
                           indexing="ij")
    om, lds = om.reshape(-1), lds.reshape(-1)
    # Eq. 16: u = sqrt(3 (1 - alpha')) = sigma_tr / sigma_t'; sigma_a = sigma_tr u / 3; sigma_s' = alpha' sigma_t'.
    u = jnp.sqrt(3.0 * om)
    sigma_tr = 1.0 / lds
    return sigma_tr * u / 3.0, (1.0 - om) * sigma_tr / u, om


def starts(r, y, se, eta, d, r_lo, r_hi, auto, cfg: Config):
    """``(theta0, mask, r_cut, flags)``: :data:`N_STARTS` starts ``(N_STARTS, p)``, the fit range ``(K, N)``, the
    threshold ``r >= r_cut`` and the notes' flags ``(slope_failed, range_fallback, ratio_raised)``."""
    TRACES["starts"] += 1
    ld, slope_failed = data_guess(r, y, se, r_lo, r_hi, cfg)
    w_full, usable_full = weights(y, se, cfg)
    in_range_full = usable_full & ((r >= r_lo) & (r <= r_hi))[None, :]
    sa_c, ss_c, om_c = candidates(ld)
    p = cfg.n_params
    model = resolve_model(cfg.model)
    r_min_lu = model.r_min_lu  # the default range starts at r_min_lu * l_u (model-specific)

    # The candidates are scored on at most SCORE_RADII radii spread evenly (in index) over [r_lo, r_hi]: ranking
    # needs no precision, and the candidates' predictions are most of a batch's cost (180 x N per problem).
    # (A model with a range limit, r_max_ld l_d, and no r_max given: spread them up to that limit at the largest
    # candidate l_d, not over every radius: the range may hold a few of them only.)
    r_top = r_hi if model.r_max_ld is None else jnp.where(jnp.isinf(r_hi), model.r_max_ld * ld * max(LD_FACTORS),
                                                          r_hi)
    idx, keep = score_radii(r, r_lo, r_top, jnp.any(se >= 0.0, axis=0))  # se < 0: padding (profile_fit._pad_radii)
    r_s = r[idx]
    y, w = y[:, idx], w_full[:, idx]
    in_range = in_range_full[:, idx] & keep[None, :]
    # Every candidate's prediction once (one batched model evaluation); both passes below score from it.
    preds = jax.vmap(lambda a, b: predict(r_s, a, b, eta, d, cfg))(sa_c, ss_c)  # (n_candidates, K, M)

    def score(sa, pred, m):
        if cfg.relative:  # least-squares scale, profiled out
            scale = jnp.sum(jnp.where(m, (w * pred) * (w * y), 0.0)) / jnp.sum(jnp.where(m, (w * pred) ** 2, 0.0))
        else:
            scale = jnp.ones_like(sa)
        res = jnp.where(m, w * (scale * pred - y), 0.0)
        n = jnp.sum(m).astype(res.dtype)
        s = jnp.sum(res**2) / jnp.maximum(n, 1.0)
        s = jnp.where((n > p) & jnp.isfinite(s) & (scale > 0.0), s, jnp.inf)
        return s, scale

    def range_mask(sa, ss, inside=in_range, radii=r_s):
        r_cut = jnp.where(auto, r_min_lu / (sa + ss), r_lo)
        m = inside & (radii >= r_cut)[None, :]
        if model.r_max_ld is not None:  # no r_max given (inf): the model's own limit, r_max_ld l_d at the start
            r_top = jnp.where(jnp.isinf(r_hi), model.r_max_ld / jnp.sqrt(3.0 * sa * (sa + ss)), r_hi)
            m = m & (radii <= r_top)[None, :]
        fallback = jnp.sum(m) <= p
        return jnp.where(fallback, inside, m), r_cut, fallback

    # The default range depends on the start: a first pass scores each candidate on its own range (mean squares, so
    # that ranges of different lengths compare), the best one fixes the range, and a second pass scores every
    # candidate on that one range (the starts and the final costs then compare).
    s0, _ = jax.vmap(lambda a, b, pr: score(a, pr, range_mask(a, b)[0]))(sa_c, ss_c, preds)
    first = jnp.argmin(s0)
    mask_s, _, _ = range_mask(sa_c[first], ss_c[first])
    mask, r_cut, fallback = range_mask(sa_c[first], ss_c[first], in_range_full, r)  # the fit's range, all radii
    scores, scales = jax.vmap(lambda a, pr: score(a, pr, mask_s))(sa_c, preds)
    best = jnp.argmin(scores)  # all inf -> 0, the data's own Rd
    # The other starts: the basins of the score over the (albedo, l_d) grid are its local minima (no neighbour of
    # the 8 lower); the ones of lowest and of highest albedo within a factor LOCAL_MIN_RATIO of the best score.
    # (Nearest-neighbour alternatives are not enough: with 1% noise on a skin-like channel the best candidate, its
    # neighbours and the best candidates a factor 4 away in albedo all led to one wrong minimum; the truth's basin
    # showed as a local minimum at 3x the best score, 30x lower in albedo.)
    grid = scores.reshape(len(ONE_MINUS_ALBEDO), len(LD_FACTORS))
    padded = jnp.pad(grid, 1, constant_values=jnp.inf)
    n_a, n_l = grid.shape
    neighbours = jnp.stack([padded[1 + da:1 + da + n_a, 1 + dl:1 + dl + n_l]
                            for da in (-1, 0, 1) for dl in (-1, 0, 1) if (da, dl) != (0, 0)])
    local = (jnp.all(grid <= neighbours, axis=0) & jnp.isfinite(grid)).reshape(-1)
    local = local & (scores <= LOCAL_MIN_RATIO * scores[best])
    lowest = jnp.argmax(jnp.where(local, om_c, -jnp.inf))  # the lowest albedo (largest 1 - alpha')
    highest = jnp.argmin(jnp.where(local, om_c, jnp.inf))
    lowest = jnp.where(local[lowest], lowest, best)
    highest = jnp.where(local[highest], highest, best)
    picks = jnp.stack([best, lowest, highest])
    sa0, ss0 = sa_c[picks], ss_c[picks]
    sc = scales[picks]
    sc = jnp.where(jnp.isfinite(sc) & (sc > 0), sc, 1.0)
    ratio_raised = jnp.zeros((), bool)
    if model.ratio_min is not None:
        # Clamp the starts into the model's validity range sigma_a / sigma_s' >= ratio_min (said in the notes).
        rmin = float(model.ratio_min(cfg.static))
        low = sa0 < rmin * ss0
        ratio_raised = low[0]
        sa0 = jnp.where(low, rmin * ss0, sa0)
    cols = [jnp.log(sa0), jnp.log(ss0)]
    if cfg.relative:
        cols.append(jnp.log(sc))
    if cfg.free_eta:
        cols.append(jnp.broadcast_to(jnp.log(eta), sa0.shape))
    theta0 = jnp.stack(cols, axis=1)
    return theta0, mask, r_cut, (slope_failed, fallback, ratio_raised)


# --- 3. Solvers -----------------------------------------------------------------------------------------------------
_RUNNING, _CONVERGED, _MAX_STEPS, _NONFINITE, _SLOW = 0, 1, 2, 3, 4  # _SLOW: stopped by the reduction test


class LMState(NamedTuple):
    """Levenberg-Marquardt state of one problem (all arrays, so that batches can be gathered and scattered)."""

    theta: jax.Array  # (p,)
    lam: jax.Array  # damping
    nu: jax.Array  # damping growth on rejection (Nielsen)
    steps: jax.Array  # iterations done
    status: jax.Array  # _RUNNING, _CONVERGED, _MAX_STEPS, _NONFINITE, _SLOW
    limit: jax.Array  # iteration cap of this problem


def lm_init(theta0, limit) -> LMState:
    # Every field derived from theta0, so that under vmap the whole carry is batched from the start: the while
    # loop's batching rule then traces its body once instead of twice (a fixpoint over the carry's batched-ness).
    zero = 0.0 * theta0[0]
    izero = zero.astype(jnp.int32)
    return LMState(theta0, zero + LM_LAMBDA0, zero + 2.0, izero, izero + _RUNNING,
                   izero + jnp.asarray(limit, jnp.int32))


def step_limits(n_starts: int, cfg: Config):
    """Iteration caps of the starts: ``max_steps`` for the first, ``min(max_steps, ALT_MAX_STEPS)`` for the others
    (they only test for another basin; one that crawls is abandoned rather than holding up a batch)."""
    return jnp.asarray([cfg.max_steps] + [min(cfg.max_steps, ALT_MAX_STEPS)] * (n_starts - 1), jnp.int32)


def _hand_jacobian(cfg: Config) -> bool:
    """The dipole with fixed ``eta`` has a hand-written Jacobian (:mod:`fitting._dipole_jac`)."""
    return cfg.model == "dipole" and not cfg.free_eta and cfg.outputs == ("R",)


def _linearise(theta, args):
    """``(residuals (K N,), J (K N, p))`` at ``theta``."""
    cfg = args[-1]
    if _hand_jacobian(cfg):
        r, y, w, mask, eta, d, _ = args
        bad = ~jnp.all(jnp.abs(theta) < 700.0)  # as in residuals()
        sa, ss, scale, _ = unpack(jnp.where(bad, 0.0, theta), eta, cfg)
        R, dla, dls = dipole_value_and_jac(r, sa, ss, eta, cfg.fresnel)
        cols = [scale * dla, scale * dls] + ([scale * R] if cfg.relative else [])  # d/d log scale = scale R
        J = jnp.where(mask[0][:, None], w[0][:, None] * jnp.stack(cols, axis=1), 0.0)
        res = jnp.where(bad, jnp.nan, jnp.where(mask[0], w[0] * (scale * R - y[0]), 0.0))
        return res, jnp.where(bad, 0.0, J)

    def res(th):  # the residuals once, as value and as auxiliary output (one trace of the model)
        v = residuals(th, args)
        return v, v

    J, rr = jax.jacfwd(res, has_aux=True)(theta)
    return rr, J


def _secant_jacobian(theta, args):
    """``(residuals, J)`` with ``J`` by central differences of step :data:`ROUGH_JACOBIAN_STEP` (rough models)."""
    h = ROUGH_JACOBIAN_STEP
    p = theta.shape[0]
    e = h * jnp.eye(p, dtype=theta.dtype)
    # The centre and the 2 p displaced points in one batched evaluation: one copy of the model in the compiled fit
    # (each copy adds ~1 s of compilation for the white-MC family; three separate calls here made 6 of its 14).
    res = jax.vmap(lambda d: residuals(theta + d, args))(jnp.concatenate([jnp.zeros((1, p), theta.dtype), e, -e]))
    return res[0], ((res[1:p + 1] - res[p + 1:]) / (2.0 * h)).T


def _covariance_jacobian(theta, args):
    """The Jacobian the covariance and the valley use: the model's own, or the secant one for rough models."""
    if resolve_model(args[-1].model).rough:
        return _secant_jacobian(theta, args)
    return _linearise(theta, args)


def solve_small(A, b):
    """``A^{-1} b`` for the LM's ``p x p`` normal equations: in closed form (the adjugate over the determinant) for
    ``p`` = 2 and 3, where a batched LAPACK call per problem and iteration costs more than the arithmetic; else
    :func:`jax.numpy.linalg.solve`. A singular ``A`` gives non-finite values (as the LU does), which the caller
    rejects."""
    p = A.shape[0]
    if p == 2:
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        return jnp.stack([A[1, 1] * b[0] - A[0, 1] * b[1], A[0, 0] * b[1] - A[1, 0] * b[0]]) / det
    if p == 3:
        c0, c1, c2 = A[:, 0], A[:, 1], A[:, 2]
        det = jnp.dot(c0, jnp.cross(c1, c2))
        # Cramer's rule: x_i = det(A with column i replaced by b) / det(A)
        return jnp.stack([jnp.dot(b, jnp.cross(c1, c2)), jnp.dot(c0, jnp.cross(b, c2)),
                          jnp.dot(c0, jnp.cross(c1, b))]) / det
    return jnp.linalg.solve(A, b)


def lm_step(state: LMState, args, cfg: Config) -> LMState:
    """One Levenberg-Marquardt iteration (a no-op for a problem that has stopped)."""
    theta = state.theta
    rr, J = _linearise(theta, args)
    f = jnp.sum(rr**2)
    g = J.T @ rr
    H = J.T @ J
    p = theta.shape[0]
    eye = jnp.eye(p, dtype=theta.dtype)
    dg = jnp.maximum(jnp.diag(H), jnp.finfo(theta.dtype).tiny)
    # Gauss-Newton step (undamped): below the tolerance in every log-parameter -> stationary, stop.
    gn = solve_small(H + 1e-300 * eye, -g)
    tol = cfg.atol + cfg.rtol * jnp.abs(theta)
    converged = jnp.all(jnp.isfinite(gn)) & jnp.all(jnp.abs(gn) <= tol)
    # Damped step (Marquardt's scaling diag(J^T J)), and the undamped one: whichever lowers the cost more is taken
    # (near the minimum that is the Gauss-Newton step, so the last steps converge quadratically and a stop by the
    # reduction test below leaves no damping error behind).
    delta = solve_small(H + state.lam * jnp.diag(dg), -g)
    # Both trials in one batched evaluation (one copy of the model in the compiled loop).
    ft, ft_gn = jax.vmap(lambda dl: jnp.sum(residuals(theta + dl, args) ** 2))(jnp.stack([delta, gn]))
    ft = jnp.where(jnp.isfinite(ft), ft, jnp.inf)
    use_gn = jnp.isfinite(ft_gn) & (ft_gn < ft) & jnp.all(jnp.isfinite(gn))
    # Within the cost's rounding: a Gauss-Newton step whose predicted reduction is below 1e-13 f cannot be judged by
    # the cost (the sum of squares is only good to ~1e-15 relative); it is taken on the gradient's word, so the
    # stationarity test above can be met (seen: 1% noise, 40 radii, stuck 1.6e-9 from the minimum in log sigma_a).
    pred_gn = -(g @ gn)
    blind = jnp.all(jnp.isfinite(gn)) & (pred_gn <= 1e-13 * f)
    use_gn = use_gn | blind
    delta, ft = jnp.where(use_gn, gn, delta), jnp.where(use_gn, jnp.where(blind, jnp.minimum(ft_gn, f), ft_gn), ft)
    trial = theta + delta
    accept = jnp.isfinite(ft) & ((ft < f) | blind) & jnp.all(jnp.isfinite(delta))
    pred = -(2.0 * delta @ g + delta @ H @ delta)
    # Or MINPACK's ftol test on a damped step that the Gauss-Newton step could not beat: its actual and predicted
    # relative reductions of the cost are both below rtol. It ends slow crawls along curved valleys (e.g. towards
    # sigma_a -> 0 from a wrong start), where Gauss-Newton fails; near a regular minimum the Gauss-Newton step wins
    # and the test above stops with the full precision.
    stop = accept & ~use_gn & (f - ft <= cfg.rtol * f) & (pred <= cfg.rtol * f)
    rho = (f - ft) / jnp.where(pred > 0, pred, 1.0)
    lam = jnp.where(accept, state.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), state.lam * state.nu)
    nu = jnp.where(accept, 2.0, 2.0 * state.nu)
    lam = jnp.clip(lam, 1e-12, 1e16)
    new_theta = jnp.where(accept & ~converged, trial, theta)
    steps = state.steps + 1
    bad = ~jnp.isfinite(f)
    status = jnp.where(converged, _CONVERGED, jnp.where(stop, _SLOW, jnp.where(bad, _NONFINITE,
                       jnp.where(steps >= state.limit, _MAX_STEPS, _RUNNING))))
    new = LMState(new_theta, lam, jnp.minimum(nu, 1e8), steps, status.astype(jnp.int32), state.limit)
    running = state.status == _RUNNING
    return jax.tree_util.tree_map(lambda a, b: jnp.where(running, a, b), new, state)


def status_result(status):
    """``optimistix.RESULTS`` of LM status codes (any shape)."""
    R = optx.RESULTS

    def one(st):
        return R.where((st == _CONVERGED) | (st == _SLOW), R.successful,
                       R.where(st == _MAX_STEPS, R.nonlinear_max_steps_reached, R.nonlinear_divergence))

    status = jnp.asarray(status)
    out = jax.vmap(one)(status.reshape(-1))
    return jax.tree_util.tree_map(lambda x: x.reshape(status.shape), out)


def lm_solve(theta0, limit, args, cfg: Config):
    """``(theta, result, steps, stationary)``: the LM loop from ``theta0`` until it stops (one problem);
    ``stationary``: stopped by the Gauss-Newton test (not by the reduction test)."""
    state = jax.lax.while_loop(lambda s: s.status == _RUNNING, lambda s: lm_step(s, args, cfg),
                               lm_init(theta0, limit))
    return state.theta, status_result(state.status), state.steps, state.status == _CONVERGED


def lm_block(state: LMState, args, cfg: Config, n_steps: int) -> LMState:
    """``n_steps`` iterations (fewer if the problem stops) of one problem; batches vmap it."""
    TRACES["lm_block"] += 1
    return jax.lax.fori_loop(0, n_steps, lambda _, s: lm_step(s, args, cfg), state)


def optx_solve(theta0, limit, args, cfg: Config):
    """``(theta, result, steps, stationary)`` with an Optimistix solver of the registry."""
    solver = resolve_solver(cfg.solver).make(rtol=cfg.rtol, atol=cfg.atol)
    fn = lambda th, a: residuals(th, (*a, cfg))  # noqa: E731  (cfg is static, not an argument leaf)
    del limit  # Optimistix's cap is static: every start gets max_steps
    sol = optx.least_squares(fn, solver, theta0, args=args[:-1], max_steps=cfg.max_steps, throw=False)
    return sol.value, sol.result, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def solve_starts(theta0s, mask, r, y, se, eta, d, cfg: Config):
    """Solve from every start ``(S, p)``: ``(theta (S, p), result (S,), steps (S,), stationary (S,))``."""
    TRACES["solve"] += 1
    w, _ = weights(y, se, cfg)
    args = (r, y, w, mask, eta, d, cfg)
    one = lm_solve if cfg.native else optx_solve
    return jax.vmap(lambda th, lim: one(th, lim, args, cfg))(theta0s, step_limits(theta0s.shape[0], cfg))


def _chosen(thetas, results, stationary, costs):
    """Index of the chosen solution: the converged one of lowest cost (a stationary one wins a tie to 1e-9: costs at
    the float64 floor of noisy data agree to ~1e-15 while the parameters of a stop by the reduction test may differ by
    1e-9); and the sort key and convergence flags of every start."""
    ok = (results == optx.RESULTS.successful) & jnp.isfinite(costs)
    key = jnp.where(ok, costs * jnp.where(stationary, 1.0, 1.0 + 1e-9),
                    jnp.where(jnp.isfinite(costs), 1e300 + costs, jnp.inf))
    return jnp.argmin(key), key, ok


def valley_starts(thetas, results, steps, stationary, mask, r, y, se, eta, d, cfg: Config):
    """Two starts ``(2, p)`` either side of the chosen solution along its valley: on the major axis of the covariance
    (``(J^T J)^-1`` at the solution; ``eta``, when free, moves with it as the axis says; a free scale is profiled out
    at every point), the point of lowest cost among :data:`VALLEY_SCAN` distances in ``(log sigma_a, log sigma_s')``
    on each side. For rough (tabulated) models, whose noise makes shallow local minima where the data constrain one
    combination of the parameters only."""
    TRACES["valley"] += 1
    w, _ = weights(y, se, cfg)
    args = (r, y, w, mask, eta, d, cfg)
    costs = jax.vmap(lambda th: jnp.sum(residuals(th, args) ** 2))(thetas)
    best, _, _ = _chosen(thetas, results, stationary, costs)
    theta = jax.lax.stop_gradient(thetas[best])
    _, J = _covariance_jacobian(theta, args)
    JTJ = J.T @ J
    dn = jnp.sqrt(jnp.diag(JTJ))
    dn = jnp.where(dn > 0, dn, 1.0)
    # Major axis of the covariance = eigenvector of the smallest eigenvalue of the normalised J^T J.
    _, vecs = jnp.linalg.eigh(JTJ / jnp.outer(dn, dn))
    v = vecs[:, 0] / dn
    v = v / jnp.maximum(jnp.linalg.norm(v[:2]), 1e-300)
    v = jnp.where(jnp.all(jnp.isfinite(v)), v, jnp.zeros_like(v).at[0].set(1.0).at[1].set(-1.0) / jnp.sqrt(2.0))
    t = jnp.asarray(VALLEY_SCAN, theta.dtype)
    side = jnp.concatenate([t, -t])[:, None] * v[None, :] + theta[None, :]  # (2 S, p)
    if cfg.relative:
        # The scale profiled out at every scanned point (least squares): the axis's linear scale drifts far out.
        wy = jnp.where(mask, w * y, 0.0).reshape(-1)

        def scan_point(th):
            wm = residuals(th.at[2].set(0.0), args) + wy  # w * model at unit scale
            scale = jnp.sum(wm * wy) / jnp.sum(wm * wm)
            return jnp.sum((scale * wm - wy) ** 2), th.at[2].set(jnp.log(jnp.where(scale > 0, scale, 1.0)))

        cost, side = jax.vmap(scan_point)(side)
    else:
        cost = jax.vmap(lambda th: jnp.sum(residuals(th, args) ** 2))(side)
    cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf).reshape(2, -1)
    k = jnp.argmin(cost, axis=1)
    return side.reshape(2, t.shape[0], -1)[jnp.arange(2), k]


_UNFILLED = int(optx.RESULTS.nonlinear_max_steps_reached._value)  # a row not solved yet: never the chosen one


def with_valley(sol, mask, r, y, se, eta, d, cfg: Config):
    """``sol`` (the starts' solutions) extended by :data:`VALLEY_ROUNDS` rounds of two valley starts' solutions
    (:func:`valley_starts`, each round from the best solution so far).

    The rounds are one ``lax.fori_loop`` over rows preallocated for them (a row not yet solved reads as unconverged,
    so no round chooses it), not a Python loop: the fused fit's graph holds one valley scan and one solve instead of
    one per round (the model is evaluated inside each, and compilation time grows with the copies)."""
    S = jax.tree_util.tree_leaves(sol[0])[0].shape[0]
    extra = 2 * VALLEY_ROUNDS

    def grow(a, fill):
        return jnp.concatenate([a, jnp.full((extra,) + a.shape[1:], fill, a.dtype)])

    thetas, results, steps, stationary = sol
    rows = (grow(thetas, 0.0), grow(results._value, _UNFILLED), grow(steps, 0), grow(stationary, False))

    def one_round(i, rows):
        th, res, st, stat = rows
        v0 = valley_starts(th, results_from_code(res), st, stat, mask, r, y, se, eta,
                           d, cfg)
        new = solve_starts(v0, mask, r, y, se, eta, d, cfg)
        at = S + 2 * i
        return (jax.lax.dynamic_update_slice_in_dim(th, new[0], at, 0),
                jax.lax.dynamic_update_slice_in_dim(res, new[1]._value.astype(res.dtype), at, 0),
                jax.lax.dynamic_update_slice_in_dim(st, new[2].astype(st.dtype), at, 0),
                jax.lax.dynamic_update_slice_in_dim(stat, new[3], at, 0))

    th, res, st, stat = jax.lax.fori_loop(0, VALLEY_ROUNDS, one_round, rows)
    return th, results_from_code(res), st, stat


# --- 4. Choice among the starts, covariance, suspect checks --------------------------------------------------------
def finish(thetas, results, steps, stationary, mask, r, y, se, eta, d, cfg: Config):
    """The fit from the solutions of the starts (``thetas (S, p)``, ``results``, ``steps``, ``stationary (S,)``): a
    dict of estimates, standard errors, status and the suspect-fit checks.

    The chosen solution is the converged one of lowest cost (:func:`_chosen`).
    Suspect (``suspect`` > 0, a bit field):

    - 1, chi^2: standard errors were given for every fitted point and a chi^2 this large has a probability below
      ``CHI2_P`` (the residuals are larger than the noise: a wrong minimum or a wrong model);
    - 2, tie: another start converged to a different minimum (more than ``ALT_SEPARATION`` and 3 standard errors
      apart in ``log sigma_a`` or ``log sigma_s'``) whose cost is within ``ALT_DCHI2`` units of chi^2 of the chosen
      one, in the fit's own residual variance: the data do not pick one;
    - 4, structure: no standard errors were given, the residuals' lag-1 autocorrelation along ``r`` exceeds
      ``STRUCTURE_RHO`` and their rms exceeds ``STRUCTURE_RMS``: a smooth misfit (a wrong minimum, or a model that
      does not describe the data), not noise.
    """
    TRACES["finish"] += 1
    w, _ = weights(y, se, cfg)
    args = (r, y, w, mask, eta, d, cfg)
    res_all = jax.vmap(lambda th: residuals(th, args))(thetas)  # (S, K N): one model evaluation for all starts
    costs = jnp.sum(res_all**2, axis=1)
    best, key, ok = _chosen(thetas, results, stationary, costs)
    theta = thetas[best]
    sa, ss, scale, eta_hat = unpack(theta, eta, cfg)
    out = {"sigma_a": sa, "sigma_s_prime": ss, "scale": scale, "eta": eta_hat,
           "result": jax.tree_util.tree_map(lambda x: x[best], results),
           
           "iterations": jnp.sum(steps)}
    out.update(covariance(theta, args, cfg))
    # Suspect checks.
    p = cfg.n_params
    n = out["n_points"]
    dof = jnp.maximum(n - p, 1.0)
    all_se = jnp.all(jnp.where(mask, se > 0.0, True))
    # P(chi^2_dof >= observed) = Q(dof / 2, chi^2 / 2), the regularised upper incomplete gamma function.
    chi2_bad = all_se & (jax.scipy.special.gammaincc(0.5 * dof, 0.5 * out["reduced_chi2"] * dof) < CHI2_P)
    s2 = jnp.maximum(out["reduced_chi2"], jnp.finfo(theta.dtype).tiny)
    se_log = jnp.stack([out["sigma_a_stderr"] / sa, out["sigma_s_prime_stderr"] / ss])
    sep = jnp.abs(thetas[:, :2] - theta[None, :2])  # (S, 2)
    different = jnp.any((sep > ALT_SEPARATION) & (sep > 3.0 * se_log[None, :]), axis=1)
    tie = ok & different & ((costs - costs[best]) <= ALT_DCHI2 * s2)
    # Without standard errors there is no noise level to compare with; instead the residuals' lag-1 autocorrelation
    # along r: near 0 for noise (sd 1 / sqrt(n)), near 1 for the smooth misfit of a wrong minimum or a wrong model.
    # Only above a relative misfit of STRUCTURE_RMS (float64 rounding in noise-free fits is far below it).
    res = res_all[best].reshape(mask.shape)  # (K, N)
    lag = jnp.sum(jnp.where(mask[:, 1:] & mask[:, :-1], res[:, 1:] * res[:, :-1], 0.0))
    rho1 = lag / jnp.maximum(jnp.sum(res**2), jnp.finfo(theta.dtype).tiny)
    rms = jnp.sqrt(jnp.sum(res**2) / jnp.maximum(n, 1.0))
    structured = ~all_se & (rho1 > STRUCTURE_RHO) & (rms > STRUCTURE_RMS)
    out["suspect"] = (chi2_bad.astype(jnp.int32) + 2 * jnp.any(tie).astype(jnp.int32)
                      + 4 * structured.astype(jnp.int32))
    out["residual_autocorrelation"] = rho1
    # The best other start's solution and its cost relative to the chosen one (inf if it did not converge).
    other = jnp.where(jnp.arange(thetas.shape[0]) == best, jnp.inf, key)
    j = jnp.argmin(other)
    out["alt_sigma_a"], out["alt_sigma_s_prime"] = jnp.exp(thetas[j, 0]), jnp.exp(thetas[j, 1])
    out["alt_cost_ratio"] = jnp.where(ok[j], costs[j] / jnp.maximum(costs[best], jnp.finfo(theta.dtype).tiny),
                                      jnp.inf)
    return out


def covariance(theta, args, cfg: Config):
    """Standard errors from ``J^T J`` at the solution, scaled by the residual variance ``SSR / (n - p)`` (for rough
    models ``J`` is a secant over :data:`ROUGH_JACOBIAN_STEP`, see :func:`_covariance_jacobian`)."""
    th = jax.lax.stop_gradient(theta)
    res, J = _covariance_jacobian(th, args)  # J: (K N, p), in the log-parameters
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


def fit(r, y, se, eta, d, r_lo, r_hi, auto, cfg: Config):
    """The whole fit of one problem in one traced function (models without a per-solution static setting):
    starts, solves and :func:`finish`. Returns ``(out, theta0, mask, r_cut, flags)``."""
    TRACES["fit"] += 1
    theta0, mask, r_cut, flags = starts(r, y, se, eta, d, r_lo, r_hi, auto, cfg)
    sol = solve_starts(theta0, mask, r, y, se, eta, d, cfg)
    if resolve_model(cfg.model).rough:
        sol = with_valley(sol, mask, r, y, se, eta, d, cfg)
    return finish(*sol, mask, r, y, se, eta, d, cfg), theta0, mask, r_cut, flags


def solution_jacobian(theta, mask, r, y, se, eta, d, cfg: Config):
    """``d (sigma_a, sigma_s') / d y`` at a least-squares solution ``theta``, ``(2, K, N)``: what
    :func:`fitting.fit_jacobian_wrt_data` returns per problem. The implicit function theorem on the solution's
    stationarity, ``grad_theta S(theta, y) = 0`` with ``S = |r|^2 / 2`` (the weights ``1 / y`` move with the data):
    ``d theta / d y = -(d2S / d theta2)^-1 d2S / d theta dy``, with the full Hessian (Optimistix's implicit adjoint
    differentiates the same condition), then the chain rule through :func:`unpack`. No solve is traced: ``theta`` is
    the fit's own solution."""
    def grad_s(th, yy):
        w, _ = weights(yy, se, cfg)
        return jax.grad(lambda t: 0.5 * jnp.sum(residuals(t, (r, yy, w, mask, eta, d, cfg)) ** 2))(th)

    hessian = jax.jacfwd(grad_s, 0)(theta, y)  # (p, p)
    mixed = jax.jacfwd(grad_s, 1)(theta, y)  # (p, K, N)
    p = theta.shape[0]
    dtheta = -jnp.linalg.solve(hessian, mixed.reshape(p, -1)).reshape(mixed.shape)
    dphys = jax.jacfwd(lambda t: jnp.stack(unpack(t, eta, cfg)[:2]))(theta)  # (2, p)
    return jnp.tensordot(dphys, dtheta, axes=1)


__all__ = ["Config", "LMState", "TRACES", "data_guess", "finish", "fit", "lm_block", "lm_init", "lm_solve",
           "predict", "solution_jacobian", "solve_starts", "starts", "valley_starts", "with_valley"]
