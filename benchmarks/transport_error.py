"""Diffusion versus transport: the error of the dipole, the multipole and the white-MC model against the MC engine.

Grid (units: sigma_t' = sigma_a + sigma_s' = 1/mm, so l_u = 1 mm): reduced albedo alpha' = sigma_s'/sigma_t' in
{0.5, 0.9, 0.99, 0.999}, eta in {1.0, 1.4}, g in {0, 0.9} (the MC uses sigma_s = sigma_s'/(1-g)); a half-space
(dipole, white MC) and slabs of d = 2 and 5 l_u (multipole, R and diffuse T -- the unscattered beam is left out of the MC's T). Normal incidence. Normalisation: the MC and the
white MC are per *incident* photon (specular excluded); the diffusion profiles are per flux *entering*, so they are
multiplied by the entry transmittance ``1 - fresnel_reflectance(eta, 1)``.

Rows:
- ``dipole`` / ``multipole R`` / ``multipole T`` / ``white MC``: per case, the relative error of R(r) (model averaged
  over each MC annulus, 8-point Gauss-Legendre) in the bands of r/l_u [0,0.5), [0.5,1), [1,5), [5,20), [20,100): the
  largest |model/MC - 1| over bins whose MC relative stderr is below 5%, and the median signed error; ``error`` is
  the relative error of the total (Rd, or T); ``seconds`` the model's evaluation time (jitted, after compilation).
- ``MC``: the reference runs; ``error`` is the relative stderr of R_diffuse, ``seconds`` the run time.
- ``figure1``: hierarchical paper Fig. 1 -- l_d/l_s against the single-scattering albedo alpha = sigma_s/sigma_t from
  Eq. 11, ``1/sqrt(3(1-alpha)(1-g alpha))`` (g = 0.9), against the MC's mean exit distance of R_diffuse divided by
  l_s = 1/sigma_t (normal beam -- the paper used random directions); and the multiply-scattered fraction
  R_multiple/R_diffuse against alpha at eta = 1.3 for g = 0 and 0.9.
"""

from __future__ import annotations

import math
import sys
import time

import jax
import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc import Stack, load_white_table, simulate, white_mc_profile
from jaxsss.medium import Medium
from jaxsss.profiles import (
    dipole_profile,
    multipole_n_pairs,
    multipole_profile,
    multipole_totals,
)
from jaxsss.reflectance import medium_total_diffuse_reflectance

NAME = "transport_error"
BANDS = ((0.0, 0.5), (0.5, 1.0), (1.0, 5.0), (5.0, 20.0), (20.0, 100.0))
R_EDGES_LU = np.concatenate([[0.0], np.geomspace(0.02, 100.0, 48)])  # in units of l_u
LANES = 1024
CONFIG = {
    "quick": dict(albedos=(0.9, 0.99), etas=(1.4,), gs=(0.0,), slabs=(2.0,), budget=2e6, max_photons=20_000,
                  fig_albedos=(0.5, 0.9, 0.99), fig_budget=1e6),
    "full": dict(albedos=(0.5, 0.9, 0.99, 0.999), etas=(1.0, 1.4), gs=(0.0, 0.9), slabs=(2.0, 5.0), budget=1.5e7,
                 max_photons=400_000, fig_albedos=(0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999),
                 fig_budget=5e6),
}
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


def _events_estimate(albedo_single: float, g: float, eta: float, slab: float | None) -> float:
    """Rough events per photon (for photon budgets only): ~10/sqrt(1 - a) for a half-space, more for g > 0."""
    ev = 10.0 / math.sqrt(max(1.0 - albedo_single, 1e-6)) * (3.0 if g > 0.5 else 1.0) * (1.5 if eta > 1 else 1.0)
    if slab is not None:  # a walk across d transport lengths takes ~d^2 transport steps of 1/(1-g) events each
        ev = min(ev, 3.0 * (slab * slab + 2.0) / (1.0 - g))
    return ev


