"""Profile fits: fits per second of :func:`fitting.fit_profiles` against ``scipy.optimize.least_squares``.

What is measured. Batches of ``B`` = 1, 100 and 10,000 absolute dipole profiles (one channel each) on one grid of
40 radii, ``geomspace(0.05, 20)`` mm, ``eta`` = 1.3, with ``sigma_a`` log-uniform in [0.001, 0.1] and ``sigma_s'`` in
[0.5, 5] per mm. The data are the model itself (noise-free), so the error is the recovery error
``max(|sigma_a / truth - 1|, |sigma_s' / truth - 1|)`` over the batch.

Methods:

- ``fitting.fit_profiles``: the public call, the whole pipeline (data-driven start, range ``r >= l_u``, Optimistix
  Levenberg-Marquardt in log-parameters with relative weights, ``J^T J`` standard errors), one vmapped compiled call
  per stage. Timed after compilation (the first call, with its compile time, is reported as ``compile_seconds``).
- ``scipy least_squares``: ``scipy.optimize.least_squares(method="lm")`` (MINPACK) on a NumPy version of the same
  model and residuals (same log-parameters, weights and fit range), one profile at a time, started from the JAX
  pipeline's own initial guess (the same start; the guess is not timed for scipy), tolerances
  ``xtol = ftol = gtol = 1e-10``, Jacobian by 2-point differences (MINPACK's default). It is timed on a subset of the
  batch (all of it for ``B <= 100``) and reported per profile. The NumPy model is checked against
  :func:`jaxsss.dipole_profile` to 1e-12 before timing.

The summary reports the ratio ``scipy seconds per profile / fitting seconds per profile`` per batch size (goal: >= 20
in batch).
"""

from __future__ import annotations

import sys

import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results

NAME = "fit_speed"
ETA = 1.3
R = np.geomspace(0.05, 20.0, 40)
ERROR_METRIC = "max rel err of sigma_a, sigma_s' vs truth (noise-free data)"


