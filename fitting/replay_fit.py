"""Transport-accurate fits of slabs and layered stacks with replay (perturbation) Monte Carlo and a trust region.

:func:`fit_replay` recovers chosen layers' ``sigma_a`` and ``sigma_s'`` (default: the deepest layer, the others fixed)
from radial profiles R(r) and/or T(r) and/or the totals (R, T), for a stack of known geometry, ``g`` and ``n``. The
forward model is :func:`jaxsss.mc.replay.replay`: one Monte Carlo run without absorption at reference scattering
coefficients, reweighted in JAX for any coefficients, so the least-squares solver (Optimistix Levenberg-Marquardt)
gets exact derivatives of a fixed random sample.

Trust region. A reweighted sample is only good near its reference: the effective sample size falls as the scattering
coefficients move away, first in the far bins, whose photons scattered most (:mod:`jaxsss.mc.replay`). The trust
statistic is the smaller of the global ``ess_fraction`` and the :data:`BIN_QUANTILE` quantile (10%) over the fitted
bins of the per-bin one (the median let the far bins of a half-space degrade unseen; measured). Each
*round* records a sample at the current reference and solves the least-squares problem on it. If the solution's
statistic is below ``ess_threshold``, the step is cut back along the line from the reference to the solution
(bisection, in log-parameters) to the farthest point where it is ``>= ess_threshold``, which becomes the next
reference; otherwise the solution itself does. The fit ends when a round's solution keeps the statistic ``>=
ess_final`` *and* moved by at most ``max_move`` standard errors from the round's reference: the answer then comes from
a sample recorded at it. At most ``max_simulations`` rounds (status ``"max_simulations"`` if the trust region was still
moving).

Regression dilution, and its correction. The sample's Jacobian is a Monte Carlo estimate too, and its noise adds to
``J^T W J`` on average, so a least-squares step on one sample is shorter than the true Gauss-Newton step: measured on
the MCML 2 mm slab at 5e4-1e5 photons, a round covered only 30-60% of the remaining way, and a fit that stopped when
the step became small ended 2-5% short of the answer (many standard errors). Each round's step is therefore corrected
with the noise part of the normal matrix, estimated from the per-photon derivatives of the weights
(:func:`_normal_matrices`): ``step = (J^T W J - noise)^-1 (J^T W J) step_LM``. The fixed point of the rounds (a
sample recorded at the answer, whose solution does not move) is unaffected by the dilution; the correction only makes
the rounds reach it (3-5 simulations from a start 20-30% off). The far bins' effective sample also matters: where it
is small the weights are heavy-tailed and a finite sample underestimates their mean (the replayed far profile of the
two-layer file from a reference 20% off read 2% of the truth), hence the bin quantile in the trust statistic.

Weights. Each residual is divided by ``sqrt(sigma_data^2 + sigma_model^2)``: the data's standard errors (given, or
Poisson-like from the data's photon count, :func:`poisson_stderr`) and the replayed sample's own standard error at
the round's reference (held fixed within the round, so the objective stays smooth). Standard errors of the estimates
come from the inverse of the corrected normal matrix of the last round (``(J^T W J)^-1`` if the correction is not
positive definite), scaled by ``max(1, reduced chi^2)``, mapped from the log-parameters.

Data conventions are MCML's (see :mod:`jaxsss.mc.replay`): per incident photon, R without the specular reflection,
T with the unscattered beam (``unscattered=False`` when the data's T excludes it).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import jaxsss  # noqa: F401  (float64)
from jaxsss.mc import Layer, Stack
from fitting.mco import poisson_stderr
from jaxsss.mc.replay import SIDE_R, SIDE_T, photon_weights, record, replay

__all__ = ["ReplayData", "ReplayFit", "fit_replay", "fit_slab_totals", "poisson_stderr"]

ESS_THRESHOLD = 0.5
"""Default: a solution whose trust statistic (module docstring) is below this is cut back to it."""
ESS_FINAL = 0.9
"""Default: a round whose solution keeps the trust statistic ``>= ESS_FINAL`` on its own sample (and moved at most
``MAX_MOVE`` standard errors) ends the fit."""
MAX_MOVE = 2.0
"""Default: the last round's solution moved by at most this many of its standard errors (each parameter, log scale)
from the round's reference. Two, not one: successive samples are independent, so solutions at the answer still jump
by about ``sqrt(2)`` model standard errors."""
CAP_OPTICAL = 12.0
"""Default path cap of half-space recordings in absorption lengths of the initial guess (``exp(-12) = 6e-6``)."""
MAX_NOISE_SHARE = 0.8
"""The dilution correction removes at most this share of ``J^T W J`` in any direction (noise-dominated samples, e.g.
the far bins of a non-absorbing half-space recording, get a partial correction)."""
BIN_QUANTILE = 0.1
"""The trust statistic uses this quantile of the fitted bins' ESS fractions (so 90% of the bins are at least as good)."""
MIN_COUNT = 10.0
"""Profile bins whose expected photon count ``value * area * photons`` in the data is below this are left out (the
Poisson-like error is not Gaussian there)."""