def _photons(budget, ev, max_photons):
    return int(min(max(budget / ev, 5_000), max_photons))


def _annulus_average(fn, edges):
    a, b = edges[:-1, None], edges[1:, None]
    r = 0.5 * (b - a) * _GL_X + 0.5 * (b + a)
    R = np.asarray(fn(r))
    return (R * r * _GL_W).sum(1) * (b - a)[:, 0] / (b[:, 0] ** 2 - a[:, 0] ** 2)


def _bands(model, mc, mc_err, edges, l_u):
    centres = np.sqrt(np.maximum(edges[:-1], 1e-300) * edges[1:]) / l_u
    centres[0] = 0.5 * edges[1] / l_u
    ok = (mc > 0) & (mc_err < 0.05 * mc)
    out = {}
    for lo, hi in BANDS:
        sel = ok & (centres >= lo) & (centres < hi)
        key = f"[{lo:g},{hi:g})"
        if sel.any():
            rel = model[sel] / mc[sel] - 1.0
            out[key] = {"max_abs": float(np.max(np.abs(rel))), "median": float(np.median(rel)), "bins": int(sel.sum())}
        else:
            out[key] = None
    return out


def _model_time(fn):
    return time_call(lambda: jax.block_until_ready(fn()), repeats=3).seconds


def run(quick: bool):
    cfg = CONFIG["quick" if quick else "full"]
    rows, cases, pending = [], [], []
    tables = {}
    for g in cfg["gs"]:
        for eta in cfg["etas"]:
            for alpha_p in cfg["albedos"]:
                for d in (None,) + tuple(cfg["slabs"]):
                    sigma_a, sigma_sp = 1.0 - alpha_p, alpha_p
                    sigma_s = sigma_sp / (1.0 - g)
                    a_single = sigma_s / (sigma_s + sigma_a)
                    ev = _events_estimate(a_single, g, eta, d)
                    photons = _photons(cfg["budget"], ev, cfg["max_photons"])
                    stack = (Stack.half_space(sigma_a, sigma_s, g, eta) if d is None
                             else Stack.slab(sigma_a, sigma_s, g, eta, d))
                    edges = R_EDGES_LU * 1.0  # l_u = 1 mm
                    res = simulate(stack, photons, seed=11, r_edges=edges, lanes=LANES, progress=False)
                    m = Medium(sigma_a, sigma_sp, eta=eta)
                    Ft = float(1.0 - fresnel_reflectance(eta, 1.0))
                    geom = "half-space" if d is None else f"slab d={d:g} l_u"
                    setting = f"{geom} a'={alpha_p} eta={eta} g={g}"
                    case = {"geometry": geom, "alpha_prime": alpha_p, "eta": eta, "g": g, "photons": photons,
                            "mc_seconds": res.seconds, "R_mc": res.R_diffuse, "R_mc_stderr": res.R_diffuse_stderr,
                            "T_mc": res.T, "T_mc_stderr": res.T_stderr, "T_unscattered": res.T_unscattered,
                            "models": {}}
                    rows.append(make_row(NAME, "MC", setting, res.R_diffuse_stderr / res.R_diffuse,
                                         "relative stderr of R_diffuse", res.seconds, res.compile_seconds,
                                         photons=photons, R=res.R_diffuse, T=res.T))
                    if d is None:
                        fn = lambda r, m=m, Ft=Ft: Ft * dipole_profile(r, m)
                        prof = _annulus_average(fn, edges)
                        Rd = Ft * float(medium_total_diffuse_reflectance(m))
                        models = {"dipole": (prof, Rd, None, lambda r=edges[1:], fn=fn: fn(r))}
                        if (g, eta) in [(0.0, 1.0), (0.0, 1.4), (0.9, 1.0), (0.9, 1.4)]:
                            # Evaluated after all MC runs (the tables may still be regenerating meanwhile).
                            pending.append((case, res, setting, g, eta, sigma_a, sigma_sp, sigma_s, edges))
                    else:
                        n_pairs = multipole_n_pairs(edges[1:], m, d)
                        fR = lambda r, m=m, d=d, k=n_pairs: Ft * multipole_profile(r, m, d, n_pairs=k)[0]  # noqa
                        fT = lambda r, m=m, d=d, k=n_pairs: Ft * multipole_profile(r, m, d, n_pairs=k)[1]  # noqa
                        Rt, Tt = (Ft * float(x) for x in multipole_totals(m, d))
                        models = {"multipole R": (_annulus_average(fR, edges), Rt, None, lambda r=edges[1:], fR=fR: fR(r)),
                                  "multipole T": (_annulus_average(fT, edges), None, Tt, lambda r=edges[1:], fT=fT: fT(r))}
                    _score(rows, case, res, setting, edges, models)
                    cases.append(case)
                    worst = {k: v["total_rel_error"] for k, v in case["models"].items()}
                    print(f"  {setting:40s} {photons:>7d} ph {res.seconds:6.1f} s  R={res.R_diffuse:.4f}"
                          f"+-{res.R_diffuse_stderr:.1e}  total errors "
                          + " ".join(f"{k}={v:+.3f}" for k, v in worst.items() if v is not None), flush=True)
    fig = figure1(cfg)
    for case, res, setting, g, eta, sigma_a, sigma_sp, sigma_s, edges in pending:
        if (g, eta) not in tables:
            tables[(g, eta)] = _load_table(g, eta)
        tab = tables[(g, eta)]
        fw = lambda r, tab=tab, sa=sigma_a, ssp=sigma_sp: white_mc_profile(r, sa, ssp, tab)
        prof_w = _annulus_average(fw, edges)
        rr = np.geomspace(1e-6, 3e3 / sigma_s, 20_000)
        Rw = float(np.trapezoid(2 * np.pi * rr * rr * np.asarray(fw(rr)), np.log(rr)))
        case["white_mc_valid"] = bool((sigma_a / sigma_s) >= tab.valid_mu_min)
        _score(rows, case, res, setting, edges, {"white MC": (prof_w, Rw, None, lambda r=edges[1:], fw=fw: fw(r))})
        print(f"  {setting:40s} white MC total error {case['models']['white MC']['total_rel_error']:+.4f}"
              f" (valid: {case['white_mc_valid']})", flush=True)
    return rows, cases, fig


