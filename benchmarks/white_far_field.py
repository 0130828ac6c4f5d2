"""White Monte Carlo against direct runs out to 20 diffusion lengths, with a radially split reference.

A plain run cannot measure R(r) far from the source: at 20 l_d the profile is ~1e-10 of its peak and a 1e5-photon run
has no counts there. The reference here is :func:`jaxsss.mc.simulate` with radial splitting (a weight window
``W(r) = exp(-(r - l_d) / l_d)`` from ``l_d`` to ``20 l_d``; standard errors from 16 batch means), which keeps the
number of photons roughly constant with r. Held-out media (the tables are non-absorbing runs; no absorbing medium
was used to build them), normal incidence, a half-space.

Rows, per case:
- ``split reference``: error = the largest relative stderr over the bins from 0.1 l_u to 20 l_d; seconds = run time.
- ``plain reference``: a plain run with the same number of photon events (the natural alternative at equal cost);
  error = its largest relative stderr over the same bins (``None`` when a bin has no counts at all).
- ``white MC``: error = the largest ``|model / reference - 1|`` over the bins (model averaged over each annulus);
  extras give it per band of r / l_d with the largest ``|z|`` (model minus reference over the combined stderr of
  the reference and the table) and the table's own relative stderr; seconds = the model's evaluation time.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results
from benchmarks.transport_error import _annulus_average
from jaxsss.mc import (
    Stack,
    load_white_table,
    simulate,
    white_mc_profile,
    white_mc_profile_stderr,
)
from jaxsss.medium import Medium

NAME = "white_far_field"
# (g, n, sigma_a, sigma_s') in 1/mm; the first is tests/mc/test_white.py's held-out g = 0 case.
CASES = ((0.0, 1.4, 0.05, 2.0), (0.0, 1.0, 0.3, 1.0), (0.9, 1.0, 0.1, 1.0))
BANDS_LD = ((0.0, 1.0), (1.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 20.0))
CONFIG = {"quick": {"cases": CASES[1:2], "photons": 20_000}, "full": {"cases": CASES, "photons": 100_000}}


def _rel(value, err):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(value > 0, err / value, np.inf)


def run_case(g, n, sigma_a, sigma_sp, photons):
    m = Medium(sigma_a, sigma_sp, eta=n)
    l_u, l_d = float(m.l_u), float(m.l_d)
    edges = np.geomspace(0.1 * l_u, 20 * l_d, 31)
    stack = Stack.half_space(sigma_a, sigma_sp / (1 - g), g, n)
    ref = simulate(stack, photons, seed=11, r_edges=edges, split_length=l_d, split_start=l_d, split_stop=20 * l_d,
                   weight_threshold=1e-3, progress=False)
    # The plain run at equal cost: as many photon events as the split run used.
    probe = simulate(stack, 5_000, seed=12, progress=False)
    plain_photons = int(ref.events / (probe.events / probe.photons))
    plain = simulate(stack, plain_photons, seed=13, r_edges=edges, progress=False)
    table = load_white_table(g, n)
    model = _annulus_average(lambda r: white_mc_profile(r, sigma_a, sigma_sp, table), edges)
    centres = np.sqrt(edges[1:] * edges[:-1])
    rel_table = np.asarray(white_mc_profile_stderr(centres, sigma_a, sigma_sp, table))
    se = np.hypot(ref.R_r_stderr, rel_table * model)
    err = model / ref.R_r - 1.0
    z = (model - ref.R_r) / se
    timing = time_call(lambda: white_mc_profile(centres, sigma_a, sigma_sp, table), repeats=5)
    setting = f"g={g:g} n={n:g} sa={sigma_a:g} ssp'={sigma_sp:g}"
    bands = {}
    for lo, hi in BANDS_LD:
        sel = (centres / l_d >= lo) & (centres / l_d < hi)
        bands[f"{lo:g}-{hi:g} l_d"] = {
            "max_abs_rel_error": float(np.max(np.abs(err[sel]))), "max_abs_z": float(np.max(np.abs(z[sel]))),
            "max_ref_rel_stderr": float(np.max(_rel(ref.R_r[sel], ref.R_r_stderr[sel]))),
            "max_table_rel_stderr": float(np.max(rel_table[sel])),
            "within_2pct_or_3_sigma": bool(np.all((np.abs(err[sel]) <= 0.02) | (np.abs(z[sel]) <= 3.0)))}
    rel_ref = _rel(ref.R_r, ref.R_r_stderr)
    rel_plain = _rel(plain.R_r, plain.R_r_stderr)
    far = centres / l_d >= 10
    rows = [
        make_row(NAME, "split reference", setting, float(rel_ref.max()), "max relative stderr, 0.1 l_u - 20 l_d",
                 ref.seconds - ref.compile_seconds, ref.compile_seconds, photons=photons, events=ref.events,
                 far_rel_stderr=float(rel_ref[far].max())),
        make_row(NAME, "plain reference", setting, float(rel_plain.max()) if np.isfinite(rel_plain).all() else None,
                 "max relative stderr, 0.1 l_u - 20 l_d", plain.seconds - plain.compile_seconds,
                 plain.compile_seconds, photons=plain_photons, events=plain.events,
                 far_rel_stderr=float(rel_plain[far].max()), empty_bins=int((plain.R_r <= 0).sum())),
        make_row(NAME, "white MC", setting, float(np.max(np.abs(err))), "max |model/reference - 1|, 0.1 l_u - 20 l_d",
                 timing.seconds, timing.compile_seconds, max_abs_z=float(np.max(np.abs(z))),
                 within_2pct_or_3_sigma=bool(np.all((np.abs(err) <= 0.02) | (np.abs(z) <= 3.0))), bands=bands),
    ]
    profile = {"r_over_ld": (centres / l_d).tolist(), "reference": ref.R_r.tolist(),
               "reference_stderr": ref.R_r_stderr.tolist(), "model": model.tolist(),
               "table_rel_stderr": rel_table.tolist(), "plain": plain.R_r.tolist(),
               "plain_stderr": plain.R_r_stderr.tolist()}
    return rows, {"setting": setting, "l_u": l_u, "l_d": l_d, "profile": profile}


def plot_profiles(cases, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f, axes = plt.subplots(1, len(cases), figsize=(5 * len(cases), 4), squeeze=False)
    for ax, case in zip(axes[0], cases):
        p = {k: np.asarray(v) for k, v in case["profile"].items()}
        x = p["r_over_ld"]
        ratio = p["model"] / p["reference"]
        ax.errorbar(x, ratio - 1, yerr=p["reference_stderr"] / p["reference"], fmt="o", ms=3,
                    label="white MC / split reference - 1 (reference stderr)")
        ax.fill_between(x, -p["table_rel_stderr"], p["table_rel_stderr"], alpha=0.25, label="table stderr")
        with np.errstate(divide="ignore", invalid="ignore"):
            plain_rel = np.where(p["plain"] > 0, p["plain_stderr"] / p["plain"], np.nan)
        ax.plot(x, plain_rel, "k:", label="plain run at equal cost: rel. stderr")
        ax.axhspan(-0.02, 0.02, color="g", alpha=0.1)
        ax.set_xscale("log")
        ax.set_ylim(-0.5, 0.5)
        ax.set_xlabel("r / l_d")
        ax.set_title(case["setting"], fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("relative error")
    axes[0][0].legend(fontsize=7)
    f.tight_layout()
    f.savefig(path, dpi=100)
    plt.close(f)


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    cfg = CONFIG["quick" if args.quick else "full"]
    t0 = time.perf_counter()
    rows, cases = [], []
    for g, n, sa, ssp in cfg["cases"]:
        case_rows, case = run_case(g, n, sa, ssp, cfg["photons"])
        rows += case_rows
        cases.append(case)
        w = case_rows[2]
        print(f"  {case['setting']:34s} max |err| {w['error']:.3f}, max |z| {w['max_abs_z']:.1f}, split far stderr "
              f"{case_rows[0]['far_rel_stderr']:.3f} vs plain {case_rows[1]['far_rel_stderr']:.3f}", flush=True)
    summary = {"cases": [{k: v for k, v in c.items() if k != "profile"} for c in cases],
               "profiles": cases, "wall_seconds": time.perf_counter() - t0}
    notes = ["reference: simulate(split_length=l_d, split_start=l_d, split_stop=20 l_d, weight_threshold=1e-3)",
             "plain reference: the same number of photon events without splitting",
             "z: (model - reference) / hypot(reference stderr, table stderr)"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="white MC to 20 l_d: error vs seconds", connect=False)
    prof_path = args.out / f"{NAME}{args.tag}_profiles.png"
    plot_profiles(cases, prof_path)
    print(f"wrote {json_path}, {png_path} and {prof_path} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