def workload(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    sa = np.exp(rng.uniform(np.log(1e-3), np.log(1e-1), n))
    ss = np.exp(rng.uniform(np.log(0.5), np.log(5.0), n))
    return sa, ss, np.stack([dipole_np(R, a, s, ETA) for a, s in zip(sa, ss)])


# --- NumPy model (the same physics as jaxsss.dipole_profile x the entry transmittance) ------------------------------
def dipole_np(r, sigma_a, sigma_s_prime, eta):
    """Dipole exitance per incident photon (1/mm^2): Jensen et al. 2001 with alpha'/(4 pi), "poly" F_dr (eta >= 1)."""
    sigma_t = sigma_a + sigma_s_prime
    alpha = sigma_s_prime / sigma_t
    sigma_tr = np.sqrt(3.0 * sigma_a * sigma_t)
    F_dr = -1.4399 / eta**2 + 0.7099 / eta + 0.6681 + 0.0636 * eta  # Groenhuis et al. 1983, eta >= 1
    A = (1.0 + F_dr) / (1.0 - F_dr)
    D = 1.0 / (3.0 * sigma_t)
    z_r = 1.0 / sigma_t
    z_v = z_r + 4.0 * A * D
    d_r = np.sqrt(r * r + z_r * z_r)
    d_v = np.sqrt(r * r + z_v * z_v)
    Rd = alpha / (4.0 * np.pi) * (z_r * (1.0 + sigma_tr * d_r) * np.exp(-sigma_tr * d_r) / d_r**3
                                  + z_v * (1.0 + sigma_tr * d_v) * np.exp(-sigma_tr * d_v) / d_v**3)
    t_entry = 1.0 - ((eta - 1.0) / (eta + 1.0)) ** 2
    return t_entry * Rd


def scipy_fit(y, theta0, r_min):
    from scipy.optimize import least_squares

    m = R >= r_min
    r, yy = R[m], y[m]

    def res(th):
        return (dipole_np(r, np.exp(th[0]), np.exp(th[1]), ETA) - yy) / yy

    sol = least_squares(res, theta0, method="lm", xtol=1e-10, ftol=1e-10, gtol=1e-10)
    return np.exp(sol.x)


def rel_error(sa_hat, ss_hat, sa, ss):
    return float(max(np.max(np.abs(np.asarray(sa_hat) / sa - 1)), np.max(np.abs(np.asarray(ss_hat) / ss - 1))))


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    import jax.numpy as jnp

    import fitting
    import jaxsss

    # The NumPy model is the library's model.
    sa_c, ss_c = np.array([0.001, 0.03, 0.1]), np.array([0.5, 2.0, 5.0])
    ref = np.asarray(fitting.entry_transmittance(ETA) * jaxsss.dipole_profile(R[:, None], jaxsss.Medium(sa_c, ss_c,
                                                                                                          ETA)))
    mine = np.stack([dipole_np(R, a, s, ETA) for a, s in zip(sa_c, ss_c)], axis=1)
    model_check = float(np.max(np.abs(mine / ref - 1)))
    assert model_check < 1e-12, model_check

    sizes = (1, 100) if args.quick else (1, 100, 10_000)
    scipy_subset = 20 if args.quick else 200
    repeats = 3 if args.quick else 5
    rows, ratios = [], {}
    for B in sizes:
        sa, ss, data = workload(B, seed=B)
        fit_fn = lambda d: fitting.fit_profiles(R, d, eta=ETA, warn=False)  # noqa: E731
        t = time_call(fit_fn, data, repeats=repeats if B < 10_000 else 2)
        fit = t.output
        err = rel_error(fit.sigma_a, fit.sigma_s_prime, sa, ss)
        per_jax = t.seconds / B
        rows.append(make_row(NAME, "fitting.fit_profiles", B, err, ERROR_METRIC, t.seconds, t.compile_seconds,
                             batch=B, seconds_per_profile=per_jax, fits_per_second=1.0 / per_jax,
                             converged=int(np.sum(fit.converged)), median_seconds=t.median_seconds))
        # scipy on (a subset of) the same batch from the same start and range.
        n = min(B, scipy_subset)
        theta0 = np.log(np.stack([np.asarray(fit.guess_sigma_a), np.asarray(fit.guess_sigma_s_prime)], -1))[:n]
        r_min = np.asarray(fit.r_min)[:n]
        scipy_all = lambda: np.stack([scipy_fit(data[i], theta0[i], r_min[i]) for i in range(n)])  # noqa: E731
        ts = time_call(scipy_all, repeats=repeats if n <= 100 else 2)
        est = ts.output
        err_s = rel_error(est[:, 0], est[:, 1], sa[:n], ss[:n])
        per_scipy = ts.seconds / n
        ratios[str(B)] = per_scipy / per_jax
        rows.append(make_row(NAME, "scipy least_squares (lm, NumPy model)", B, err_s, ERROR_METRIC, ts.seconds, None,
                             batch=B, profiles_timed=n, seconds_per_profile=per_scipy, fits_per_second=1.0 / per_scipy,
                             median_seconds=ts.median_seconds))
        print(f"B={B}: fitting {1 / per_jax:,.0f} fits/s (compile {t.compile_seconds:.1f} s, err {err:.1e}); scipy "
              f"{1 / per_scipy:,.0f} fits/s (err {err_s:.1e}); ratio {ratios[str(B)]:.1f}x", flush=True)
    summary = {"ratio_scipy_over_fitting_per_profile": ratios, "goal_ratio_in_batch": 20,
               "numpy_model_max_rel_diff_vs_jaxsss": model_check, "radii": len(R), "eta": ETA}
    notes = ["seconds: one call for the whole batch (fitting) or for the timed subset (scipy); compare "
             "seconds_per_profile", "same start (the fitting pipeline's initial guess) and fit range for scipy"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title=f"{NAME}: error vs seconds per batch call", connect=False)
    print(f"wrote {json_path} and {png_path}")
    del jnp
    return 0


if __name__ == "__main__":
    sys.exit(main())
