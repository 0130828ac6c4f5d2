"""Replay (perturbation) Monte Carlo fits of the MCML slab and layered files: recovered vs true, time, simulations.

What is measured (``python -m benchmarks.replay_fits [--quick]``):

- ``fit``: :func:`fitting.fit_replay` on every slab and layered file of ``/work/shared/reference/mcml`` (quick: the
  0.3 mm slab only): R(r) and T(r) for slabs, R(r) for the two-layer half-space; the deepest layer free, starting at
  (1.3 sigma_a, 0.8 sigma_s') of the truth. ``error`` is the larger relative error of sigma_a and sigma_s';
  ``seconds`` is the wall time of the fit (recordings and first-time compilation included), with simulations and
  photons.
- ``totals``: :func:`fitting.fit_slab_totals` on (R, T) from iadpython (adding-doubling, 16 quadrature points).
- ``ess``: ``ess_fraction`` (global and median over the fitted bins) of a sample recorded at the truth, against the
  relative change of sigma_s' (and of sigma_a, which costs nothing).
- ``profile``: the replayed profile against MCML per radial band, from a sample at the truth and from one at
  sigma_s' 5% off: median |relative error| and mean z-score (combined standard errors) per band.
"""

from __future__ import annotations

import os
import re
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np



class MCMLCase(NamedTuple):
    """One MCML run from its ``.csv`` (mm, 1/mm): layers as dicts ``n, mua, mus, g, d`` (top first), ambient
    indices, photon count, run seconds, the header's totals and the profiles (per incident photon per mm^2)."""

    name: str
    layers: list
    n_above: float
    n_below: float
    photons: int
    seconds: float
    totals: dict
    r_edges: np.ndarray
    R_r: np.ndarray
    T_r: np.ndarray


def read_mcml_csv(name: str, directory: Path | None = None) -> MCMLCase:
    """Parse ``NAME.csv`` of the shared MCML set (the two header lines give the parameters and MCML's totals).

    Only the test and benchmark helper of the replay fits: the fitting layer's ``.mco`` reader is ``fitting.mco``.
    """
    from benchmarks.mcml_fits import mcml_dir

    path = Path(directory or mcml_dir()) / f"{name}.csv"
    with open(path) as f:
        head, tot = f.readline(), f.readline()
    layers = [dict(n=float(m[1]), mua=float(m[2]), mus=float(m[3]), g=float(m[4]), d=float(m[5]))
              for m in re.finditer(r"layer\d+: n=([\d.]+) mua=([\d.]+)/mm mus=([\d.]+)/mm g=([\d.]+) d=([\d.]+|inf) mm",
                                   head)]
    amb = re.search(r"n_above=([\d.]+) n_below=([\d.]+)", head)
    photons = int(re.search(r"photons=(\d+)", head)[1])
    seconds = float(re.search(r"seconds=([\d.]+)", head)[1])
    totals = {k: float(v) for k, v in re.findall(r"(\w+)=([\d.eE+-]+)", tot)}
    if not layers or amb is None:
        raise ValueError(f"read_mcml_csv({path}): line 1 does not describe the layers and ambient indices")
    data = np.loadtxt(path, delimiter=",", comments="#", skiprows=3)
    r_edges = np.concatenate([data[:, 0], data[-1:, 1]])
    return MCMLCase(name, layers, float(amb[1]), float(amb[2]), photons, seconds, totals, r_edges, data[:, 2],
                    data[:, 3])


NAME = "replay_fits"
CASES = ("slab03mm_n133_g09", "slab2mm_n14_g08", "skin2layer_n14_g08")
START = (1.3, 0.8)  # the fits start at (1.3 sigma_a, 0.8 sigma_s') of the truth
CONFIG = {
    "quick": dict(cases=CASES[:1], photons=50_000, totals=((0.5, 3.0, 0.9, 1.33, 0.3),), ess_photons=20_000),
    "full": dict(cases=CASES, photons=100_000, totals=((0.5, 3.0, 0.9, 1.33, 0.3), (0.05, 1.0, 0.8, 1.4, 1.0),
                                                       (0.01, 2.0, 0.0, 1.5, 2.0)), ess_photons=100_000),
}
BANDS_MM = ((0.0, 0.1), (0.1, 0.5), (0.5, 2.0), (2.0, 5.0), (5.0, 10.0))