class ReplayData(NamedTuple):
    """What :func:`fit_replay` fits (any non-empty subset; per incident photon, mm, 1/mm^2).

    ``r_edges`` ``(M + 1,)`` with ``R_r``/``T_r`` ``(M,)`` per mm^2 of each annulus; ``R``, ``T`` totals. Each has a
    standard error (same shape) or ``None``: then ``photons`` (the data's photon count) gives Poisson-like errors.
    ``unscattered``: whether the data's T (and T(r)) includes the unscattered beam. ``mask``: ``(M,)`` bool bins to
    use (default: bins with at least :data:`MIN_COUNT` expected photons, excluding the last bin, which MCML uses to
    collect everything beyond the grid).
    """

    r_edges: np.ndarray | None = None
    R_r: np.ndarray | None = None
    T_r: np.ndarray | None = None
    R: float | None = None
    T: float | None = None
    R_r_stderr: np.ndarray | None = None
    T_r_stderr: np.ndarray | None = None
    R_stderr: float | None = None
    T_stderr: float | None = None
    photons: int | None = None
    unscattered: bool = True
    mask: np.ndarray | None = None


class ReplayFit(NamedTuple):
    """Result of :func:`fit_replay` (1/mm; values in the order of ``free_layers``).

    ``status``: ``"converged"``, or why not (the solver's message, ``"max_simulations"`` when the trust region was
    still moving). ``iterations``: solver steps over all rounds; ``simulations``, ``photons_simulated``: reference runs
    and their photons; ``ess_fraction``: at the solution, on the last sample; ``cap_bound``: upper bound on the
    ``R + T`` that the path cap lost at the solution (:mod:`jaxsss.mc.replay`); ``reduced_chi2``, ``n_points``;
    ``history``: per round ``(reference, solution, trust statistic at the solution, move in standard errors, gain of
    the dilution correction; 1 when not applied)``, parameters in logs; ``seconds``: wall
    time (recording compile included).
    """

    sigma_a: np.ndarray
    sigma_s_prime: np.ndarray
    sigma_a_stderr: np.ndarray
    sigma_s_prime_stderr: np.ndarray
    status: str
    iterations: int
    simulations: int
    photons_simulated: int
    ess_fraction: float
    cap_bound: float
    reduced_chi2: float
    n_points: int
    free_layers: tuple
    history: list
    seconds: float

    @property
    def converged(self) -> bool:
        return self.status == "converged"


def _block(value, stderr, photons, area, name):
    v = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if not np.all(np.isfinite(v)):
        raise ValueError(f"fit_replay(data.{name}) has non-finite values")
    if stderr is None:
        if photons is None:
            raise ValueError(f"fit_replay(data.{name}_stderr=None, data.photons=None): give the standard errors or "
                             "the data's photon count")
        se = poisson_stderr(v, photons, area)
    else:
        se = np.atleast_1d(np.asarray(stderr, dtype=np.float64))
        if se.shape != v.shape or np.any(~(se > 0)):
            raise ValueError(f"fit_replay(data.{name}_stderr) must be > 0 with the shape of data.{name} {v.shape}")
    return v, se


