"""Rd -> alpha' inversion: error against time for Newton (:func:`jaxsss.reflectance.invert_rd`) and tables.

What is measured. One call inverts a batch of total diffuse reflectances ``Rd`` (hierarchical paper Eq. 15) spread
over ``(1e-4, 1 - 1e-4)`` -- half log-spaced in ``Rd`` (the ``Rd -> 0`` end), half log-spaced in ``1 - Rd``
(the stiff ``Rd -> 1`` end) -- for three boundaries, ``eta`` = 1.0, 1.3, 2.5 (``A`` from the "poly" ``F_dr``),
interleaved in one batch in random order.

Methods:

- ``invert_rd tol``: :func:`~jaxsss.reflectance.invert_rd` (Optimistix Newton, vmapped) with ``rtol = atol`` swept
  from 1e-4 to 1e-14, ``max_steps`` 64;
- ``invert_rd max_steps``: the same at ``rtol = atol = 1e-14`` with the iteration cap swept (capped elements keep
  their last iterate);
- ``table catmull-rom``: pbrt-v4's approach (``BSSRDFTable`` + ``InvertCatmullRom``), written here in JAX: ``Rd``
  tabulated per ``A`` at ``n`` albedos with pbrt's spacing ``alpha'_i = (1 - exp(-8 i/(n-1))) / (1 - exp(-8))``
  (dense near ``alpha' = 1``), then a monotone binary search for the segment and a safeguarded Newton-bisection
  (fixed 8 steps) on the segment's Catmull-Rom cubic, with pbrt's nonuniform finite-difference slopes.
  ``1 - alpha'`` comes from the stored ``1 - alpha'_i`` nodes (no cancellation in the nodes themselves).

Error. ``error = max(max rel err of alpha', max rel err of 1 - alpha')`` over the batch, both also stored
(``err_alpha``, ``err_one_minus_alpha``, and ``err_mid`` restricted to ``Rd`` in [0.01, 0.99]). The reference is
``invert_rd`` at ``rtol = atol = 1e-15``, ``max_steps`` 256, verified by the forward map: the relative residuals of
``Rd`` and of ``1 - Rd`` (computed without cancellation) are stored in the summary.
"""

from __future__ import annotations

import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._harness import make_row, parse_args, time_interleaved, write_results
from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.fresnel import A_coefficient
from jaxsss.reflectance import _neg_log_rd_of_s, invert_rd, total_diffuse_reflectance

NAME = "rd_inversion"
ETAS = (1.0, 1.3, 2.5)
RD_EDGE = 1e-4
ERROR_METRIC = "max(max rel err alpha', max rel err 1-alpha')"
NEWTON_BISECTION_STEPS = 8  # fixed, so the table inversion vectorises with no while_loop


# --- Workload and reference -------------------------------------------------------------------------------------------
def workload(n: int, seed: int = 0):
    """``(Rd, A, k)``: ``n`` reflectances, their boundary coefficient and boundary index ``k`` into :data:`ETAS`."""
    half = n // 2
    lo = np.logspace(np.log10(RD_EDGE), np.log10(0.5), half)
    hi = 1.0 - np.logspace(np.log10(RD_EDGE), np.log10(0.5), n - half)[::-1]
    Rd = np.concatenate([lo, hi])
    rng = np.random.default_rng(seed)
    k = rng.integers(0, len(ETAS), size=n)
    perm = rng.permutation(n)
    Rd = Rd[perm]
    A_values = np.asarray(A_coefficient(jnp.asarray(ETAS)))
    return jnp.asarray(Rd), jnp.asarray(A_values[k]), jnp.asarray(k, dtype=jnp.int32), A_values


def neg_log_rd(alpha, one_minus_alpha, A):
    """``-log Rd`` (Eq. 15) from ``alpha'`` and ``1 - alpha'``, each used where it is accurate (no cancellation)."""
    u = jnp.sqrt(3.0 * one_minus_alpha)
    log_alpha = jnp.where(alpha < 0.5, jnp.log(alpha), jnp.log1p(-one_minus_alpha))
    return -log_alpha - jnp.log1p(0.5 * jnp.expm1(-4.0 / 3.0 * A * u)) + u