def mcml_stack(case: MCMLCase, factors=(1.0, 1.0)):
    """The case's stack; the deepest layer's (sigma_a, sigma_s) multiplied by ``factors``."""
    from jaxsss.mc import Layer, Stack

    last = len(case.layers) - 1
    layers = [Layer(l["mua"] * (factors[0] if i == last else 1.0), l["mus"] * (factors[1] if i == last else 1.0),
                    l["g"], l["n"], l["d"]) for i, l in enumerate(case.layers)]
    return Stack(layers, case.n_above, case.n_below)


def mcml_data(case: MCMLCase, stack):
    from fitting import ReplayData

    return ReplayData(r_edges=case.r_edges, R_r=case.R_r, T_r=None if stack.is_half_space else case.T_r,
                      photons=case.photons)


def _truth(case: MCMLCase):
    deep = case.layers[-1]
    return deep["mua"], deep["mus"] * (1.0 - deep["g"])


def _fit_rows(cfg):
    from benchmarks._harness import make_row
    from fitting import fit_replay

    rows = []
    for name in cfg["cases"]:
        case = read_mcml_csv(name)
        stack = mcml_stack(case, START)
        sa, ssp = _truth(case)
        fit = fit_replay(stack, mcml_data(case, stack), photons=cfg["photons"], seed=1)
        e_a, e_s = fit.sigma_a[0] / sa - 1.0, fit.sigma_s_prime[0] / ssp - 1.0
        rows.append(make_row(
            NAME, "fit", name, max(abs(e_a), abs(e_s)), "max relative error of sigma_a, sigma_s'", fit.seconds, None,
            sigma_a=fit.sigma_a[0], sigma_a_stderr=fit.sigma_a_stderr[0], sigma_a_true=sa, sigma_a_error=e_a,
            sigma_s_prime=fit.sigma_s_prime[0], sigma_s_prime_stderr=fit.sigma_s_prime_stderr[0],
            sigma_s_prime_true=ssp, sigma_s_prime_error=e_s, z_sigma_a=e_a * sa / fit.sigma_a_stderr[0],
            z_sigma_s_prime=e_s * ssp / fit.sigma_s_prime_stderr[0], status=fit.status, simulations=fit.simulations,
            photons_simulated=fit.photons_simulated, iterations=fit.iterations, reduced_chi2=fit.reduced_chi2,
            n_points=fit.n_points, ess_fraction=fit.ess_fraction, cap_bound=fit.cap_bound,
            mcml_photons=case.photons, mcml_seconds=case.seconds))
        print(f"  fit {name}: sigma_a {fit.sigma_a[0]:.5g} +- {fit.sigma_a_stderr[0]:.2g} (true {sa:g}, "
              f"{100 * e_a:+.2f}%), sigma_s' {fit.sigma_s_prime[0]:.5g} +- {fit.sigma_s_prime_stderr[0]:.2g} (true "
              f"{ssp:g}, {100 * e_s:+.2f}%), {fit.seconds:.1f} s, {fit.simulations} sims, {fit.status}", flush=True)
    return rows


def _totals_rows(cfg):
    import iadpython

    from benchmarks._harness import make_row
    from fitting import fit_slab_totals
    from jaxsss.fresnel import fresnel_reflectance

    rows = []
    for sa, ssp, g, n, d in cfg["totals"]:
        mus = ssp / (1.0 - g)
        ur1, ut1, _, _ = iadpython.Sample(a=mus / (mus + sa), b=(mus + sa) * d, g=g, d=d, n=n, quad_pts=16).rt()
        R, T = float(ur1) - float(fresnel_reflectance(n, 1.0)), float(ut1)
        fit = fit_slab_totals(R, T, g=g, n=n, thickness=d, guess=(1.4 * sa, 0.6 * ssp), photons=cfg["photons"],
                              seed=2)
        e_a, e_s = fit.sigma_a[0] / sa - 1.0, fit.sigma_s_prime[0] / ssp - 1.0
        setting = f"sa={sa:g} ssp={ssp:g} g={g:g} n={n:g} d={d:g}"
        rows.append(make_row(
            NAME, "totals vs iadpython", setting, max(abs(e_a), abs(e_s)), "max relative error of sigma_a, sigma_s'",
            fit.seconds, None, R=R, T=T, sigma_a=fit.sigma_a[0], sigma_a_stderr=fit.sigma_a_stderr[0],
            sigma_s_prime=fit.sigma_s_prime[0], sigma_s_prime_stderr=fit.sigma_s_prime_stderr[0],
            sigma_a_error=e_a, sigma_s_prime_error=e_s, status=fit.status, simulations=fit.simulations,
            photons_simulated=fit.photons_simulated))
        print(f"  totals {setting}: {100 * e_a:+.2f}% / {100 * e_s:+.2f}%, {fit.seconds:.1f} s, {fit.simulations} sims",
              flush=True)
    return rows