def _check_data(data: ReplayData):
    """The fitted blocks ``[(name, values, stderr, index)]`` and the radial edges."""
    if not isinstance(data, ReplayData):
        raise ValueError(f"fit_replay(data={type(data).__name__}) must be a ReplayData")
    blocks, edges = [], None
    if data.R_r is not None or data.T_r is not None:
        if data.r_edges is None:
            raise ValueError("fit_replay(data.r_edges=None): profiles need their radial bin edges")
        edges = np.asarray(data.r_edges, dtype=np.float64)
        area = np.pi * np.diff(edges**2)
        for name in ("R_r", "T_r"):
            if getattr(data, name) is None:
                continue
            if np.shape(getattr(data, name)) != area.shape:
                raise ValueError(f"fit_replay(data.{name}=array of shape {np.shape(getattr(data, name))}) must have "
                                 f"one value per bin of r_edges ({area.size})")
            v, se = _block(getattr(data, name), getattr(data, name + "_stderr"), data.photons, area, name)
            if data.mask is not None:
                keep = np.asarray(data.mask, bool)
            else:
                # Expected photons per bin: N p from the photon count, else (v / se)^2 (a Poisson count's
                # relative error is 1 / sqrt(count)).
                count = v * area * data.photons if data.photons is not None else (v / se) ** 2
                keep = (count >= MIN_COUNT) & (np.arange(v.size) < v.size - 1)
            idx = np.flatnonzero(keep)
            blocks.append((name, v[idx], se[idx], idx))
    for name in ("R", "T"):
        if getattr(data, name) is not None:
            v, se = _block(getattr(data, name), getattr(data, name + "_stderr"), data.photons, 1.0, name)
            blocks.append((name, v, se, None))
    if not blocks:
        raise ValueError("fit_replay(data=ReplayData()) has nothing to fit: give R_r, T_r, R or T")
    return blocks, edges


def _predict(est, name, unscattered):
    """The model's values and standard errors for one data block."""
    if name == "R":
        return jnp.atleast_1d(est.R), jnp.atleast_1d(est.R_stderr)
    if name == "T":
        T = est.T if unscattered else est.T - est.T_unscattered
        return jnp.atleast_1d(T), jnp.atleast_1d(est.T_stderr)
    if name == "T_r" and not unscattered:
        raise ValueError("fit_replay(data.unscattered=False) is supported for the total T only")
    return getattr(est, name), getattr(est, name + "_stderr")


class _Problem(eqx.Module):
    """The fixed parts of a fit, as a pytree (so the compiled model and solver are reused across fits)."""

    sa0: jax.Array  # (L,) sigma_a of every layer (the free ones are overwritten)
    ssp0: jax.Array  # (L,) sigma_s'
    free: jax.Array  # (k,) free layer indices
    idx: tuple  # per data block: bin indices of a profile, or None for a total
    y: jax.Array  # (P,) data
    sigma: jax.Array  # (P,) residual scale
    names: tuple = eqx.field(static=True)
    unscattered: bool = eqx.field(static=True)


def _make_problem(sa0, ssp0, free, blocks, unscattered) -> _Problem:
    """The :class:`_Problem` of per-layer start values, free layer indices and checked data blocks (the residual scale
    is the data's standard error until a sample's is added)."""
    return _Problem(sa0=jnp.asarray(sa0), ssp0=jnp.asarray(ssp0), free=jnp.asarray(free, jnp.int32),
                    idx=tuple(None if b[3] is None else jnp.asarray(b[3], jnp.int32) for b in blocks),
                    y=jnp.asarray(np.concatenate([b[1] for b in blocks])),
                    sigma=jnp.asarray(np.concatenate([b[2] for b in blocks])),
                    names=tuple(b[0] for b in blocks), unscattered=bool(unscattered))


