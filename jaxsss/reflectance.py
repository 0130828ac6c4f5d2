"""Total diffuse reflectance of a semi-infinite medium, and its inversion Rd -> alpha' (hierarchical paper Eq. 15).

``Rd(alpha', A) = alpha'/2 (1 + exp(-4/3 A sqrt(3(1-alpha')))) exp(-sqrt(3(1-alpha')))`` is the plane integral of
the dipole profile (per unit flux entering the medium). It rises monotonically from 0 at ``alpha' = 0`` to 1 at
``alpha' = 1``.

Inversion. The paper uses "a few iterations of a simple secant root finder". We solve with Newton's method (a plain
loop, elementwise) in the unconstrained variable ``s``, where ``u = sqrt(3 (1 - alpha')) = sqrt(3) sigmoid(s)``:

- both stiff ends stay well conditioned: ``1 - alpha' = sigmoid(s)^2`` is exact as ``Rd -> 1`` (where ``alpha' -> 1``
  and, at fixed ``l_d``, ``sigma_t' -> infinity``) and ``alpha' = sigmoid(-s) (1 + sigmoid(s))`` as ``Rd -> 0``;
- the residual is ``log(-log Rd(s)) - log(-log Rd_target)``: linear in ``s`` as ``Rd -> 1`` and logarithmic as
  ``Rd -> 0``, and evaluated without cancellation, so ``u`` (and hence ``sigma_a = sigma_tr u / 3``) is accurate to
  about 1e-15 relative at ``Rd = 1 - 1e-12`` and ``alpha'`` to about 1e-14 at ``Rd = 1e-12``;
- gradients flow through the implicit function theorem (a ``jax.custom_jvp`` on the solve), so ``d alpha'/d Rd``
  equals ``1 / (dRd/d alpha')`` without differentiating the iterations.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range
from jaxsss.medium import Medium

__all__ = [
    "RdInversion",
    "alpha_prime_from_rd",
    "invert_rd",
    "medium_total_diffuse_reflectance",
    "total_diffuse_reflectance",
    "total_diffuse_reflectance_u",
]

_SQRT3 = 3.0**0.5


def _eq15(alpha_prime, u, A):
    """Hierarchical paper Eq. 15 with ``u = sqrt(3 (1 - alpha'))`` supplied by the caller (so it can avoid cancellation)."""
    return 0.5 * alpha_prime * (1.0 + jnp.exp(-4.0 / 3.0 * A * u)) * jnp.exp(-u)


def total_diffuse_reflectance_u(u, A):
    """Eq. 15 in the variable ``u = sqrt(3 (1 - alpha'))`` in ``[0, sqrt(3)]``: ``(1 - u^2/3)/2 (1 + e^{-4Au/3}) e^{-u}``."""
    return _eq15(1.0 - u * u / 3.0, u, A)


def total_diffuse_reflectance(alpha_prime, A):
    """Total diffuse reflectance ``Rd`` of the dipole (hierarchical paper Eq. 15), per unit flux entering.

    Args:
        alpha_prime: reduced albedo in ``[0, 1]``.
        A: boundary coefficient ``(1 + F_dr)/(1 - F_dr)`` (``>= 1`` for ``eta >= 1``; ``> 0`` always).

    Returns:
        ``Rd`` in ``[0, 1]``, broadcast shape.
    """
    alpha_prime = check_range(alpha_prime, "alpha_prime", 0.0, 1.0, owner="total_diffuse_reflectance")
    A = check_range(A, "A", 0.0, None, lo_open=True, owner="total_diffuse_reflectance")
    return _eq15(alpha_prime, jnp.sqrt(3.0 * (1.0 - alpha_prime)), A)


@jax.custom_jvp
def _u_of_medium(sigma_a, sigma_s_prime):
    """``u = sqrt(3 sigma_a / sigma_t')`` with the derivative written out so that ``sigma_a = 0`` gives the true one
    (``+inf`` in ``sigma_a``, ``0`` in ``sigma_s'``) rather than ``inf * 0 = nan`` from the chain rule."""
    return jnp.sqrt(3.0 * sigma_a / (sigma_a + sigma_s_prime))


def _u_of_medium_jvp(primals, tangents):
    sa, ss = primals
    dsa, dss = tangents
    st = sa + ss
    u = jnp.sqrt(3.0 * sa / st)
    # du = 3 / (2 u st^2) (ss dsa - sa dss); the dss coefficient 3 sa / (2 u st^2) = u / (2 st) is finite at sa = 0,
    # the dsa coefficient 3 ss / (2 u st^2) is +inf there (the true derivative: u ~ sqrt(sigma_a)).
    k = 1.5 * ss / (u * st * st)
    m = u / (2.0 * st)
    zero = jax.custom_derivatives.SymbolicZero
    du = jnp.zeros_like(u)
    # A tangent that is symbolically zero (sigma_a held fixed) adds nothing: no inf * 0 at sigma_a = 0.
    if not isinstance(dsa, zero):
        du = du + k * dsa
    if not isinstance(dss, zero):
        du = du - m * dss
    return u, du


_u_of_medium.defjvp(_u_of_medium_jvp, symbolic_zeros=True)


def medium_total_diffuse_reflectance(medium: Medium):
    """``Rd`` of a :class:`Medium` (Eq. 15), using ``1 - alpha' = sigma_a / sigma_t'`` to avoid cancellation.

    At ``sigma_a = 0`` (``Rd = 1``) the derivative in ``sigma_a`` is truly infinite -- ``Rd ~ 1 - (1 + 2A/3)
    sqrt(3 sigma_a / sigma_s')`` -- and reverse-mode gradients say so (``-inf``), while those in ``sigma_s'`` and
    ``eta`` are finite (zero: a non-absorbing half-space reflects everything). Forward mode gives the same, provided
    the ``sigma_a`` tangent is a symbolic zero when ``sigma_a`` is held fixed (an explicit zero tangent meets the
    infinite coefficient: ``0 * inf = nan``). :func:`total_diffuse_reflectance_u` is the parametrisation with a
    finite derivative there (``dRd/du = -(1 + 2A/3)`` at ``u = 0``)."""
    return _eq15(medium.alpha_prime, _u_of_medium(medium.sigma_a, medium.sigma_s_prime), medium.A)


class RdInversion(eqx.Module):
    """Result of :func:`invert_rd`: the reduced albedo and the solver's report.

    Attributes:
        alpha_prime: reduced albedo, shape of the broadcast inputs.
        u: ``sqrt(3 (1 - alpha'))``, equal to ``sigma_tr / sigma_t'`` -- the accurate variable near ``Rd -> 1``.
        one_minus_alpha_prime: ``1 - alpha' = u^2 / 3`` without cancellation.
        result: ``optimistix.RESULTS`` per element (``successful`` when converged).
        steps: Newton iterations taken per element.
    """

    alpha_prime: jax.Array
    u: jax.Array
    one_minus_alpha_prime: jax.Array
    result: optx.RESULTS
    steps: jax.Array

    @property
    def converged(self):
        """Boolean array: the root finder converged for each element."""
        return self.result == optx.RESULTS.successful


def _neg_log_rd_of_s(s, A):
    """``-log Rd`` (> 0) as a function of ``s`` with ``u = sqrt3 sigmoid(s)``, free of cancellation at both ends."""
    sig = jax.nn.sigmoid(s)
    u = _SQRT3 * sig
    # log alpha': alpha' = 1 - sig^2 (accurate for s < 0, Rd -> 1) = sigmoid(-s) (1 + sig) (accurate for s > 0).
    log_alpha = jnp.where(s < 0.0, jnp.log1p(-sig * sig), jax.nn.log_sigmoid(-s) + jnp.log1p(sig))
    # -log of Eq. 15, using log 2 - log(1 + e^{-x}) = -log1p(expm1(-x) / 2).
    return -log_alpha - jnp.log1p(0.5 * jnp.expm1(-4.0 / 3.0 * A * u)) + u


def _initial_s(log_L, A):
    """Closed-form starting point for Newton from the two asymptotes of Eq. 15 (``L = -log Rd``)."""
    L = jnp.exp(log_L)
    # Rd -> 1: -log Rd ~ u (1 + 2A/3).
    u_hi = jnp.clip(L / (1.0 + 2.0 * A / 3.0), 1e-300, 0.999 * _SQRT3)
    s_hi = jnp.log(u_hi) - jnp.log(_SQRT3 - u_hi)
    # Rd -> 0: Rd ~ k alpha' with k = (1 + e^{-4A/sqrt3}) e^{-sqrt3} / 2, and alpha' ~ 2 e^{-s} for large s.
    log_k = jnp.log(0.5 * (1.0 + jnp.exp(-4.0 * A / _SQRT3))) - _SQRT3
    s_lo = L + log_k + jnp.log(2.0)
    return jnp.where(s_hi > s_lo, s_hi, s_lo)


def _residual(s, log_L, A):
    """``log(-log Rd(s)) - log(-log Rd)``: linear in ``s`` as ``Rd -> 1``, logarithmic as ``Rd -> 0``."""
    return jnp.log(_neg_log_rd_of_s(s, A)) - log_L


def _newton(log_L, A, rtol, atol, max_steps):
    """Newton's method on :func:`_residual` from :func:`_initial_s`, elementwise: ``(s, converged, steps)``.

    A plain loop of a few array operations (Optimistix's Newton compiled in about 3 s, this in a small fraction of
    that; :func:`jaxsss.from_rd_ld` is on the path of every profile fit's start and of ``jaxsss reparam``). It stops
    when every element's step is below ``atol + rtol |s|``; elements already there are frozen."""

    def newton_step(s):
        val, der = jax.jvp(lambda x: _residual(x, log_L, A), (s,), (jnp.ones_like(s),))
        return val / der

    def step(state):
        s, it, done = state
        ds = newton_step(s)
        ok = jnp.abs(ds) <= atol + rtol * jnp.abs(s)
        s_new = jnp.where(done | ~jnp.isfinite(ds), s, s - ds)
        return s_new, it + jnp.where(done, 0, 1), done | ok | ~jnp.isfinite(ds)

    def going(state):
        _, it, done = state
        return jnp.any(~done) & (jnp.max(it) < max_steps)

    s0 = _initial_s(log_L, A)
    init = (s0, jnp.zeros(s0.shape, jnp.int32), jnp.zeros(s0.shape, bool))
    s, steps, _ = jax.lax.while_loop(going, step, init)
    # Converged: the Newton step at the final point is (still) within the tolerance.
    ds = newton_step(s)
    conv = jnp.isfinite(s) & jnp.isfinite(ds) & (jnp.abs(ds) <= atol + rtol * jnp.abs(s))
    return s, conv, steps


@partial(jax.custom_jvp, nondiff_argnums=(2, 3, 4))
def _solve_s(log_L, A, rtol, atol, max_steps):
    return _newton(log_L, A, rtol, atol, max_steps)


@_solve_s.defjvp
def _solve_s_jvp(rtol, atol, max_steps, primals, tangents):
    # Implicit function theorem on f(s; log_L, A) = 0: ds = -(f_logL dlog_L + f_A dA) / f_s, with f_logL = -1.
    log_L, A = primals
    dlog_L, dA = tangents
    s, conv, steps = _solve_s(log_L, A, rtol, atol, max_steps)
    _, f_s = jax.jvp(lambda x: _residual(x, log_L, A), (s,), (jnp.ones_like(s),))
    _, f_A_dA = jax.jvp(lambda a: _residual(s, log_L, a), (A,), (dA,))
    ds = (dlog_L - f_A_dA) / f_s
    zero = lambda x: np.zeros(x.shape, jax.dtypes.float0)  # noqa: E731
    return (s, conv, steps), (ds, zero(conv), zero(steps))


@partial(jax.jit, static_argnums=(2, 3, 4))
def _invert(Rd, A, rtol, atol, max_steps):
    log_L = jnp.log(-jnp.log(Rd))
    log_L, A = jnp.broadcast_arrays(log_L, A)
    shape = log_L.shape
    s, conv, steps = _solve_s(log_L, A, rtol, atol, max_steps)
    R = optx.RESULTS
    result = jax.vmap(lambda c: R.where(c, R.successful, R.nonlinear_max_steps_reached))(conv.reshape(-1))
    s = s.reshape(shape)
    sig = jax.nn.sigmoid(s)
    return RdInversion(
        # alpha' = sigmoid(-s) (1 + sigmoid(s)), in logs so that it does not underflow before Rd does.
        alpha_prime=jnp.exp(jax.nn.log_sigmoid(-s) + jnp.log1p(sig)),
        u=_SQRT3 * sig,
        one_minus_alpha_prime=sig * sig,
        result=jax.tree_util.tree_map(lambda x: x.reshape(shape), result),
        steps=steps.reshape(shape),
    )


def invert_rd(Rd, A, *, rtol: float | None = None, atol: float | None = None, max_steps: int = 64) -> RdInversion:
    """Solve Eq. 15 for the reduced albedo: ``Rd(alpha', A) = Rd``.

    Args:
        Rd: total diffuse reflectance in the open interval ``(0, 1)``, any shape.
        A: boundary coefficient (``> 0``), broadcasting with ``Rd``.
        rtol, atol: Newton tolerances on ``s`` (see module docstring). The defaults, 1e-13 in float64 and 1e-6 in
            float32 (chosen from the dtype of ``Rd``), give ``alpha'`` and ``1 - alpha'`` to about 1e-14 relative in
            float64.
        max_steps: iteration cap; elements that hit it report ``result != successful``.

    Returns:
        :class:`RdInversion`. Differentiable in ``Rd`` and ``A`` by the implicit function theorem.
    """
    Rd = check_range(Rd, "Rd", 0.0, 1.0, lo_open=True, hi_open=True, owner="invert_rd")
    A = check_range(A, "A", 0.0, None, lo_open=True, owner="invert_rd")
    default_tol = 1e-13 if jnp.result_type(Rd, A) == jnp.float64 else 1e-6
    rtol = default_tol if rtol is None else rtol
    atol = default_tol if atol is None else atol
    return _invert(Rd, A, rtol, atol, max_steps)


def alpha_prime_from_rd(Rd, A, **kwargs):
    """``alpha'(Rd, A)``: the reduced albedo alone (see :func:`invert_rd` for the status and options)."""
    return invert_rd(Rd, A, **kwargs).alpha_prime