def reference(Rd, A):
    ref = invert_rd(Rd, A, rtol=1e-15, atol=1e-15, max_steps=256)
    L = neg_log_rd(ref.alpha_prime, ref.one_minus_alpha_prime, A)
    # Rd as the product of Eq. 15's factors (accurate at Rd -> 0); 1 - Rd = -expm1(-L) (accurate at Rd -> 1).
    u = ref.u
    fwd = np.asarray(0.5 * ref.alpha_prime * (1.0 + jnp.exp(-4.0 / 3.0 * A * u)) * jnp.exp(-u))
    Rd_np = np.asarray(Rd)
    one_minus_fwd = np.asarray(-jnp.expm1(-L))
    check = {
        "settings": "invert_rd(rtol=atol=1e-15, max_steps=256)",
        # At 1e-15 some iterates stall at rounding level and hit the cap; the forward map checks the values.
        "n_not_converged": int(np.sum(~np.asarray(ref.converged))),
        "max_steps_taken": int(np.max(np.asarray(ref.steps))),
        # Forward map Rd(alpha'_ref) against the input; 1 - Rd is exact in float64 for Rd >= 1/2 (Sterbenz).
        "forward_rel_residual_Rd": float(np.max(np.abs(fwd - Rd_np) / Rd_np)),
        "forward_rel_residual_1_minus_Rd": float(np.max(np.abs(one_minus_fwd - (1.0 - Rd_np)) / (1.0 - Rd_np))),
    }
    return np.asarray(ref.alpha_prime), np.asarray(ref.one_minus_alpha_prime), check


def errors(alpha, one_minus, ref_alpha, ref_om, Rd):
    alpha, one_minus = np.asarray(alpha), np.asarray(one_minus)
    ea = np.abs(alpha - ref_alpha) / ref_alpha
    eo = np.abs(one_minus - ref_om) / ref_om
    mid = (np.asarray(Rd) >= 0.01) & (np.asarray(Rd) <= 0.99)
    return {
        "err_alpha": float(np.max(ea)),
        "err_one_minus_alpha": float(np.max(eo)),
        "err_mid": float(max(np.max(ea[mid]), np.max(eo[mid]))),
    }


# --- pbrt-v4 style table + InvertCatmullRom, in JAX -------------------------------------------------------------------
def build_table(n: int, A_values):
    """Per-boundary tables, flattened: ``(Rd_i, alpha'_i, 1 - alpha'_i)`` each of shape ``(len(A) * n,)``."""
    i = np.arange(n)
    # pbrt-v4 BSSRDFTable rho samples: (1 - exp(-8 i/(n-1))) / (1 - exp(-8)); and 1 - rho without cancellation.
    alpha = -np.expm1(-8.0 * i / (n - 1)) / -np.expm1(-8.0)
    one_minus = (np.exp(-8.0 * i / (n - 1)) - np.exp(-8.0)) / -np.expm1(-8.0)
    alpha[-1], one_minus[-1] = 1.0, 0.0
    Rd = total_diffuse_reflectance(jnp.asarray(alpha)[None, :], jnp.asarray(A_values)[:, None])
    tile = lambda x: jnp.asarray(np.tile(x, len(A_values)))  # noqa: E731
    return jnp.reshape(Rd, -1), tile(alpha), tile(one_minus)