def _coefficients(theta, problem: _Problem):
    """Per-layer ``(sigma_a, sigma_s')`` with the free layers' values ``exp(theta)`` (``theta``: ``(2k,)`` log)."""
    k = problem.free.shape[0]
    sa = problem.sa0.at[problem.free].set(jnp.exp(theta[:k]))
    ssp = problem.ssp0.at[problem.free].set(jnp.exp(theta[k:]))
    return sa, ssp


@jax.jit
def _model(theta, sample, problem: _Problem):
    """The model's values and standard errors at the data points, the trust statistic and the cap bound."""
    est = replay(sample, *_coefficients(theta, problem))
    vals, errs, bins_ess = [], [], []
    for name, idx in zip(problem.names, problem.idx):
        v, e = _predict(est, name, problem.unscattered)
        vals.append(v if idx is None else v[idx])
        errs.append(e if idx is None else e[idx])
        if idx is not None:
            bins_ess.append(getattr(est, name + "_ess_fraction")[idx])
    # Trust-region statistic: the global ESS fraction, or the BIN_QUANTILE quantile over the fitted bins if lower.
    ess = est.ess_fraction
    if bins_ess:
        ess = jnp.minimum(ess, jnp.quantile(jnp.concatenate(bins_ess), BIN_QUANTILE))
    return jnp.concatenate(vals), jnp.concatenate(errs), ess, est.cap_bound


def _residuals(theta, args):
    sample, problem = args
    return (_model(theta, sample, problem)[0] - problem.y) / problem.sigma


@jax.jit
def _normal_matrices(theta, sample, problem: _Problem):
    """``J^T W J`` of the weighted residuals and its noise part ``sum_i Cov(J_i) / sigma_i^2`` at ``theta``.

    The sample's Jacobian ``J`` is itself a Monte Carlo estimate; its per-bin noise adds ``sum_i Cov(J_i) /
    sigma_i^2`` to ``J^T W J`` on average, which shrinks every Gauss-Newton step (regression dilution: measured, a
    round then covers only 30-60% of the way to the answer at 5e4-1e5 photons). ``Cov(J_i)`` comes from the
    per-photon derivatives of the weights: for bin ``i``, ``sum_p (dw_p/dtheta)(dw_p/dtheta)^T / (N area_i)^2``.
    """
    N = sample.photons

    def weights(th):
        return photon_weights(sample, *_coefficients(th, problem))[0]

    d = jax.jacfwd(weights)(theta)  # (N, P) per-photon derivatives
    outer = d[:, :, None] * d[:, None, :]
    M = sample.r_edges.shape[0] - 1
    area = jnp.pi * jnp.diff(sample.r_edges**2)
    unscattered = jnp.sum(sample.scatterings, axis=1) == 0.0
    covs = []
    for name, idx in zip(problem.names, problem.idx):
        mask = sample.side == (SIDE_R if name.startswith("R") else SIDE_T)
        if name == "T" and not problem.unscattered:
            mask = mask & ~unscattered
        o = jnp.where(mask[:, None, None], outer, 0.0)
        if idx is None:
            covs.append(jnp.sum(o, axis=0)[None] / N**2)
        else:
            per_bin = jax.ops.segment_sum(o, sample.bin, num_segments=M + 1)[:M] / (N**2 * area[:, None, None] ** 2)
            covs.append(per_bin[idx])
    cov = jnp.concatenate(covs)  # (points, P, P)
    J = jax.jacfwd(_residuals)(theta, (sample, problem))
    noise = jnp.sum(cov / (problem.sigma**2)[:, None, None], axis=0)
    return J.T @ J, noise


