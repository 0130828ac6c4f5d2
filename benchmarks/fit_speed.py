"""Profile fits: start-up, one fit and batches of :func:`fitting.fit_profiles` against ``scipy.optimize.least_squares``.

What is measured (issue 18), all in one run:

1. **Processes.** ``jaxsss fit PROFILE.csv`` (a 40-radius dipole profile with 2% noise and standard errors, the CLI
   tests' format) and ``jaxsss reparam --rd 0.5 --ld 1 --eta 1.3``, each as a fresh process, wall time: *cold* with a
   fresh empty compilation cache directory (``JAXSSS_COMPILATION_CACHE``), then *warm* (the same directory again).
   ``python -c "import jaxsss.cli"`` is the floor (importing jax alone is most of it).
2. **First fit in a notebook.** A fresh process imports :mod:`fitting` and fits the issue's problem once (below):
   import and first-fit seconds, cold and warm cache.
3. **One fit, warm.** The issue's problem: skin1 (Jensen 2001: sigma_a 0.032, 0.17, 0.48; sigma_s' 0.74, 0.88,
   1.01 /mm), 3 channels, eta 1.3, 100 radii ``linspace(0.1, 10)`` mm, 1% Gaussian noise, relative weights, the
   default range. ``fitting.fit_profile`` (median of repeats after compilation; the whole pipeline: three starts,
   LM, checks, standard errors) against scipy's ``least_squares(method="lm")`` (MINPACK, 2-point differences) on a
   NumPy dipole with the same residuals and range, one channel after the other from the pipeline's first start.
4. **Batches.** ``B`` profiles (``--quick``: 100 and 1000; full: 1000 and 10,000) of 3 channels, each a skin1-like
   material with ``sigma_a`` and ``sigma_s'`` scaled by independent log-uniform factors in [0.5, 2], 1% noise; one
   ``fit_profiles`` call (its compile time reported apart) against scipy on a subset (per profile).

Error: ``max(|sigma_a / truth - 1|, |sigma_s' / truth - 1|)`` (with noise, so ~1e-2 is the noise, not the method).
Ratios: scipy seconds / fitting seconds (per profile); > 1 means fitting is faster. Wall-clock ratios (the issue's
goals) and CPU-time ratios (``time.process_time``, all threads: the work, less sensitive to other jobs' load) are
both reported.
"""

from __future__ import annotations

import os
import sys

# scipy's side single-threaded (before NumPy loads OpenBLAS): its problems are tiny, and OpenBLAS's spinning threads
# otherwise add CPU time (and compete with XLA) without speeding anything up.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from benchmarks._harness import make_row, parse_args, time_call, time_interleaved, write_results  # noqa: E402

NAME = "fit_speed"
ETA = 1.3
R = np.linspace(0.1, 10.0, 100)
SKIN1_SA = np.array([0.032, 0.17, 0.48])
SKIN1_SS = np.array([0.74, 0.88, 1.01])
ERROR_METRIC = "max rel err of sigma_a, sigma_s' vs truth (1% noise)"


def noisy(sa, ss, rng, noise=0.01):
    """(N, C) dipole profiles with multiplicative Gaussian noise."""
    y = np.stack([dipole_np(R, a, s, ETA) for a, s in zip(sa, ss)], axis=-1)
    return y * (1.0 + noise * rng.standard_normal(y.shape))