def _load_table(g, eta, wait_seconds=1200.0):
    """The shipped white-MC table; while ``python -m jaxsss.mc.white --regenerate`` is still writing it (the two can
    run side by side), wait for it up to ``wait_seconds``."""
    t0 = time.perf_counter()
    while True:
        try:
            return load_white_table(g, eta)
        except ValueError:
            if time.perf_counter() - t0 > wait_seconds:
                raise
            time.sleep(10.0)


def _score(rows, case, res, setting, edges, models):
    for name, (prof, Rtot, Ttot, timed) in models.items():
        is_T = name.endswith(" T")
        if is_T:  # diffuse transmittance: the unscattered beam (order 0, at r = 0) left out
            mc = res.T_r_order[1] + res.T_r_order[2]
            mc_err = np.hypot(res.T_r_order_stderr[1], res.T_r_order_stderr[2])
        else:
            mc, mc_err = res.R_r, res.R_r_stderr
        bands = _bands(prof, mc, mc_err, edges, 1.0)
        if is_T:
            T_diffuse = res.T - res.T_unscattered
            tot_err = Ttot / T_diffuse - 1.0 if T_diffuse > 0 else None
        else:
            tot_err = Rtot / res.R_diffuse - 1.0
        case["models"][name] = {"bands": bands, "total_rel_error": tot_err,
                                "total": Ttot if is_T else Rtot}
        rows.append(make_row(NAME, name, setting, None if tot_err is None else abs(tot_err),
                             "|total/total_MC - 1| (Rd, or T for 'multipole T')", _model_time(timed),
                             None, bands=bands, signed_total_error=tot_err))