def _corrected_step(theta_ref, theta, sample, problem, max_gain: float = 5.0):
    """The round's step ``theta - theta_ref`` corrected for the dilution by the Jacobian's noise (see
    :func:`_normal_matrices`): ``(J^T W J - lam noise)^-1 (J^T W J) step`` with ``lam = 1``, or less where the noise
    would leave the matrix not positive definite (:data:`MAX_NOISE_SHARE`), if the gain stays below ``max_gain``;
    else the step itself. Returns the step, the corrected matrix (or
    ``J^T W J``) and the gain ``|corrected| / |step|`` (1 when not applied)."""
    A, noise = (np.asarray(a) for a in _normal_matrices(theta_ref, sample, problem))
    step = np.asarray(theta - theta_ref)
    try:
        # A - lam noise stays positive definite for lam < 1 / mu_max, mu_max the largest eigenvalue of A^-1 noise;
        # where the noise dominates (mu_max > 1) only part of it is removed (lam = MAX_NOISE_SHARE / mu_max).
        mu_max = float(np.max(np.real(np.linalg.eigvals(np.linalg.solve(A, noise)))))
        lam = 1.0 if mu_max < MAX_NOISE_SHARE else MAX_NOISE_SHARE / mu_max
        C = A - lam * noise
        corrected = np.linalg.solve(C, A @ step)
        gain = float(np.linalg.norm(corrected) / max(np.linalg.norm(step), 1e-300))
        if np.all(np.isfinite(corrected)) and gain <= max_gain:
            return corrected, C, gain
    except np.linalg.LinAlgError:
        pass
    return step, A, 1.0


def layer_indices(free_layers: Sequence[int], num_layers: int, owner: str) -> list[int]:
    """``free_layers`` (indices, negative from the bottom) as distinct indices in ``[0, num_layers)``, in the given
    order; a ``ValueError`` naming ``owner`` for an index out of range, a repeat or an empty list."""
    L, free = num_layers, []
    for i in free_layers:
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -L <= i < L:
            raise ValueError(f"{owner}(free_layers={tuple(free_layers)!r}): layer index {i!r} is outside the allowed "
                             f"range [{-L}, {L - 1}]")
        free.append(int(i) % L)
    if not free or len(set(free)) != len(free):
        raise ValueError(f"{owner}(free_layers={tuple(free_layers)!r}) must name distinct layers, at least one")
    return free