def _band_stats(model, model_se, data, data_se, r_edges):
    """Per band of ``BANDS_MM``: median |model / data - 1| and mean z over bins with data > 0."""
    r_mid = 0.5 * (r_edges[:-1] + r_edges[1:])
    out = {}
    for lo, hi in BANDS_MM:
        sel = (r_mid >= lo) & (r_mid < hi) & (data > 0) & (np.arange(data.size) < data.size - 1)
        if not np.any(sel):
            continue
        z = (model[sel] - data[sel]) / np.hypot(model_se[sel], data_se[sel])
        out[f"{lo:g}-{hi:g} mm"] = {"median_rel_error": float(np.median(np.abs(model[sel] / data[sel] - 1.0))),
                                    "mean_z": float(np.mean(z)), "bins": int(sel.sum())}
    return out


def _ess_and_profile(cfg):
    import jax.numpy as jnp

    from fitting.replay_fit import CAP_OPTICAL, poisson_stderr
    from jaxsss.mc.replay import record, replay

    summary = {}
    for name in cfg["cases"]:
        case = read_mcml_csv(name)
        area = np.pi * np.diff(case.r_edges**2)
        sa, ssp = _truth(case)
        truth = mcml_stack(case)
        sa_all = jnp.asarray(truth.sigma_a)
        ssp_all = jnp.asarray(truth.sigma_s * (1.0 - truth.g))
        max_path = CAP_OPTICAL / sa if truth.is_half_space else float("inf")
        item = {}
        for label, factor in (("reference at truth", 1.0), ("reference sigma_s' -5%", 0.95)):
            sample = record(mcml_stack(case, (1.0, factor)), cfg["ess_photons"], r_edges=case.r_edges, seed=3,
                            max_path=max_path)
            est = replay(sample, sa_all, ssp_all)
            bands = {}
            for side in ("R_r", "T_r") if not truth.is_half_space else ("R_r",):
                d = getattr(case, side)
                bands[side] = _band_stats(np.asarray(getattr(est, side)), np.asarray(getattr(est, side + "_stderr")),
                                          d, poisson_stderr(d, case.photons, area), case.r_edges)
            item[label] = {"bands": bands, "recording_seconds": float(sample.seconds),
                           "events_per_photon": float(sample.events) / cfg["ess_photons"], "capped": sample.capped,
                           "cap_bound": float(est.cap_bound)}
            if factor == 1.0:
                ess = []
                for f in (0.8, 0.9, 0.95, 0.98, 1.0, 1.02, 1.05, 1.1, 1.2):
                    e = replay(sample, sa_all, ssp_all.at[-1].multiply(f))
                    mask = np.asarray(e.R_r) > 0
                    ess.append({"sigma_s_prime_factor": f, "ess_fraction": float(e.ess_fraction),
                                "median_bin_ess_fraction": float(np.median(np.asarray(e.R_r_ess_fraction)[mask]))})
                e = replay(sample, sa_all.at[-1].multiply(2.0), ssp_all)
                ess.append({"sigma_a_factor": 2.0, "ess_fraction": float(e.ess_fraction)})
                item["ess_vs_distance"] = ess
        summary[name] = item
        print(f"  ess/profile {name}: done", flush=True)
    return summary


def main(argv=None) -> int:
    from benchmarks._harness import parse_args, write_results

    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    cfg = CONFIG["quick" if args.quick else "full"]
    load_at_start = os.getloadavg()[0]
    t0 = time.perf_counter()
    rows = _fit_rows(cfg) + _totals_rows(cfg)
    summary = {"ess_and_profile": _ess_and_profile(cfg), "loadavg_1min_at_start": load_at_start,
               "photons_per_simulation": cfg["photons"], "start": START,
               "total_seconds": time.perf_counter() - t0}
    notes = [
        "seconds: wall time of each fit including its recordings and any compilation not yet cached (the first fit "
        "of a data shape compiles the model and solver, ~5-15 s on this machine; later fits reuse them)",
        "fits start at (1.3 sigma_a, 0.8 sigma_s') of the truth; data errors Poisson-like from MCML's photon count",
        "the machine is shared (2 cores, several other jobs): compare seconds within this run only",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="replay Monte Carlo fits: error vs seconds", connect=False)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