def figure1(cfg):
    """Hierarchical paper Fig. 1: l_d/l_s (Eq. 11 vs MC, g = 0.9, eta = 1) and the multiple-scattering fraction
    (eta = 1.3, g = 0 and 0.9), normal incidence, sigma_t = 1/mm (l_s = 1 mm)."""
    out = {"ld_over_ls": [], "multiple_fraction": []}
    for a in cfg["fig_albedos"]:
        g = 0.9
        ev = _events_estimate(a, g, 1.0, None)
        res = simulate(Stack.half_space(1.0 - a, a, g, 1.0), _photons(cfg["fig_budget"], ev, 200_000), seed=5,
                       lanes=LANES, progress=False)
        eq11 = 1.0 / math.sqrt(3.0 * (1.0 - a) * (1.0 - g * a))
        out["ld_over_ls"].append({"albedo": a, "eq11": eq11, "mc": res.mean_exit_radius,
                                  "mc_stderr": res.mean_exit_radius_stderr, "photons": res.photons})
        for g2 in (0.0, 0.9):
            ev = _events_estimate(a, g2, 1.3, None)
            res = simulate(Stack.half_space(1.0 - a, a, g2, 1.3), _photons(cfg["fig_budget"], ev, 200_000), seed=6,
                           lanes=LANES, progress=False)
            out["multiple_fraction"].append({"albedo": a, "g": g2, "fraction": res.R_multiple / res.R_diffuse,
                                             "R_diffuse": res.R_diffuse, "photons": res.photons})
        print(f"  fig1 a={a}: l_d/l_s Eq.11 {eq11:.2f}, MC {out['ld_over_ls'][-1]['mc']:.2f}; multiple fraction "
              + ", ".join(f"g={x['g']}: {x['fraction']:.3f}" for x in out["multiple_fraction"][-2:]), flush=True)
    return out


def plot_figure1(fig, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    ld = fig["ld_over_ls"]
    al = np.array([x["albedo"] for x in ld])
    x = -np.log10(1 - al)
    a1.plot(x, [p["eq11"] for p in ld], "-", label="Eq. 11")
    a1.errorbar(x, [p["mc"] for p in ld], yerr=[p["mc_stderr"] for p in ld], fmt="o", label="MC (normal beam)")
    a1.set_xlabel("-log10(1 - albedo)")
    a1.set_ylabel("l_d / l_s  (g = 0.9)")
    a1.set_yscale("log")
    a1.legend()
    for g in (0.0, 0.9):
        pts = [p for p in fig["multiple_fraction"] if p["g"] == g]
        a2.plot(-np.log10(1 - np.array([p["albedo"] for p in pts])), [p["fraction"] for p in pts], "o-",
                label=f"g = {g}")
    a2.set_xlabel("-log10(1 - albedo)")
    a2.set_ylabel("multiply scattered fraction of R_diffuse (eta = 1.3)")
    a2.legend()
    f.suptitle("Hierarchical paper Fig. 1, reproduced with jaxsss.mc")
    f.tight_layout()
    f.savefig(path, dpi=100)
    plt.close(f)


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    t0 = time.perf_counter()
    rows, cases, fig = run(args.quick)
    summary = {"cases": cases, "figure1": fig, "wall_seconds": time.perf_counter() - t0}
    notes = ["models are per incident photon: diffusion profiles times 1 - F(eta, 1)",
             "bands: max |model/MC - 1| over bins with MC relative stderr < 5%; r in units of l_u = 1/sigma_t'",
             "figure1: normal-beam MC (the paper used random directions); l_s = 1/sigma_t"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="diffusion vs transport: |total error| vs model seconds",
                                        connect=False)
    fig_path = args.out / f"{NAME}{args.tag}_figure1.png"
    plot_figure1(fig, fig_path)
    print(f"wrote {json_path}, {png_path} and {fig_path} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