def batch_workload(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    sa = SKIN1_SA * np.exp(rng.uniform(np.log(0.5), np.log(2.0), (n, 3)))
    ss = SKIN1_SS * np.exp(rng.uniform(np.log(0.5), np.log(2.0), (n, 3)))
    return sa, ss, np.stack([noisy(a, s, rng) for a, s in zip(sa, ss)])
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
    """One channel: scipy's MINPACK LM on the NumPy dipole, relative residuals on ``r >= r_min``."""
    from scipy.optimize import least_squares

    m = R >= r_min
    r, yy = R[m], y[m]

    def res(th):
        return (dipole_np(r, np.exp(th[0]), np.exp(th[1]), ETA) - yy) / yy

    sol = least_squares(res, theta0, method="lm", xtol=1e-10, ftol=1e-10, gtol=1e-10)
    return np.exp(sol.x)


def scipy_profiles(data, fit, n):
    """scipy on the first ``n`` profiles (all channels) of ``data (B, N, C)`` from the fit's start and range."""
    g_sa = np.asarray(fit.guess_sigma_a).reshape(-1, 3)
    g_ss = np.asarray(fit.guess_sigma_s_prime).reshape(-1, 3)
    r_min = np.asarray(fit.r_min).reshape(-1, 3)
    out = np.zeros((n, 3, 2))
    for b in range(n):
        for c in range(3):
            out[b, c] = scipy_fit(data[b, :, c], np.log([g_sa[b, c], g_ss[b, c]]), r_min[b, c])
    return out


def cpu_seconds(fn, repeats):
    """Median CPU seconds of this process (all threads) per call: on a machine shared with other jobs the wall time
    swings with their load; CPU time measures the work (XLA may use both cores, so wall <= CPU for fitting)."""
    import time

    out = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        out.append(time.process_time() - t0)
    return float(np.median(out))


def rel_error(sa_hat, ss_hat, sa, ss):
    return float(max(np.max(np.abs(np.asarray(sa_hat) / sa - 1)), np.max(np.abs(np.asarray(ss_hat) / ss - 1))))


FIRST_FIT = """
import time, numpy as np
t0 = time.perf_counter()
import fitting
t1 = time.perf_counter()
r = np.linspace(0.1, 10.0, 100)
y = np.load({path!r})
fit = fitting.fit_profile(r, y, eta=1.3, warn=False)
t2 = time.perf_counter()
print(t1 - t0, t2 - t1, bool(fit.converged.all()))
"""


def _process(argv, cache, env_extra=None):
    import os
    import subprocess
    import time

    env = {**os.environ, "JAXSSS_COMPILATION_CACHE": str(cache), **(env_extra or {})}
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{argv}: exit {proc.returncode}: {proc.stderr[-2000:]}")
    return seconds, proc.stdout


def startup_rows(tmp):
    """Cold and warm process times (fresh cache dir, then again)."""
    import shutil
    import sys as _sys

    rng = np.random.default_rng(11)
    r40 = np.geomspace(0.05, 20.0, 40)
    prof = dipole_np(r40, 0.01, 1.5, ETA)
    se = 0.02 * prof
    csv = tmp / "profile.csv"
    noisy40 = prof + se * rng.standard_normal(40)
    csv.write_text("r_mm,R,R_stderr\n" + "\n".join(
        f"{float(a)!r},{float(b)!r},{float(c)!r}" for a, b, c in zip(r40, noisy40, se)) + "\n")
    npy = tmp / "skin1.npy"
    np.save(npy, noisy(SKIN1_SA, SKIN1_SS, np.random.default_rng(0)))
    script = tmp / "first_fit.py"
    script.write_text(FIRST_FIT.format(path=str(npy)))
    py = _sys.executable
    jaxsss_bin = [py, "-m", "jaxsss"]
    cases = {
        "import jaxsss.cli": [py, "-c", "import jaxsss.cli"],
        "jaxsss fit PROFILE.csv": jaxsss_bin + ["fit", str(csv), "--eta", "1.3"],
        "jaxsss reparam (one value)": jaxsss_bin + ["reparam", "--rd", "0.5", "--ld", "1", "--eta", "1.3"],
        "first fit in a fresh process": [py, str(script)],
    }
    out = {}
    for label, argv in cases.items():
        cache = tmp / ("cache_" + label.split()[0].replace(".", "_") + label.split()[-1].replace(".", "_"))
        shutil.rmtree(cache, ignore_errors=True)
        cold, so_cold = _process(argv, cache)
        warm, so_warm = _process(argv, cache)
        out[label] = {"cold": cold, "warm": warm}
        if label.startswith("first fit"):
            imp_c, fit_c, _ = so_cold.split()
            imp_w, fit_w, _ = so_warm.split()
            out[label].update(import_cold=float(imp_c), fit_cold=float(fit_c), import_warm=float(imp_w),
                              fit_warm=float(fit_w))
        print(f"{label}: cold {cold:.2f} s, warm {warm:.2f} s", flush=True)
    return out


def main(argv=None) -> int:
    import os
    import tempfile
    from pathlib import Path

    args = parse_args(argv, __doc__.splitlines()[0])
    import fitting
    import jaxsss

    # The NumPy model is the library's model.
    sa_c, ss_c = np.array([0.001, 0.03, 0.1]), np.array([0.5, 2.0, 5.0])
    ref = np.asarray(fitting.entry_transmittance(ETA) * jaxsss.dipole_profile(R[:, None], jaxsss.Medium(sa_c, ss_c,
                                                                                                          ETA)))
    mine = np.stack([dipole_np(R, a, s, ETA) for a, s in zip(sa_c, ss_c)], axis=1)
    model_check = float(np.max(np.abs(mine / ref - 1)))
    assert model_check < 1e-12, model_check
    rows = []
    load = os.getloadavg()[0]
    print(f"load average {load:.2f}", flush=True)

    # 1-2. Processes, cold and warm.
    with tempfile.TemporaryDirectory() as tmp:
        procs = startup_rows(Path(tmp))
    for label, t in procs.items():
        for which in ("cold", "warm"):
            rows.append(make_row(NAME, f"process: {label} ({which} cache)", which, None, "wall seconds",
                                 t[which], None, **{k: v for k, v in t.items() if k not in ("cold", "warm")}))

    # 3. One fit, warm, against scipy (same data, start and range), timed round-robin (the machine's load drifts).
    rng = np.random.default_rng(1)
    y1 = noisy(SKIN1_SA, SKIN1_SS, rng)
    fit0 = fitting.fit_profile(R, y1, eta=ETA, warn=False)
    both = time_interleaved({"fit": (lambda d: fitting.fit_profile(R, d, eta=ETA, warn=False), (y1,)),
                             "scipy": (lambda: scipy_profiles(y1[None], fit0, 1), ())}, repeats=10)
    t, ts = both["fit"], both["scipy"]
    fit = t.output
    err = rel_error(fit.sigma_a, fit.sigma_s_prime, SKIN1_SA, SKIN1_SS)
    cpu_fit = cpu_seconds(lambda: fitting.fit_profile(R, y1, eta=ETA, warn=False), 10)
    cpu_scipy = cpu_seconds(lambda: scipy_profiles(y1[None], fit0, 1), 10)
    est = ts.output[0]
    err_s = rel_error(est[:, 0], est[:, 1], SKIN1_SA, SKIN1_SS)
    single_ratio = ts.median_seconds / t.median_seconds
    single_cpu_ratio = cpu_scipy / cpu_fit
    rows.append(make_row(NAME, "fitting.fit_profile (one 3-channel fit)", 1, err, ERROR_METRIC, t.median_seconds,
                         t.compile_seconds, batch=1, iterations=np.asarray(fit.iterations).tolist(),
                         cpu_seconds=cpu_fit))
    rows.append(make_row(NAME, "scipy least_squares (lm, NumPy model; 3 channels)", 1, err_s, ERROR_METRIC,
                         ts.median_seconds, None, batch=1, cpu_seconds=cpu_scipy))
    print(f"one fit: fitting {t.median_seconds * 1e3:.2f} ms (compile {t.compile_seconds:.1f} s, err {err:.1e}), "
          f"scipy {ts.median_seconds * 1e3:.2f} ms (err {err_s:.1e}); ratio {single_ratio:.2f} wall, "
          f"{single_cpu_ratio:.2f} CPU", flush=True)

    # 4. Batches.
    sizes = (100, 1000) if args.quick else (1000, 10_000)
    scipy_subset = 20 if args.quick else 100
    ratios, cpu_ratios = {}, {}
    for B in sizes:
        sa, ss, data = batch_workload(B, seed=B)
        t = time_call(lambda d: fitting.fit_profiles(R, d, eta=ETA, warn=False), data, repeats=2)
        fit = t.output
        err = rel_error(fit.sigma_a, fit.sigma_s_prime, sa, ss)
        per_jax = t.median_seconds / B
        n = min(B, scipy_subset)
        ts = time_call(lambda: scipy_profiles(data, fit, n), repeats=1)
        est = ts.output
        err_s = rel_error(est[..., 0], est[..., 1], sa[:n], ss[:n])
        per_scipy = ts.seconds / n
        ratios[str(B)] = per_scipy / per_jax
        cpu_jax = cpu_seconds(lambda: fitting.fit_profiles(R, data, eta=ETA, warn=False), 2) / B
        cpu_sp = cpu_seconds(lambda: scipy_profiles(data, fit, n), 1) / n
        cpu_ratios[str(B)] = cpu_sp / cpu_jax
        iters = np.asarray(fit.iterations)
        rows.append(make_row(NAME, "fitting.fit_profiles", B, err, ERROR_METRIC, t.median_seconds, t.compile_seconds,
                             batch=B, seconds_per_profile=per_jax, converged=int(np.sum(fit.converged)),
                             reliable=int(np.sum(fit.reliable)), mean_iterations=float(iters.mean()),
                             max_iterations=int(iters.max()), cpu_seconds_per_profile=cpu_jax))
        rows.append(make_row(NAME, "scipy least_squares (lm, NumPy model)", B, err_s, ERROR_METRIC, ts.seconds, None,
                             batch=B, profiles_timed=n, seconds_per_profile=per_scipy, cpu_seconds_per_profile=cpu_sp))
        print(f"B={B}: fitting {per_jax * 1e3:.3f} ms/profile (compile {t.compile_seconds:.1f} s, err {err:.1e}, "
              f"iterations mean {iters.mean():.1f} max {iters.max()}); scipy {per_scipy * 1e3:.3f} ms/profile "
              f"(err {err_s:.1e}); ratio {ratios[str(B)]:.1f}x wall, {cpu_ratios[str(B)]:.1f}x CPU", flush=True)
    summary = {"ratio_scipy_over_fitting_one_fit": single_ratio, "ratio_scipy_over_fitting_per_profile": ratios,
               "cpu_ratio_one_fit": single_cpu_ratio, "cpu_ratio_per_profile": cpu_ratios,
               "load_average_at_end": os.getloadavg()[0],
               "processes": procs, "goals": {"fit_process_warm_s": 2, "fit_process_cold_s": 5, "first_fit_s": 2,
                                             "one_fit_ratio": 1, "batch_ratio": 20},
               "numpy_model_max_rel_diff_vs_jaxsss": model_check, "radii": len(R), "eta": ETA,
               "load_average_at_start": load}
    notes = ["seconds: median per call (fitting) or per timed subset (scipy); compare seconds_per_profile",
             "scipy: same residuals, range and start (the pipeline's first start), one channel at a time",
             "process rows: wall seconds of a fresh process; cold = empty compilation cache directory"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title=f"{NAME}: error vs seconds per call", connect=False)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