def _invert_table_impl(tab_Rd, tab_alpha, tab_om, Rd, k, n: int):
    base = k * n
    # Monotone search (pbrt FindInterval): largest i in [0, n-2] with tab_Rd[i] <= Rd, by fixed-count bisection.
    lo = jnp.zeros_like(k)
    hi = jnp.full_like(k, n - 1)

    def search(_, lohi):
        lo, hi = lohi
        mid = (lo + hi) // 2
        go_right = tab_Rd[base + mid] <= Rd
        return jnp.where(go_right, mid, lo), jnp.where(go_right, hi, mid)

    lo, hi = jax.lax.fori_loop(0, int(np.ceil(np.log2(n - 1))), search, (lo, hi))
    i = lo
    x0, x1 = tab_alpha[base + i], tab_alpha[base + i + 1]
    f0, f1 = tab_Rd[base + i], tab_Rd[base + i + 1]
    width = x1 - x0
    # Catmull-Rom slopes from nonuniform finite differences (pbrt InvertCatmullRom), one-sided at the ends.
    im1, ip2 = jnp.maximum(i - 1, 0), jnp.minimum(i + 2, n - 1)
    d0 = jnp.where(i > 0, width * (f1 - tab_Rd[base + im1]) / (x1 - tab_alpha[base + im1]), f1 - f0)
    d1 = jnp.where(i + 2 < n, width * (tab_Rd[base + ip2] - f0) / (tab_alpha[base + ip2] - x0), f1 - f0)

    def cubic(t):
        t2, t3 = t * t, t * t * t
        F = (2 * t3 - 3 * t2 + 1) * f0 + (-2 * t3 + 3 * t2) * f1 + (t3 - 2 * t2 + t) * d0 + (t3 - t2) * d1
        dF = (6 * t2 - 6 * t) * f0 + (-6 * t2 + 6 * t) * f1 + (3 * t2 - 4 * t + 1) * d0 + (3 * t2 - 2 * t) * d1
        return F - Rd, dF

    # Newton-bisection on t in [0, 1] (pbrt NewtonBisection), fixed step count; start from linear interpolation.
    def newton(_, state):
        t, a, b = state
        F, dF = cubic(t)
        a, b = jnp.where(F < 0, t, a), jnp.where(F < 0, b, t)
        t_new = t - F / jnp.where(dF == 0, 1.0, dF)
        bad = (dF == 0) | ~(t_new > a) | ~(t_new < b)
        return jnp.where(bad, 0.5 * (a + b), t_new), a, b

    t0 = jnp.clip((Rd - f0) / (f1 - f0), 0.0, 1.0)
    t, _, _ = jax.lax.fori_loop(0, NEWTON_BISECTION_STEPS, newton, (t0, jnp.zeros_like(t0), jnp.ones_like(t0)))
    return x0 + t * width, tab_om[base + i] - t * width


invert_table = jax.jit(_invert_table_impl, static_argnames="n")


# --- The run ----------------------------------------------------------------------------------------------------------
# Sizes and sweeps per mode (a test shrinks "quick" further). The goal check needs tol 1e-12 and table 100.
CONFIG = {
    "quick": {"n_batch": 10_000, "repeats": 5, "tols": (1e-4, 1e-8, 1e-12, 1e-14), "caps": (2, 4),
              "tables": (100, 1000)},
    "full": {"n_batch": 100_000, "repeats": 9, "tols": (1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 1e-14),
             "caps": (1, 2, 3, 4, 5, 6), "tables": (30, 100, 1000, 10000)},
}


def run(quick: bool):
    cfg = CONFIG["quick" if quick else "full"]
    n_batch, repeats = cfg["n_batch"], cfg["repeats"]
    Rd, A, k, A_values = workload(n_batch)
    ref_alpha, ref_om, check = reference(Rd, A)
    print(f"  reference: {check}", flush=True)
    rows = []

    def add(method, setting, timing, alpha, one_minus, **extra):
        errs = errors(alpha, one_minus, ref_alpha, ref_om, Rd)
        row = make_row(NAME, method, setting, error=max(errs["err_alpha"], errs["err_one_minus_alpha"]),
                       error_metric=ERROR_METRIC, seconds=timing.seconds, compile_seconds=timing.compile_seconds,
                       median_seconds=timing.median_seconds, repeats=timing.repeats, n_batch=n_batch, **errs, **extra)
        rows.append(row)
        print(f"  {method:20s} {str(setting):6s} err {row['error']:.2e} (alpha {row['err_alpha']:.1e}, 1-alpha "
              f"{row['err_one_minus_alpha']:.1e}, mid {row['err_mid']:.1e}) "
              f"{row['seconds'] * 1e3:8.2f} ms  compile {row['compile_seconds']:.2f} s", flush=True)

    # Every (method, setting), timed round-robin so that other load on the machine hits all of them alike.
    calls, build_seconds = {}, {}
    for tol in cfg["tols"]:
        calls[("invert_rd tol", f"{tol:.0e}")] = (invert_rd, (Rd, A), {"rtol": tol, "atol": tol})
    for cap in cfg["caps"]:
        calls[("invert_rd max_steps", cap)] = (invert_rd, (Rd, A), {"rtol": 1e-14, "atol": 1e-14, "max_steps": cap})
    for n in cfg["tables"]:
        t0 = time.perf_counter()
        tables = jax.block_until_ready(build_table(n, A_values))
        build_seconds[n] = time.perf_counter() - t0
        calls[("table catmull-rom", n)] = (invert_table, (*tables, Rd, k), {"n": n})
    calls.update(diagnostic_calls(Rd, A))
    timings = time_interleaved(calls, repeats)

    for (method, setting), t in timings.items():
        if method == "diag":
            continue
        if method == "table catmull-rom":
            add(method, setting, t, *t.output, table_build_seconds=build_seconds[setting])
            continue
        res = t.output
        steps = np.asarray(res.steps)
        add(method, setting, t, res.alpha_prime, res.one_minus_alpha_prime,
            mean_steps=float(steps.mean()), max_steps_taken=int(steps.max()),
            n_not_converged=int(np.sum(~np.asarray(res.converged))))

    summary = {"reference": check, "why": diagnose_newton(timings)}
    newton_12 = next(r for r in rows if r["method"] == "invert_rd tol" and r["setting"] == "1e-12")
    table_100 = next(r for r in rows if r["method"] == "table catmull-rom" and r["setting"] == 100)
    summary["goal"] = {
        "statement": "invert_rd at 1e-12 no slower than the 100-sample table at its own accuracy",
        "invert_rd_1e-12_error": newton_12["error"],
        "invert_rd_1e-12_seconds": newton_12["seconds"],
        "table_100_error": table_100["error"],
        "table_100_err_mid": table_100["err_mid"],
        "table_100_seconds": table_100["seconds"],
        "newton_over_table_time": newton_12["seconds"] / table_100["seconds"],
        "met": bool(newton_12["seconds"] <= table_100["seconds"]),
    }
    return rows, summary


