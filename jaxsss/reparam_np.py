"""(Rd, l_d) -> (sigma_a, sigma_s') in NumPy, for a process that converts a few values (``jaxsss reparam``).

The same mathematics as :func:`jaxsss.from_rd_ld` with ``fresnel="poly"`` (hierarchical paper Eq. 15 inverted by
Newton's method in ``s``, ``u = sqrt(3 (1 - alpha')) = sqrt(3) sigmoid(s)``, then Eq. 16; see
:mod:`jaxsss.reflectance`), without importing JAX: a one-value conversion then takes the time of Python and NumPy
(~0.2 s) instead of JAX's import and a compiled program (~1.5 s on this machine; issue 18). Not differentiable; the
library function is the one to use in code. ``tests/test_reparam_np.py`` checks that both agree to 1e-12.
"""

from __future__ import annotations

import numpy as np

_SQRT3 = np.sqrt(3.0)
MAX_STEPS = 64
TOL = 1e-13  # Newton tolerance on s (jaxsss.reflectance.invert_rd's float64 default)


def A_poly(eta):
    """Boundary coefficient ``A = (1 + F_dr) / (1 - F_dr)`` with the polynomial ``F_dr`` of :func:`jaxsss.F_dr_poly`
    (Groenhuis et al. 1983 for ``eta >= 1``, Egan and Hilgeman 1973 below); ``eta = n_inside / n_outside``."""
    eta = np.asarray(eta, dtype=np.float64)
    inv = 1.0 / eta
    # Groenhuis et al. 1983 (hierarchical paper Eq. 10) / Egan and Hilgeman 1973 (photon-diffusion Eq. 7).
    F = np.where(eta >= 1.0, -1.4399 * inv * inv + 0.7099 * inv + 0.6681 + 0.0636 * eta,
                 -0.4399 + 0.7099 * inv - 0.3319 * inv * inv + 0.0636 * inv**3)
    return (1.0 + F) / (1.0 - F)


def _log_sigmoid(x):
    return -np.logaddexp(0.0, -x)


def _neg_log_rd(s, A):
    """``-log Rd`` of Eq. 15 at ``u = sqrt(3) sigmoid(s)`` and its derivative in ``s`` (no cancellation at either
    end, as :func:`jaxsss.reflectance._neg_log_rd_of_s`)."""
    sig = np.exp(_log_sigmoid(s))
    u = _SQRT3 * sig
    dsig = sig * (1.0 - sig)
    # log alpha' = log(1 - sig^2) (s < 0) = log sigmoid(-s) + log1p(sig) (s >= 0); d/ds = -2 sig dsig / (1 - sig^2)
    log_alpha = np.where(s < 0.0, np.log1p(-sig * sig), _log_sigmoid(-s) + np.log1p(sig))
    one_minus = np.where(s < 0.0, 1.0 - sig * sig, np.exp(_log_sigmoid(-s)) * (1.0 + sig))
    dlog_alpha = -2.0 * sig * dsig / one_minus
    # Eq. 15: -log Rd = -log alpha' - log((1 + e^{-4Au/3}) / 2) + u
    e = np.expm1(-4.0 / 3.0 * A * u)
    val = -log_alpha - np.log1p(0.5 * e) + u
    de = -4.0 / 3.0 * A * _SQRT3 * dsig * (e + 1.0)
    der = -dlog_alpha - 0.5 * de / (1.0 + 0.5 * e) + _SQRT3 * dsig
    return val, der


def _initial_s(L, A):
    """Newton's start from the asymptotes of Eq. 15 (``L = -log Rd``), as :func:`jaxsss.reflectance._initial_s`."""
    u_hi = np.clip(L / (1.0 + 2.0 * A / 3.0), 1e-300, 0.999 * _SQRT3)  # Rd -> 1: -log Rd ~ u (1 + 2A/3)
    s_hi = np.log(u_hi) - np.log(_SQRT3 - u_hi)
    log_k = np.log(0.5 * (1.0 + np.exp(-4.0 * A / _SQRT3))) - _SQRT3  # Rd -> 0: Rd ~ k alpha', alpha' ~ 2 e^{-s}
    s_lo = L + log_k + np.log(2.0)
    return np.where(s_hi > s_lo, s_hi, s_lo)


def from_rd_ld(rd, ld, eta, g=None) -> dict:
    """``{"sigma_a", "sigma_s_prime", "alpha_prime", "rd", "ld", "eta", ["sigma_s", "sigma_t"], "converged"}`` as
    NumPy arrays (1/mm; broadcast over the inputs) from ``rd`` in ``(0, 1)``, ``ld > 0`` (mm), ``eta > 0``
    (``n_inside / n_outside``) and optionally ``g`` in ``(-1, 1)``; ``F_dr`` by the polynomial fits."""
    rd, ld, eta = (np.asarray(x, dtype=np.float64) for x in (rd, ld, eta))
    for name, x, ok, allowed in (("rd", rd, (rd > 0) & (rd < 1), "(0, 1)"), ("ld", ld, ld > 0, "(0, inf)"),
                                 ("eta", eta, eta > 0, "(0, inf)")):
        if not np.all(ok & np.isfinite(x)):
            bad = x[~(ok & np.isfinite(x))].flat[0]
            raise ValueError(f"from_rd_ld({name}={bad:g}) is outside the allowed range {allowed}")
    if g is not None and not -1.0 < float(g) < 1.0:
        raise ValueError(f"from_rd_ld(g={float(g):g}) is outside the allowed range (-1, 1)")
    rd, ld, eta = np.broadcast_arrays(rd, ld, eta)
    A = A_poly(eta)
    L = -np.log(rd)
    log_L = np.log(L)
    s = _initial_s(L, A)
    done = np.zeros(s.shape, bool)
    # Newton on log(-log Rd(s)) - log(-log Rd) (linear in s as Rd -> 1, logarithmic as Rd -> 0)
    for _ in range(MAX_STEPS):
        val, der = _neg_log_rd(s, A)
        ds = (np.log(val) - log_L) / (der / val)
        ok = np.isfinite(ds)
        s = np.where(done | ~ok, s, s - ds)
        done = done | ~ok | (np.abs(ds) <= TOL + TOL * np.abs(s))
        if done.all():
            break
    val, der = _neg_log_rd(s, A)
    ds = (np.log(val) - log_L) / (der / val)
    converged = np.isfinite(s) & np.isfinite(ds) & (np.abs(ds) <= TOL + TOL * np.abs(s))
    sig = np.exp(_log_sigmoid(s))
    alpha = np.exp(_log_sigmoid(-s) + np.log1p(sig))
    u = _SQRT3 * sig
    sigma_tr = 1.0 / ld
    # Eq. 16: sigma_t' = sigma_tr / u; sigma_a = sigma_tr u / 3; sigma_s' = alpha' sigma_t'.
    out = {"sigma_a": sigma_tr * u / 3.0, "sigma_s_prime": alpha * sigma_tr / u, "alpha_prime": alpha, "rd": rd,
           "ld": ld, "eta": eta}
    if g is not None:
        out["sigma_s"] = out["sigma_s_prime"] / (1.0 - float(g))
        out["sigma_t"] = out["sigma_s"] + out["sigma_a"]
    out["converged"] = converged
    return out


__all__ = ["A_poly", "from_rd_ld"]
