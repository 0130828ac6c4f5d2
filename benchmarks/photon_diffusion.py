"""Photon diffusion (Donner and Jensen 2007) against Monte Carlo: oblique beams, near the source, thin slabs, an edge.

Every case compares the new models with the classic dipole (or multipole) and with the Monte Carlo *multiply
scattered* exitance (scattering order >= 2: the diffusion sources model the light scattered after the first
interaction, DESIGN.md trap 6), per incident photon. Diffusion profiles are per flux entering and are multiplied by
the entry transmittance ``1 - F(eta, cos theta_i)``. Units: ``sigma_t' = 1/mm`` (``l_u = 1`` mm), ``g = 0``
(``sigma_s = sigma_s'``), ``eta = 1.3``.

Cases (``case`` in every row):

- ``oblique <angle> a'=<albedo>`` (paper Fig. 2): pencil beam at 0, 45 and 80 degrees on a half-space; MC x-y exit
  histogram ``R_xy_order[2]`` (0.5 mm cells). Models averaged over each cell (Gauss-Legendre 8x8; cells touching
  the point of entry are split there). ``error`` = relative L2 error ``||model - MC|| / ||MC||`` over cells whose
  MC relative stderr is below 10%; extras: the centroid ``x`` of the exitance over the grid (the shift) and the
  asymmetry ``(E[x > 0] - E[x < 0]) / E`` on the centre row ``|y| < 0.25`` mm, model and MC.
- ``near_source a'=<albedo>`` (paper Fig. 3): normal incidence, radial ``R_r_order[2]`` (annulus averages);
  ``error`` = relative L2 error over annuli with ``r < 2 l_u``; the full range is an extra.
- ``slab d=<d> a'=<albedo>``: diffuse (order >= 2) transmittance ``T(r)`` of a thin slab, relative L2 over annuli
  ``r < 5 l_u``: dipole (``n_pairs = 0``), multipole (source at ``l_u``), and the photon-diffusion multipole (sources
  along the beam inside the slab, Eq. 8 quadrature, evaluated through Eq. 15 at ``gamma = pi``).
- ``edge a=<a>``: beam at distance ``a`` from a right-angled edge (quarter-space MC, :mod:`jaxsss.mc.edge`); side
  face histogram over ``(z, y)``; relative L2 error: the dipole (JMLH01, ``r = |x_o - x_i|``), the quadpole (source
  at ``l_u``), the photon-diffusion quadpole (beam sources, Eq. 15 at ``gamma = pi/2``) and, to isolate what the
  quadpole's second boundary adds, the same beam sources with the side face's dipole alone.

Models named ``PD kappa=<k>`` use the Eq. 8 quadrature with the Eq. 9 coefficient ``k``; ``PD sampled N`` the paper's
sampled estimator with N sources. ``seconds`` is the model's evaluation on the case's grid after compilation
(``MC`` rows: the MC run). The summary's ``kappa`` block is the evidence for the choice of Eq. 9's coefficient: the
mean relative L2 error of each choice over the oblique and near-source cases.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc import Stack, simulate
from jaxsss.mc.edge import simulate_edge
from jaxsss.medium import Medium
from jaxsss.profiles import (
    attenuated_dipole_profile,
    beam_integral,
    blended_exitance,
    dipole_exitance,
    dipole_profile,
    multipole_n_pairs,
    multipole_profile,
    oblique_profile,
    oblique_profile_sampled,
    quadpole_profile,
)
from jaxsss.profiles.oblique import (
    DEFAULT_KAPPA,
    KAPPA_COEFFICIENTS,
    attenuation_kernel,
)

NAME = "photon_diffusion"
ETA = 1.3
KAPPAS = tuple(KAPPA_COEFFICIENTS)
CONFIG = {
    "quick": dict(albedos=(0.99,), angles=(0.0, 45.0, 80.0), photons=40_000, slabs=(1.0,), edges=(1.0,),
                  edge_photons=40_000, sampled=(16,)),
    "full": dict(albedos=(0.9, 0.99), angles=(0.0, 45.0, 80.0), photons=1_000_000, slabs=(0.5, 2.0),
                 edges=(1.0, 3.0), edge_photons=1_000_000, sampled=(16, 256)),
}
X_EDGES = np.linspace(-6.25, 10.25, 34)  # mm; 0.5 mm cells, the entry point at a cell centre
Y_EDGES = np.linspace(-4.25, 4.25, 18)
R_EDGES = np.concatenate([[0.0], np.geomspace(0.05, 20.0, 40)])
SIDE_Z = np.linspace(0.0, 8.0, 17)
SIDE_Y = np.linspace(-4.25, 4.25, 18)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


# --- Averaging models over MC bins ----------------------------------------------------------------------------------
def _cells(x_edges, y_edges, x_split=0.0, y_split=0.0):
    """Sub-rectangles of the grid (split at the singular point) with their cell index and Gauss points/weights."""
    rects = []
    for i in range(x_edges.size - 1):
        for j in range(y_edges.size - 1):
            xs = [x_edges[i], x_edges[i + 1]]
            ys = [y_edges[j], y_edges[j + 1]]
            if xs[0] < x_split < xs[1]:
                xs.insert(1, x_split)
            if ys[0] < y_split < ys[1]:
                ys.insert(1, y_split)
            for a, b in zip(xs[:-1], xs[1:]):
                for c, d in zip(ys[:-1], ys[1:]):
                    rects.append((i, j, a, b, c, d))
    r = np.array(rects)
    a, b, c, d = (r[:, k, None, None] for k in range(2, 6))
    X = 0.5 * (b - a) * _GL_X[:, None] + 0.5 * (a + b)
    Y = 0.5 * (d - c) * _GL_X[None, :] + 0.5 * (c + d)
    W = 0.25 * (b - a) * (d - c) * _GL_W[:, None] * _GL_W[None, :]
    X, Y = np.broadcast_arrays(X, Y)
    return r[:, 0].astype(int), r[:, 1].astype(int), X, Y, np.broadcast_to(W, X.shape)


def _cell_average(values, cells, shape, x_edges, y_edges):
    i, j, _, _, W = cells
    acc = np.zeros(shape)
    np.add.at(acc, (i, j), np.sum(np.asarray(values) * W, axis=(1, 2)))
    return acc / np.outer(np.diff(x_edges), np.diff(y_edges))


def _annulus_points(edges):
    a, b = edges[:-1, None], edges[1:, None]
    r = 0.5 * (b - a) * _GL_X + 0.5 * (b + a)
    w = 2 * np.pi * r * 0.5 * (b - a) * _GL_W / (np.pi * (b**2 - a**2))
    return r, w


def _rel_l2(model, mc, err, sel=None):
    ok = (mc > 0) & (err < 0.1 * mc)
    if sel is not None:
        ok &= sel
    return float(np.sqrt(np.sum((model[ok] - mc[ok]) ** 2) / np.sum(mc[ok] ** 2))), int(ok.sum())


def _timed(fn, *args):
    t = time_call(fn, *args, repeats=3)
    return np.asarray(t.output), t.seconds, t.compile_seconds


def _row(rows, case, model, error, metric, seconds, compile_seconds, **extra):
    rows.append(make_row(NAME, model, case, error, metric, seconds, compile_seconds, case=case, model=model,
                         **extra))
    err = "n/a" if error is None else f"{error:.4f}"
    print(f"  {case:28s} {model:28s} error {err:>8s}  {seconds * 1e3:8.2f} ms", flush=True)


# --- Cases --------------------------------------------------------------------------------------------------------
def oblique_cases(cfg, rows, kappa_errors, profiles):
    cells = _cells(X_EDGES, Y_EDGES)
    shape = (X_EDGES.size - 1, Y_EDGES.size - 1)
    xc = 0.5 * (X_EDGES[1:] + X_EDGES[:-1])
    centre_row = np.argmin(np.abs(0.5 * (Y_EDGES[1:] + Y_EDGES[:-1])))
    r_pts, r_w = _annulus_points(R_EDGES)
    for alpha_p in cfg["albedos"]:
        m = Medium(1.0 - alpha_p, alpha_p, ETA)
        for angle in cfg["angles"]:
            case = f"oblique {angle:g}deg a'={alpha_p}"
            res = simulate(Stack.half_space(1.0 - alpha_p, alpha_p, 0.0, ETA), cfg["photons"], seed=7,
                           angle_deg=angle, xy_edges=(X_EDGES, Y_EDGES), r_edges=R_EDGES if angle == 0 else None,
                           lanes=1024, progress=False)
            mc, mc_err = res.R_xy_order[2], res.R_xy_order_stderr[2]
            _row(rows, case, "MC", res.R_multiple_stderr / res.R_multiple, "relative stderr of R_multiple",
                 res.seconds, res.compile_seconds, photons=res.photons, R_multiple=res.R_multiple)
            theta = math.radians(angle)
            Ft = float(1.0 - fresnel_reflectance(ETA, math.cos(theta)))
            X, Y = jnp.asarray(cells[2]), jnp.asarray(cells[3])
            models = {"dipole": jax.jit(lambda X, Y: Ft * dipole_profile(jnp.hypot(X, Y), m))}
            for k in KAPPAS:
                models[f"PD kappa={k}"] = jax.jit(lambda X, Y, k=k: Ft * oblique_profile(X, Y, m, theta, kappa=k))
            if angle == 45.0:
                for n in cfg["sampled"]:
                    models[f"PD sampled {n}"] = jax.jit(lambda X, Y, n=n: Ft * oblique_profile_sampled(
                        X, Y, m, theta, jax.random.key(3), n))

            def stats(E):
                # Over the window |x| < 6.25 mm, symmetric about the point of entry.
                sym = np.abs(xc) < 6.25
                cell = np.outer(np.diff(X_EDGES), np.diff(Y_EDGES))[sym]
                Ew = E[sym]
                row = Ew[:, centre_row]
                x = xc[sym]
                return {"centroid_x": float(np.sum(Ew * cell * x[:, None]) / np.sum(Ew * cell)),
                        "asymmetry": float((row[x > 0].sum() - row[x < 0].sum()) / row.sum())}

            mc_stats = stats(mc)
            profiles[case] = {"x": xc.tolist(), "MC": mc[:, centre_row].tolist()}
            for name, fn in models.items():
                vals, sec, comp = _timed(fn, X, Y)
                E = _cell_average(vals, cells, shape, X_EDGES, Y_EDGES)
                err, nbins = _rel_l2(E, mc, mc_err)
                st = stats(E)
                _row(rows, case, name, err, "relative L2 error of R_multiple(x, y) over cells (MC stderr < 10%)",
                     sec, comp, bins=nbins, centroid_x=st["centroid_x"], centroid_x_mc=mc_stats["centroid_x"],
                     asymmetry=st["asymmetry"], asymmetry_mc=mc_stats["asymmetry"])
                profiles[case][name] = E[:, centre_row].tolist()
                if name.startswith("PD kappa="):
                    kappa_errors.setdefault(name.split("=", 1)[1], []).append(err)
            if angle == 0.0:
                near_source_case(res, m, alpha_p, r_pts, r_w, rows, kappa_errors)


def near_source_case(res, m, alpha_p, r_pts, r_w, rows, kappa_errors):
    case = f"near_source a'={alpha_p}"
    Ft = float(1.0 - fresnel_reflectance(ETA, 1.0))
    mc, mc_err = res.R_r_order[2], res.R_r_order_stderr[2]
    _row(rows, case, "MC", res.R_multiple_stderr / res.R_multiple, "relative stderr of R_multiple", res.seconds,
         res.compile_seconds, photons=res.photons)
    r = jnp.asarray(r_pts)
    models = {"dipole": jax.jit(lambda r: Ft * dipole_profile(r, m))}
    for k in KAPPAS:
        if k != "none":
            models[f"attenuated dipole kappa={k}"] = jax.jit(
                lambda r, k=k: Ft * attenuated_dipole_profile(r, m, kappa=k))
        models[f"PD kappa={k}"] = jax.jit(lambda r, k=k: Ft * oblique_profile(r, 0.0, m, 0.0, kappa=k))
    centres = 0.5 * (R_EDGES[1:] + R_EDGES[:-1])
    for name, fn in models.items():
        vals, sec, comp = _timed(fn, r)
        E = np.sum(vals * r_w, axis=1)
        err, nbins = _rel_l2(E, mc, mc_err, centres < 2.0)
        err_all, _ = _rel_l2(E, mc, mc_err)
        _row(rows, case, name, err, "relative L2 error of R_multiple(r) over annuli r < 2 l_u (MC stderr < 10%)",
             sec, comp, bins=nbins, error_all_r=err_all)
        if name.startswith("PD kappa="):
            kappa_errors.setdefault(name.split("=", 1)[1], []).append(err)
        elif name.startswith("attenuated"):
            kappa_errors.setdefault("attenuated dipole " + name.split("=", 1)[1], []).append(err)


def slab_cases(cfg, rows):
    r_pts, r_w = _annulus_points(R_EDGES)
    centres = 0.5 * (R_EDGES[1:] + R_EDGES[:-1])
    alpha_p = 0.99
    m = Medium(1.0 - alpha_p, alpha_p, ETA)
    Ft = float(1.0 - fresnel_reflectance(ETA, 1.0))
    for d in cfg["slabs"]:
        case = f"slab d={d:g} a'={alpha_p}"
        res = simulate(Stack.slab(1.0 - alpha_p, alpha_p, 0.0, ETA, d), cfg["photons"], seed=9, r_edges=R_EDGES,
                       lanes=1024, progress=False)
        mc, mc_err = res.T_r_order[2], res.T_r_order_stderr[2]
        _row(rows, case, "MC", res.T_order_stderr[2] / res.T_order[2], "relative stderr of T_multiple",
             res.seconds, res.compile_seconds, photons=res.photons, T_multiple=res.T_order[2])
        n_pairs = multipole_n_pairs(R_EDGES[1:], m, d)
        r = jnp.asarray(r_pts)

        def pd_multipole(r, k):
            # Sources along the beam inside the slab (Eq. 8, x < d), each seen from the bottom face through Eq. 15
            # (gamma = pi: the multipole with thickness = source depth + view depth = d).
            def f(x):
                src = jnp.stack([jnp.zeros_like(x), jnp.zeros_like(x), -x], axis=-1)
                xo = jnp.stack([r, jnp.zeros_like(r), jnp.full_like(r, -d)], axis=-1)
                up, down = jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.0, -1.0])
                E = blended_exitance(xo, down, src, up, x, m, n_pairs=n_pairs)
                return attenuation_kernel(jnp.sqrt(r * r + (d - x) ** 2), m, kappa=k) * E

            return Ft * m.alpha_prime * beam_integral(f, jnp.full_like(r, d), r, m, length=d)

        models = {"dipole (n_pairs=0)": jax.jit(lambda r: Ft * multipole_profile(r, m, d, n_pairs=0)[1]),
                  "multipole": jax.jit(lambda r: Ft * multipole_profile(r, m, d, n_pairs=n_pairs)[1])}
        for k in KAPPAS:
            models[f"PD multipole kappa={k}"] = jax.jit(lambda r, k=k: pd_multipole(r, k))
        for name, fn in models.items():
            vals, sec, comp = _timed(fn, r)
            T = np.sum(vals * r_w, axis=1)
            err, nbins = _rel_l2(T, mc, mc_err, centres < 5.0)
            _row(rows, case, name, err, "relative L2 error of T_multiple(r) over annuli r < 5 l_u (MC stderr < 10%)",
                 sec, comp, bins=nbins, n_pairs=n_pairs)


def edge_cases(cfg, rows, profiles):
    alpha_p = 0.99
    m = Medium(1.0 - alpha_p, alpha_p, ETA)
    Ft = float(1.0 - fresnel_reflectance(ETA, 1.0))
    cells = _cells(SIDE_Z, SIDE_Y, x_split=-1.0, y_split=0.0)
    shape = (SIDE_Z.size - 1, SIDE_Y.size - 1)
    zc = 0.5 * (SIDE_Z[1:] + SIDE_Z[:-1])
    centre_col = np.argmin(np.abs(0.5 * (SIDE_Y[1:] + SIDE_Y[:-1])))
    for a in cfg["edges"]:
        case = f"edge a={a:g} a'={alpha_p}"
        top_x = np.linspace(0.0, a + 8.0, 17)
        res = simulate_edge(1.0 - alpha_p, alpha_p, 0.0, ETA, cfg["edge_photons"], edge_distance=a,
                            top_edges=(top_x, SIDE_Y), side_edges=(SIDE_Z, SIDE_Y), seed=13)
        mc, mc_err = res.side_hist[2], res.side_hist_stderr[2]
        _row(rows, case, "MC", res.R_side_order_stderr[2] / res.R_side_order[2],
             "relative stderr of R_side_multiple", res.seconds, res.compile_seconds, photons=res.photons,
             R_side_multiple=res.R_side_order[2], R_top_multiple=res.R_top_order[2],
             weight_balance=res.weight_balance)
        Z, Y = jnp.asarray(cells[2]), jnp.asarray(cells[3])

        def pd_quadpole(Z, Y, k):
            # Sources along the beam (depth x below the top face, distance a from the side face), seen from the side
            # face through Eq. 15 (gamma = pi/2: the quadpole).
            def f(x):
                src = jnp.stack([jnp.full_like(x, a), jnp.zeros_like(x), -x], axis=-1)
                xo = jnp.stack([jnp.zeros_like(Z), Y, -Z], axis=-1)
                E = blended_exitance(xo, jnp.array([-1.0, 0.0, 0.0]), src, jnp.array([0.0, 0.0, 1.0]), x, m)
                return attenuation_kernel(jnp.sqrt(a * a + Y * Y + (Z - x) ** 2), m, kappa=k) * E

            return Ft * m.alpha_prime * beam_integral(f, Z, jnp.sqrt(a * a + Y * Y), m)

        def pd_view_dipole(Z, Y):
            # The same beam sources with the side face's dipole alone (no image in the top face's boundary): what
            # the quadpole's second boundary adds.
            def f(x):
                rho = jnp.sqrt(Y * Y + (Z - x) ** 2)
                kap = attenuation_kernel(jnp.sqrt(a * a + rho * rho), m)
                return kap * dipole_exitance(rho, a, m)

            return Ft * m.alpha_prime * beam_integral(f, Z, jnp.sqrt(a * a + Y * Y), m)

        models = {"dipole": jax.jit(lambda Z, Y: Ft * dipole_profile(jnp.sqrt(a * a + Y * Y + Z * Z), m)),
                  "quadpole": jax.jit(lambda Z, Y: Ft * quadpole_profile(Z, Y, m, a, face="side")),
                  f"PD side-face dipole kappa={DEFAULT_KAPPA}": jax.jit(pd_view_dipole)}
        for k in KAPPAS:
            models[f"PD quadpole kappa={k}"] = jax.jit(lambda Z, Y, k=k: pd_quadpole(Z, Y, k))
        profiles[case] = {"z": zc.tolist(), "MC": mc[:, centre_col].tolist()}
        for name, fn in models.items():
            vals, sec, comp = _timed(fn, Z, Y)
            E = _cell_average(vals, cells, shape, SIDE_Z, SIDE_Y)
            err, nbins = _rel_l2(E, mc, mc_err)
            _row(rows, case, name, err, "relative L2 error of the side face's R_multiple(z, y) (MC stderr < 10%)",
                 sec, comp, bins=nbins, side_total=float(np.sum(E * np.outer(np.diff(SIDE_Z), np.diff(SIDE_Y)))),
                 side_total_mc_in_grid=float(np.sum(mc * np.outer(np.diff(SIDE_Z), np.diff(SIDE_Y)))))
            profiles[case][name] = E[:, centre_col].tolist()


def plot_profiles(profiles, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [k for k in profiles if k.startswith("oblique")] + [k for k in profiles if k.startswith("edge")]
    fig, axes = plt.subplots(1, len(keys), figsize=(3.2 * len(keys), 3.2), squeeze=False)
    for ax, key in zip(axes[0], keys):
        p = profiles[key]
        xs = p.get("x", p.get("z"))
        for name, v in p.items():
            if name in ("x", "z") or name.startswith("PD sampled"):
                continue
            ax.semilogy(xs, np.maximum(v, 1e-8), "k." if name == "MC" else "-", label=name, lw=1)
        ax.set_title(key, fontsize=8)
        ax.set_xlabel("x (mm)" if "x" in p else "z on the side face (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0][0].set_ylabel("multiply scattered exitance (1/mm^2)", fontsize=8)
    axes[0][-1].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run(quick: bool):
    cfg = CONFIG["quick" if quick else "full"]
    rows, kappa_errors, profiles = [], {}, {}
    oblique_cases(cfg, rows, kappa_errors, profiles)
    slab_cases(cfg, rows)
    edge_cases(cfg, rows, profiles)
    kappa = {k: {"mean_error": float(np.mean(v)), "errors": v} for k, v in kappa_errors.items()}
    return rows, {"kappa": kappa}, profiles


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    json_path = None
    if "--json" in argv:
        i = argv.index("--json")
        if i + 1 >= len(argv):
            print("photon_diffusion: --json needs a PATH", file=sys.stderr)
            return 2
        json_path = Path(argv[i + 1])
        del argv[i:i + 2]
    args = parse_args(argv, __doc__.splitlines()[0])
    name, out = NAME + args.tag, args.out
    if json_path is not None:
        name, out = json_path.stem, json_path.parent
    t0 = time.perf_counter()
    rows, summary, profiles = run(args.quick)
    summary["wall_seconds"] = time.perf_counter() - t0
    notes = ["models per incident photon (profiles x (1 - F(eta, cos theta_i))); MC: scattering order >= 2 only",
             "sigma_t' = 1/mm, g = 0, eta = 1.3; error = relative L2 over bins with MC relative stderr < 10%"]
    jp, pp = write_results(name, rows, out, quick=args.quick, summary=summary, notes=notes,
                           title="photon diffusion vs MC: error vs model seconds", connect=False)
    fig = Path(out) / f"{name}_profiles.png"
    plot_profiles(profiles, fig)
    print(f"wrote {jp}, {pp} and {fig} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