def diagnostic_calls(Rd, A) -> dict:
    """Extra calls timed with the sweep, to show where invert_rd's time goes (see :func:`diagnose_newton`)."""
    from jaxsss.reflectance import _invert

    log_L = jnp.log(-jnp.log(Rd))

    # One residual + derivative evaluation over the whole batch: the floor for one Newton step.
    @jax.jit
    def one_step(s):
        f = lambda s_: jnp.log(_neg_log_rd_of_s(s_, A)) - log_L  # noqa: E731
        val, slope = jax.jvp(f, (s,), (jnp.ones_like(s),))
        return s - val / slope

    return {
        ("diag", "jitted core"): (_invert, (Rd, A, 1e-12, 1e-12, 64)),
        ("diag", "one step"): (one_step, (jnp.zeros_like(Rd),)),
    }


def diagnose_newton(timings: dict) -> dict:
    """Where invert_rd's time goes: validation, lockstep iterations, the while_loop, and the steps themselves."""
    t_public = timings[("invert_rd tol", "1e-12")]
    t_jitted, t_step = timings[("diag", "jitted core")], timings[("diag", "one step")]
    steps = np.asarray(t_public.output.steps)
    max_steps, mean_steps = int(steps.max()), float(steps.mean())
    return {
        "invert_rd_1e-12_seconds": t_public.seconds,
        "jitted_core_seconds (no eager validation)": t_jitted.seconds,
        "eager_validation_seconds": t_public.seconds - t_jitted.seconds,
        "max_newton_steps": max_steps,
        "mean_newton_steps": mean_steps,
        # vmap of a while_loop runs every lane until the slowest converges: max/mean steps of wasted work.
        "lockstep_factor": max_steps / mean_steps,
        "one_vectorised_newton_step_seconds": t_step.seconds,
        "steps_x_one_step_seconds": max_steps * t_step.seconds,
        "while_loop_overhead_factor": t_jitted.seconds / (max_steps * t_step.seconds),
    }


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    load_at_start = os.getloadavg()[0]  # the machine may be shared; recorded next to the end-of-run load
    rows, summary = run(args.quick)
    notes = [
        "seconds: min of the repeats after compilation (median in median_seconds), all settings timed round-robin; "
        "compile_seconds: first call",
        f"error: {ERROR_METRIC} against invert_rd(rtol=atol=1e-15), checked by the forward map (summary.reference)",
        "err_mid: the same metric restricted to Rd in [0.01, 0.99]",
        f"table: pbrt-v4 spacing, binary search, {NEWTON_BISECTION_STEPS} Newton-bisection steps on the cubic",
    ]
    summary["loadavg_1min_at_start"] = load_at_start
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary, notes=notes,
                                        title="Rd -> alpha' inversion: error vs seconds per batch")
    for key in ("goal", "why"):
        print(f"  {key}: {summary[key]}")
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