def fit_replay(stack: Stack, data: ReplayData, *, free_layers: Sequence[int] = (-1,), photons: int = 200_000,
               ess_threshold: float = ESS_THRESHOLD, ess_final: float = ESS_FINAL, max_move: float = MAX_MOVE,
               max_simulations: int = 12, max_steps: int = 100,
               rtol: float = 1e-6, atol: float = 1e-8, seed: int = 0, max_path: float | None = None,
               record_kwargs: dict | None = None) -> ReplayFit:
    """Fit the free layers' ``sigma_a`` and ``sigma_s'`` of ``stack`` to ``data`` with replay Monte Carlo.

    Args:
        stack: the geometry (``g``, ``n``, thicknesses, ambient indices) and the coefficients: fixed layers keep
            theirs; the free layers' ``sigma_a`` (``> 0``) and ``sigma_s (1 - g)`` are the initial guess.
        data: :class:`ReplayData`.
        free_layers: indices of the layers to fit (negative from the bottom; default the deepest).
        photons: photons per reference simulation.
        ess_threshold: in ``(0, 1)``: a solution below it is cut back to it (module docstring).
        ess_final: in ``[ess_threshold, 1)``: a solution at or above it on its own sample, ...
        max_move: ... that moved by at most this many standard errors from the sample's reference, ends the fit.
        max_simulations: reference runs at most (``>= 2``: at least one move and the final run).
        max_steps, rtol, atol: Levenberg-Marquardt settings per round (Optimistix's Cauchy termination).
        seed: round ``j`` records with seed ``seed + j``.
        max_path: the recording's path cap (mm; :func:`jaxsss.mc.replay.record`). ``None``: none for a finite stack;
            for a half-space :data:`CAP_OPTICAL` / (smallest ``sigma_a`` of the initial guess), so that a capped walk
            would have kept at most ``exp(-CAP_OPTICAL)`` of its weight there; the result's ``cap_bound`` reports the
            bound at the solution.
        record_kwargs: further arguments of :func:`jaxsss.mc.replay.record` (``max_steps``, ``batch_size``, ``lanes``).

    Returns:
        :class:`ReplayFit`.
    """
    t_start = time.perf_counter()
    if not isinstance(stack, Stack):
        raise ValueError(f"fit_replay(stack={stack!r}) must be a jaxsss.mc.Stack")
    L = stack.num_layers
    free = layer_indices(free_layers, L, "fit_replay")
    if not 0.0 < ess_threshold < 1.0:
        raise ValueError(f"fit_replay(ess_threshold={ess_threshold!r}) is outside the allowed range (0, 1)")
    if not ess_threshold <= ess_final < 1.0:
        raise ValueError(f"fit_replay(ess_final={ess_final!r}) is outside the allowed range [ess_threshold, 1)")
    if isinstance(max_simulations, bool) or not isinstance(max_simulations, int) or max_simulations < 2:
        raise ValueError(f"fit_replay(max_simulations={max_simulations!r}) must be an integer in [2, inf)")
    blocks, edges = _check_data(data)
    if edges is None:
        edges = np.array([0.0, 1.0])  # totals only: one dummy bin
    g = np.asarray(stack.g)
    sa0 = np.asarray(stack.sigma_a, dtype=np.float64).copy()
    ssp0 = np.asarray(stack.sigma_s, dtype=np.float64) * (1.0 - g)
    for i in free:
        if not (sa0[i] > 0 and ssp0[i] > 0):
            raise ValueError(f"fit_replay(stack layer {i}: sigma_a={sa0[i]:g}, sigma_s={float(stack.sigma_s[i]):g}) "
                             "is the initial guess and must be > 0 for free layers")
    if max_path is None:
        max_path = CAP_OPTICAL / float(np.min(sa0[sa0 > 0], initial=np.inf)) if stack.is_half_space else math.inf
    problem = _make_problem(sa0, ssp0, free, blocks, data.unscattered)
    sigma_data = problem.sigma
    n_points, k = int(problem.y.size), len(free)

    def stack_at(theta):
        sa, ssp = (np.asarray(a) for a in _coefficients(theta, problem))
        layers = [Layer(sa[i], ssp[i] / (1.0 - g[i]), g[i], float(stack.n[i]), float(stack.thickness[i]))
                  for i in range(L)]
        return Stack(layers, n_above=stack.n_above, n_below=stack.n_below)

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    theta_ref = jnp.log(jnp.concatenate([problem.sa0[problem.free], problem.ssp0[problem.free]]))
    history, iterations, simulations, status = [], 0, 0, "max_simulations"
    while simulations < max_simulations:
        sample = record(stack_at(theta_ref), photons, r_edges=edges, seed=seed + simulations, max_path=max_path,
                        **(record_kwargs or {}))
        simulations += 1
        # Weights: the data's and the sample's own standard errors (at the reference), in quadrature.
        model_se = _model(theta_ref, sample, problem)[1]
        problem = eqx.tree_at(lambda p: p.sigma, problem, jnp.sqrt(sigma_data**2 + model_se**2))
        sol = optx.least_squares(_residuals, solver, theta_ref, args=(sample, problem), max_steps=max_steps,
                                 throw=False)
        iterations += int(sol.stats["num_steps"])
        theta = sol.value
        # Undo the regression dilution of the step (the sample's noisy Jacobian), then check the trust region.
        step, normal, gain = _corrected_step(theta_ref, theta, sample, problem)
        theta = theta_ref + jnp.asarray(step)
        _, _, ess, cap_bound = (float(v) if np.ndim(v) == 0 else v for v in _model(theta, sample, problem))
        try:
            se_log = np.sqrt(np.maximum(np.diag(np.linalg.inv(normal)), 0.0))
        except np.linalg.LinAlgError:
            se_log = np.full(step.size, np.inf)
        moved = float(np.max(np.abs(step) / se_log))
        history.append((np.asarray(theta_ref), np.asarray(theta), ess, moved, gain))
        if ess >= ess_final and moved <= max_move:
            # The solution lies next to the sample's reference: this round's answer is final.
            ok = bool(sol.result == optx.RESULTS.successful)
            status = "converged" if ok else (" ".join(optx.RESULTS[sol.result].split()) or "failed")
            break
        if ess >= ess_threshold:
            theta_ref = theta  # inside the trust region: re-simulate at the solution
            continue
        # Cut the step back to the farthest point on the segment with the statistic >= threshold (bisection).
        lo, hi = 0.0, 1.0
        for _ in range(12):
            mid = 0.5 * (lo + hi)
            if float(_model(theta_ref + mid * (theta - theta_ref), sample, problem)[2]) >= ess_threshold:
                lo = mid
            else:
                hi = mid
        theta_ref = theta_ref + max(lo, 1e-3) * (theta - theta_ref)

    r = np.asarray(_residuals(theta, (sample, problem)))
    chi2 = float(r @ r) / max(n_points - 2 * k, 1)
    se_log = se_log * math.sqrt(max(1.0, chi2))
    est = np.exp(np.asarray(theta))
    return ReplayFit(
        sigma_a=est[:k], sigma_s_prime=est[k:], sigma_a_stderr=est[:k] * se_log[:k],
        sigma_s_prime_stderr=est[k:] * se_log[k:], status=status, iterations=iterations, simulations=simulations,
        photons_simulated=simulations * photons, ess_fraction=ess, cap_bound=cap_bound, reduced_chi2=chi2, n_points=n_points,
        free_layers=tuple(free), history=history, seconds=time.perf_counter() - t_start)


