"""White Monte Carlo for any (n, g): the family's interpolation error at off-grid (n, g), and against MCML.

What is measured (issue 15, item 1; acceptance "band medians within 2% of a direct simulation from 0.1 l_u to
10 l_d"). The family (:mod:`jaxsss.mc.white_family`) interpolates ``log R`` of its nodes' annulus averages in ``g``
and ``n``. Its error is measured where it has no node:

- ``offgrid``: held-out white runs at ``(n, g)`` between the nodes -- simulated like a node (same engine, same
  grid, other seeds; ``jaxsss/mc/data/offgrid``) or re-binned from the single-pair tables of :mod:`jaxsss.mc.white`
  (n = 1.33, g = 0 and 0.9: 10^6 photons each). Each is the exact answer (up to its Monte Carlo noise) for every
  absorption, by the same reweighting; it is compared with the family's interpolated annulus averages at
  ``mu' = sigma_a / sigma_s'`` in ``MU_PRIMES``. Per band of radius (0.1-1 l_u, 1 l_u-1 l_d, 1-3 l_d, 3-10 l_d): the
  median signed relative error (the row's ``error`` is the largest ``|median|`` over the bands), and beside it the
  median relative standard error of the reference and of the nodes (noise that a median can only partly remove).
- ``direct``: one absorbing engine run (real absorption, no reweighting) at an off-grid ``(n, g)`` against the family
  profile averaged over the same annuli.
- ``leave-one-out``: a node predicted by the family without it (the grid's spacing doubled locally): what a coarser
  grid would cost, the measured ground for the spacing chosen.
- ``mcml``: each half-space ``.mco`` file of ``shared/reference/mcml`` (read with :func:`fitting.read_mco`): the family's
  profile at the file's coefficients, averaged over the file's annuli, against the file's ``Rd_r``; band medians as
  above, noise from the photon count (:func:`fitting.mco.bin_standard_errors`).

``seconds``: evaluating one profile (the file's radii, or the 91 grid bins) after compilation; the reference's
``simulation_seconds`` (the engine run a direct answer costs) is an extra key.

Writes ``white_interpolation.json``, ``white_interpolation.png`` (the harness's error against seconds) and
``white_interpolation_bands.png`` (band medians per case, with the reference's noise as bars).

``--quick``: two off-grid cases, two absorptions, two MCML files, no leave-one-out, a small direct run.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results
from jaxsss.mc import white_family as wf

NAME = "white_interpolation"
MU_PRIMES = (0.003, 0.01, 0.03, 0.1, 0.3)
BAND_NAMES = ("0.1-1 l_u", "1 l_u-1 l_d", "1-3 l_d", "3-10 l_d")
OFFGRID_DIR = Path(wf.__file__).resolve().parent / "data" / "offgrid"
WHITE_DIR = Path(wf.__file__).resolve().parent / "data"
MCML_DIR = Path(__file__).resolve().parents[1] / ".." / ".." / "shared" / "reference" / "mcml"
CONFIG = {
    "quick": {"cases": 2, "mu": (0.01, 0.1), "loo": False, "mcml": 2, "direct_photons": 20_000},
    "full": {"cases": None, "mu": MU_PRIMES, "loo": True, "mcml": None, "direct_photons": 2_000_000},
}


def _mcml_dir() -> Path:
    for cand in (MCML_DIR, Path("/work/shared/reference/mcml")):
        if cand.exists():
            return cand.resolve()
    raise FileNotFoundError("shared/reference/mcml not found beside the repository")


def offgrid_cases() -> list[tuple[str, dict]]:
    """Held-out tables: ``(label, node table)``; simulated off-grid nodes first, then the re-binned 10^6-photon ones."""
    out = []
    for p in sorted(OFFGRID_DIR.glob("node_*.npz")):
        t = wf.load_node(p)
        out.append((f"g={t['g']:g} n={t['n']:g} ({t['photons']:.0e} photons)", t))
    for g, n in ((0.0, 1.33), (0.9, 1.33)):
        p = WHITE_DIR / f"white_g{g:.2f}_n{n:.2f}.npz"
        try:
            t = wf.node_from_white_table(p)
        except ValueError:  # its pathlength grid is not on the common one
            continue
        out.append((f"g={g:g} n={n:g} (white table, {t['photons']:.0e} photons)", t))
    return out


def bands(mu: float, centres: np.ndarray) -> list[np.ndarray]:
    """Masks of the radial bands (transport units: ``l_u = 1 / (1 + mu')``, ``l_d = 1 / sqrt(3 mu' (1 + mu'))``)."""
    l_u = 1.0 / (1.0 + mu)
    l_d = 1.0 / np.sqrt(3.0 * mu * (1.0 + mu))
    lims = ((0.1 * l_u, l_u), (l_u, l_d), (l_d, 3 * l_d), (3 * l_d, 10 * l_d))
    return [(centres >= a) & (centres < b) for a, b in lims]


def _rel_stderr(t: dict, mu: float, valid: int) -> np.ndarray:
    """Relative standard error of a node's annulus averages at ``mu'`` (simulated cells; the tail taken as exact)."""
    p = t["pathlength_edges"]
    w = np.exp(-mu * 0.5 * (p[1:] + p[:-1]))
    R = t["R"].astype(np.float64)
    E = t["R_stderr"].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.sqrt(((E * w) ** 2).sum(1)) / (R * w).sum(1)
    rel[valid:] = np.nan
    return rel


def band_stats(err: np.ndarray, noise: np.ndarray, masks) -> dict:
    out = {}
    for name, m in zip(BAND_NAMES, masks):
        ok = m & np.isfinite(err)
        if not ok.any():
            continue
        out[name] = {"median": float(np.median(err[ok])), "median_abs": float(np.median(np.abs(err[ok]))),
                     "noise": float(np.nanmedian(noise[ok])) if np.isfinite(noise[ok]).any() else None,
                     "bins": int(ok.sum())}
    return out


def _row_error(stats: dict) -> float:
    return max(abs(s["median"]) for s in stats.values())


MERGE = 2  # grid bins per compared annulus: 10 per decade (the grid's 20 per decade halve the noise per point)


def coarse(edges: np.ndarray, *values: np.ndarray, rel: np.ndarray | None = None):
    """Merge the grid's annuli (after the first, ``[0, 0.01)``) ``MERGE`` at a time: geometric centres, area-weighted
    averages of each of ``values`` (linear, ``(M,)``), and the merged relative standard error from ``rel`` (of the
    first of ``values``). A merged annulus is NaN where any part is."""
    area = np.pi * np.diff(edges**2)
    M = len(area)
    groups = [np.array([0])] + [np.arange(i, min(i + MERGE, M)) for i in range(1, M, MERGE)]
    lo = np.array([edges[gr[0]] for gr in groups])
    hi = np.array([edges[gr[-1] + 1] for gr in groups])
    centres = np.where(lo > 0, np.sqrt(lo * hi), 0.5 * hi)
    out = [np.array([np.sum(v[gr] * area[gr]) / np.sum(area[gr]) for gr in groups]) for v in values]
    noise = None
    if rel is not None:
        v = values[0]
        noise = np.array([np.sqrt(np.sum((area[gr] * v[gr] * rel[gr]) ** 2)) / np.sum(area[gr] * v[gr])
                          for gr in groups])
    return centres, out, noise


def compare_node(fam, t: dict, mus, method: str, label: str, seconds_per_profile: float) -> list[dict]:
    """Rows comparing the family at ``(t["g"], t["n"])`` with the node table ``t`` (exact reweighting), on annuli of
    ``MERGE`` grid bins (:func:`coarse`)."""
    ref = wf.family_from_nodes({(t["g"], t["n"]): t}, (t["g"],), (t["n"],))
    edges = np.asarray(ref.r_edges)
    valid = int(ref.valid[0, 0])
    rows = []
    for mu in mus:
        R_ref = np.exp(np.asarray(wf.log_bin_profile(mu, t["g"], t["n"], ref)))
        R_fam = np.exp(np.asarray(wf.log_bin_profile(mu, t["g"], t["n"], fam)))
        R_ref[valid:] = np.nan  # the reference's own extrapolation is not a reference
        centres, (a, b), noise = coarse(edges, R_ref, R_fam, rel=_rel_stderr(t, mu, valid))
        err = b / a - 1.0
        stats = band_stats(err, noise, bands(mu, centres))
        rows.append(make_row(NAME, method, f"{label}, mu'={mu:g}", _row_error(stats),
                             "max over bands of |median relative error| (annuli of 10 per decade)",
                             seconds_per_profile, None, g=t["g"], n=t["n"], mu_prime=mu, bands=stats,
                             simulation_seconds=float(t["seconds"]), photons=int(t["photons"])))
    return rows


def leave_one_out(nodes: dict, mus, seconds: float) -> list[dict]:
    """Each inner node predicted by the family built without its g (or its n) value."""
    rows = []
    for axis, values in (("g", wf.G_NODES), ("n", wf.N_NODES)):
        for k in range(1, len(values) - 1):
            gs = [g for g in wf.G_NODES if not (axis == "g" and g == values[k])]
            ns = [n for n in wf.N_NODES if not (axis == "n" and n == values[k])]
            fam = wf.family_from_nodes(nodes, gs, ns)
            for other in (wf.N_NODES if axis == "g" else wf.G_NODES)[:: 2 if axis == "g" else 1]:
                key = (values[k], other) if axis == "g" else (other, values[k])
                lbl = f"drop {axis}={values[k]:g}: g={key[0]:g} n={key[1]:g}"
                rows += compare_node(fam, nodes[key], mus, "leave-one-out", lbl, seconds)
    return rows


def direct_rows(fam, photons: int) -> list[dict]:
    """An absorbing engine run at an off-grid (n, g) against the family's annulus averages."""
    from benchmarks.transport_error import _annulus_average
    from jaxsss.mc import Stack, simulate

    g, n, sa, ssp = 0.7, 1.35, 0.1, 1.0  # mu' = 0.1, between nodes on both axes
    l_u, l_d = 1.0 / (sa + ssp), 1.0 / np.sqrt(3 * sa * (sa + ssp))
    edges = np.geomspace(0.1 * l_u, 10 * l_d, 25)
    res = simulate(Stack.half_space(sa, ssp / (1 - g), g, n), photons, seed=4242, r_edges=edges, progress=False)
    timing = time_call(lambda: _annulus_average(lambda r: wf.white_family_profile(r, sa, ssp, g, n, fam), edges),
                       repeats=3)
    model = np.asarray(timing.output)
    err = model / res.R_r - 1.0
    noise = res.R_r_stderr / res.R_r
    centres = np.sqrt(edges[1:] * edges[:-1]) * ssp
    stats = band_stats(err, noise, bands(sa / ssp, centres))
    return [make_row(NAME, "direct", f"engine run g={g:g} n={n:g} mu'={sa / ssp:g} ({photons:.0e} photons)",
                     _row_error(stats), "max over bands of |median relative error| (annulus averages)",
                     timing.seconds, timing.compile_seconds, g=g, n=n, mu_prime=sa / ssp, bands=stats,
                     simulation_seconds=res.seconds, photons=photons)]


def mcml_rows(fam, limit) -> list[dict]:
    from fitting.mco import bin_standard_errors, read_mco

    rows = []
    files = sorted(_mcml_dir().glob("halfspace_*.mco"))
    for path in files[:limit]:
        run = read_mco(path)
        lay = run.layers[0]
        sa, ssp, g, n = lay.mua, lay.mus * (1.0 - lay.g), lay.g, lay.n / run.n_above
        if not (wf.G_NODES[0] <= g <= wf.G_NODES[-1] and wf.N_NODES[0] <= n <= wf.N_NODES[-1]):
            continue
        edges = np.concatenate([run.r_lo[:1], run.r_hi])
        from benchmarks.transport_error import _annulus_average

        timing = time_call(lambda: _annulus_average(lambda r: wf.white_family_profile(r, sa, ssp, g, n, fam), edges),
                           repeats=3)
        model = np.asarray(timing.output)
        se = np.asarray(bin_standard_errors(run, run.Rd_r))
        with np.errstate(divide="ignore", invalid="ignore"):
            err = np.where(run.Rd_r > 0, model / run.Rd_r - 1.0, np.nan)
            noise = np.where(run.Rd_r > 0, se / run.Rd_r, np.nan)
        centres = 0.5 * (run.r_lo + run.r_hi) * ssp
        stats = band_stats(err, noise, bands(sa / ssp, centres))
        rows.append(make_row(NAME, "mcml", f"{path.stem} (sigma_a={sa:g}, sigma_s'={ssp:g}, g={g:g}, n={n:g})",
                             _row_error(stats), "max over bands of |median relative error| (MCML annuli)",
                             timing.seconds, timing.compile_seconds, g=g, n=n, mu_prime=sa / ssp, bands=stats,
                             simulation_seconds=float(run.seconds), photons=int(run.photons), file=path.name))
    return rows


def plot(rows, path: Path) -> None:
    """Band medians per case (one colour per held-out case, dropped node or MCML file; one point per absorption),
    with the reference's median relative stderr as error bars, and the +-2% acceptance band shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    for ax, method in zip(axes, ("offgrid", "leave-one-out", "mcml")):
        sel = [r for r in rows if r["method"] == method or (method == "offgrid" and r["method"] == "direct")]
        groups = list(dict.fromkeys(r["setting"].split(", mu'")[0].split(":")[0] for r in sel))
        colours = plt.cm.tab10.colors
        for i, r in enumerate(sel):
            grp = r["setting"].split(", mu'")[0].split(":")[0]
            k = groups.index(grp)
            xs = [BAND_NAMES.index(b) + 0.8 * (i / max(len(sel), 1) - 0.4) for b in r["bands"]]
            ys = [100 * s["median"] for s in r["bands"].values()]
            es = [100 * (s["noise"] or 0.0) for s in r["bands"].values()]
            first = all(q["setting"].split(", mu'")[0].split(":")[0] != grp for q in sel[:i])
            ax.errorbar(xs, ys, yerr=es, fmt="s" if r["method"] == "direct" else "o", ms=3, lw=0.6,
                        color=colours[k % 10], label=grp if first else None)
        ax.axhspan(-2, 2, color="0.9", zorder=0)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xticks(range(len(BAND_NAMES)), BAND_NAMES, fontsize=8)
        ax.set_ylabel("band median of family / reference - 1 (%)")
        ax.set_title({"offgrid": "off-grid (n, g): held-out white runs (o), an absorbing run (s)",
                      "leave-one-out": "a node predicted without its g or n (spacing x2 there)",
                      "mcml": "MCML 1.2.2 half-spaces at the files' coefficients"}[method], fontsize=9)
        ax.set_ylim(-10, 10)
        if groups:
            ax.legend(fontsize=5, ncol=2)
    fig.suptitle("White MC family: band medians at mu' = sigma_a / sigma_s' in " + ", ".join(f"{m:g}" for m in
                 sorted({r["mu_prime"] for r in rows if r["method"] != "mcml"})) + " (bars: median relative stderr "
                 "of the reference per annulus)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(quick: bool = False) -> dict:
    cfg = CONFIG["quick" if quick else "full"]
    t0 = time.perf_counter()
    fam = wf.load_white_family()
    rows = []
    cases = offgrid_cases()
    if cfg["cases"]:
        cases = cases[: cfg["cases"]]
    timing = time_call(lambda: wf.log_bin_profile(0.01, 0.7, 1.3, fam), repeats=3)
    for label, t in cases:
        rows += compare_node(fam, t, cfg["mu"], "offgrid", label, timing.seconds)
    rows += direct_rows(fam, cfg["direct_photons"])
    if cfg["loo"]:
        nodes = {(g, n): wf.load_node(wf.FAMILY_DIR / wf.node_file(g, n)) for g in wf.G_NODES for n in wf.N_NODES}
        rows += leave_one_out(nodes, cfg["mu"], timing.seconds)
    rows += mcml_rows(fam, cfg["mcml"])
    off = [r for r in rows if r["method"] in ("offgrid", "direct")]
    summary = {
        "grid_g": list(wf.G_NODES), "grid_n": list(wf.N_NODES),
        "offgrid_worst_band_median": max(r["error"] for r in off),
        "offgrid_within_2pct": all(r["error"] <= 0.02 for r in off),
        "mcml_worst_band_median": max((r["error"] for r in rows if r["method"] == "mcml"), default=None),
        "seconds_total": time.perf_counter() - t0,
    }
    return {"rows": rows, "summary": summary}


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    out = run(quick=args.quick)
    name = NAME + args.tag
    write_results(name, out["rows"], args.out, summary=out["summary"], quick=args.quick,
                  title="white MC family: worst band median vs evaluation seconds")
    plot(out["rows"], Path(args.out) / f"{name}_bands.png")
    for r in out["rows"]:
        b = "  ".join(f"{k}: {100 * v['median']:+.2f}% (noise {100 * (v['noise'] or 0):.1f}%)"
                      for k, v in r["bands"].items())
        print(f"{r['method']:14s} {r['setting']:60s} worst {100 * r['error']:.2f}%  {b}")
    print(out["summary"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