def fit_slab_totals(R: float, T: float, *, g: float, n: float, thickness: float, guess=(0.1, 1.0),
                    n_above: float = 1.0, n_below: float | None = None, R_stderr: float | None = None,
                    T_stderr: float | None = None, photons_data: int | None = None, unscattered: bool = True,
                    **kwargs) -> ReplayFit:
    """``sigma_a`` and ``sigma_s'`` (1/mm) of a slab from its total reflectance and transmittance (inverse
    adding-doubling's problem, solved with replay Monte Carlo).

    Args:
        R: diffuse reflectance per incident photon, specular reflection excluded, in ``(0, 1)``.
        T: total transmittance per incident photon, in ``(0, 1)``; with the unscattered beam unless
            ``unscattered=False``.
        g, n, thickness: the slab's anisotropy, refractive index and thickness (mm); ambient ``n_above``, ``n_below``
            (default ``n_above``).
        guess: initial ``(sigma_a, sigma_s')``, 1/mm, both ``> 0``.
        R_stderr, T_stderr: the data's standard errors, or ``photons_data`` for Poisson-like ones; if neither is
            given, ``1e-4`` (measurements of totals are rarely better).
        **kwargs: passed to :func:`fit_replay`.
    """
    for name, v in (("R", R), ("T", T)):
        if not 0.0 < float(v) < 1.0:
            raise ValueError(f"fit_slab_totals({name}={v!r}) is outside the allowed range (0, 1)")
    if float(R) + float(T) >= 1.0:
        raise ValueError(f"fit_slab_totals(R={R!r}, T={T!r}): R + T must be < 1 (the slab absorbs)")
    if photons_data is None:
        R_stderr = 1e-4 if R_stderr is None else R_stderr
        T_stderr = 1e-4 if T_stderr is None else T_stderr
    stack = Stack.slab(guess[0], guess[1] / (1.0 - g), g, n, thickness, n_above=n_above, n_below=n_below)
    data = ReplayData(R=R, T=T, R_stderr=R_stderr, T_stderr=T_stderr, photons=photons_data, unscattered=unscattered)
    return fit_replay(stack, data, **kwargs)
