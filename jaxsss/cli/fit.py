"""``jaxsss fit``: fit sigma_a and sigma_s' to a measured radial profile (CSV, NumPy or MCML ``.mco`` file) with
:mod:`fitting`."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from jaxsss.cli._common import UNITS_EPILOG, CLIError, add_fresnel_option, format_table, number, print_json

NAME = "fit"
HELP = "fit sigma_a and sigma_s' to a radial profile R(r) (and T(r) for a slab)"

DESCRIPTION = """\
Fit the absorption and reduced scattering coefficients (1/mm) to a radial profile read from PROFILE: a CSV with
columns r_mm, R[, R_stderr][, T, T_stderr] (a header line and '#' comments allowed), a .npy array with those
columns, or a .npz with arrays of those names. r is in mm; R and T in 1/mm^2 per INCIDENT photon (absolute: the
models include the entry transmittance 1 - F(eta, cos 0); the mc model's tables are per incident photon already),
or in any unit with --relative (a free scale is fitted). The mc model (white Monte Carlo, transport-accurate) needs
--g; it covers g in [0, 0.95] and eta in [1, 1.6] (a family of tables, interpolated); its default range starts at
0.1 l_u.

Solver: Optimistix Levenberg-Marquardt (--solver to change) in log-parameters; weights 1/stderr when the file has
standard errors, else relative residuals. Fit range: by default r >= l_u (one transport mean free path at the
initial guess), where diffusion is trustworthy; --r-min/--r-max override it. The result states the range used.

Output: a table (default) or one JSON object (--json) with sigma_a, sigma_s_prime, sigma_a_stderr,
sigma_s_prime_stderr (1/mm), converged, iterations, seconds, model, and more (correlation, r_min, r_max, scale...).
--plot FILE.png saves data, fit and residuals. Exit status: 0 on success, 1 if the solver did not converge (the
output says so), 2 on a user error.

MCML runs: a .mco file (MCML 1.2.2's output) carries its own layers (n, g, thicknesses), ambient indices and photon
count, so it needs no other argument: `jaxsss fit RUN.mco --json`. The default model there is mc, the
transport-accurate one: white MC for a half-space whose (g, n) the family covers, else replay (perturbation)
Monte Carlo of the file's geometry with a trust region (seconds for a slab, up to minutes for a weakly absorbing
half-space or a stack; --photons per simulation). The deepest layer is fitted, the others stay at the file's values
(--free-layers chooses, top layer 0); the JSON's sigma_a and sigma_s_prime list the free layers, deepest first.
--model dipole|multipole fits a one-layer run with a diffusion model for comparison. Options that the file decides
(--eta, --thickness, --g, ...) are refused for a .mco file.

Slab profiles: --model mc with --thickness D (and --g, --eta) fits a profile file of a slab by the same replay Monte
Carlo (R(r) and, when the file has it, T(r) with the unscattered beam, MCML's convention). The profile must carry
standard errors and be bin averages: the binned CSV layout (r_lo_mm, r_hi_mm, Rd_per_mm2[, Tt_per_mm2], as MCML's
CSV export) or centres of equal bins from r = 0. --photons and --seed apply; the fit range is the whole profile."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    from fitting import FORWARD_MODELS, SOLVERS

    p = subparsers.add_parser(
        NAME, help=HELP, description=DESCRIPTION, epilog=UNITS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("profile", metavar="PROFILE", help="profile file: .csv, .npy, .npz (r in mm) or an MCML .mco run")
    p.add_argument("--eta", type=number, help="relative index n_inside / n_outside, > 0 (required, except for .mco)")
    p.add_argument("--model", choices=list(FORWARD_MODELS), default=None,
                   help="forward model (default: dipole; mc for a .mco run): "
                   + "; ".join(f"{m.name}: {m.summary}" for m in FORWARD_MODELS.values()))
    p.add_argument("--thickness", type=number, metavar="D", help="slab thickness, mm, > 0 (multipole; required there)")
    p.add_argument("--g", type=number, metavar="G",
                   help="Henyey-Greenstein anisotropy, fixed (mc model; required there: g in [0, 0.95], eta in "
                   "[1, 1.6])")
    p.add_argument("--relative", action="store_true", help="the profile has an unknown scale (fitted)")
    p.add_argument("--free-eta", action="store_true", help="also fit eta (usually fixed)")
    p.add_argument("--free-g", action="store_true",
                   help="also fit the anisotropy g (--model mc, half-space; g in [0, 0.95]): near-source data with "
                   "standard errors carry it, the far field does not (the result says when g is not constrained)")
    p.add_argument("--r-min", type=number, metavar="R", help="smallest radius fitted, mm (default: l_u at the guess)")
    p.add_argument("--r-max", type=number, metavar="R", help="largest radius fitted, mm (default: all)")
    p.add_argument("--solver", choices=list(SOLVERS), default="levenberg_marquardt", help="least-squares solver")
    p.add_argument("--max-steps", type=int, default=256, help="solver iteration cap (default 256)")
    add_fresnel_option(p)
    p.add_argument("--free-layers", metavar="I[,J...]",
                   help=".mco runs: indices of the layers to fit, top layer 0, negative from the bottom (default -1)")
    p.add_argument("--photons", type=int, metavar="N",
                   help=".mco runs, replay Monte Carlo: photons per simulation (default 100000)")
    p.add_argument("--seed", type=int, default=0, help=".mco runs: seed of the replay simulations (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--plot", metavar="FILE.png", help="save a plot of data, fit and residuals to FILE.png")
    p.set_defaults(run=run, defaults={name: p.get_default(name) for name in _MCO_DECIDES + _MCO_ONLY})
    return p


def _plot(path, data, fit):
    from jaxsss.cli._plot import pyplot, save

    plt = pyplot()
    outputs = list(fit.outputs)
    fig, axes = plt.subplots(2, len(outputs), figsize=(5.5 * len(outputs), 6.0), squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1]}, sharex="col")
    r = np.asarray(data.r)
    r_fine = np.geomspace(max(r[r > 0].min(), 1e-6), r.max(), 300) if np.any(r > 0) else r
    pred_fine = fit.predict(r_fine)
    pred = fit.predict(r)
    lo, hi = float(fit.r_min), float(fit.r_max)
    for j, key in enumerate(outputs):
        y = np.asarray(getattr(data, key))
        se = getattr(data, f"{key}_stderr")
        ax, axr = axes[0, j], axes[1, j]
        inside = (r >= lo) & (r <= hi)
        shown = y > 0
        ax.plot(r[inside & shown], y[inside & shown], "o", ms=3, color="tab:blue", label="data (fitted)")
        ax.plot(r[~inside & shown], y[~inside & shown], "o", ms=3, mfc="none", color="tab:gray", label="data (not fitted)")
        ax.plot(r_fine, pred_fine[key], "-", color="tab:red", label=f"{fit.model} fit")
        ax.axvspan(lo, hi, color="tab:green", alpha=0.07, label="fit range")
        ax.set_yscale("log")
        ax.set_xscale("log" if np.all(r > 0) and r.max() / r.min() >= 100 else "linear")
        ax.set_ylabel(f"{key}(r) [{'a.u.' if fit.relative else '1/mm$^2$ per incident photon'}]")
        ax.set_title(f"{key}: sigma_a = {float(fit.sigma_a):.4g} +- {float(fit.sigma_a_stderr):.2g}, "
                     f"sigma_s' = {float(fit.sigma_s_prime):.4g} +- {float(fit.sigma_s_prime_stderr):.2g} /mm",
                     fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        # Residuals: in standard errors when given, else relative.
        if se is not None:
            res, label = (pred[key] - y) / np.asarray(se), "(fit - data) / stderr"
        else:
            res, label = np.where(y != 0, (pred[key] - y) / np.where(y != 0, y, 1.0), np.nan), "(fit - data) / data"
        axr.plot(r[inside], res[inside], "o", ms=3, color="tab:blue")
        axr.plot(r[~inside], res[~inside], "o", ms=3, mfc="none", color="tab:gray")
        axr.axhline(0.0, color="k", lw=0.8)
        axr.set_xlabel("r [mm]")
        axr.set_ylabel(label, fontsize=8)
        axr.grid(True, alpha=0.3)
        if se is None:
            lim = np.nanmax(np.abs(res[inside])) if np.any(inside) else 1.0
            axr.set_ylim(-1.5 * lim - 1e-12, 1.5 * lim + 1e-12)
    status = "converged" if bool(np.all(fit.converged)) else "NOT CONVERGED"
    fig.suptitle(f"{data.source}: {fit.model} fit, eta = {float(fit.eta):g} ({status})", fontsize=9)
    fig.tight_layout()
    return save(fig, path)


# Options a .mco run decides itself (the file's layers, indices and photon count), and options only a .mco run takes;
# a given option is one that differs from the parser's default (recorded by add_parser as ``args.defaults``).
_MCO_DECIDES = ("eta", "thickness", "g", "relative", "free_eta", "free_g", "r_min", "r_max", "solver", "max_steps", "fresnel",
                "plot")
_MCO_ONLY = ("free_layers", "photons", "seed")


# A slab profile with --model mc is fitted by replay Monte Carlo (fitting.fit_mc_slab): these options do not apply.
_SLAB_MC_REFUSES = ("relative", "free_eta", "free_g", "r_min", "r_max", "solver", "max_steps", "fresnel", "plot")
_SLAB_MC_TAKES = ("photons", "seed")


def _run_mc_slab(args, data) -> int:
    from fitting import fit_mc_slab

    for name in _SLAB_MC_REFUSES:
        if getattr(args, name) != args.defaults.get(name, None):
            raise CLIError(f"{_flag(name)} does not apply to --model mc with --thickness (replay Monte Carlo fits "
                           "the whole binned profile with its standard errors)")
    if args.g is None:
        raise CLIError("--model mc needs --g (the Henyey-Greenstein anisotropy of the slab)")
    if args.photons is not None and args.photons < 1000:
        raise CLIError(f"--photons {args.photons} must be >= 1000")
    fit = fit_mc_slab(data, eta=args.eta, g=args.g, thickness=args.thickness, photons=args.photons or 100_000,
                      seed=args.seed)
    return _print_layer_fit(args, fit, f"slab {args.thickness:g} mm, eta {args.eta:g}, g {args.g:g}")


_FREE_G_REFUSES = ("g", "relative", "free_eta", "solver", "fresnel", "plot")


def _run_free_g(args, data) -> int:
    from fitting import fit_free_g

    if args.model != "mc":
        raise CLIError(f"--free-g needs --model mc (the white Monte Carlo family is smooth in g); got {args.model}")
    for name in _FREE_G_REFUSES:
        if getattr(args, name) != args.defaults.get(name, None):
            raise CLIError(f"{_flag(name)} does not apply with --free-g")
    fit = fit_free_g(data, eta=args.eta, r_min=args.r_min, r_max=args.r_max, max_steps=args.max_steps)
    if args.json:
        print_json({**fit.to_dict(), "model": "mc", "file": data.source})
    else:
        print(f"{data.source}: {len(data.r)} radii; model mc with free g, {fit.n_points} points in "
              f"[{fit.r_min:g}, {fit.r_max:g}] mm, {'converged' if fit.converged else 'NOT CONVERGED'}, "
              f"reduced chi^2 {fit.reduced_chi2:.3g}, {fit.seconds:.1f} s")
        print(format_table(["sigma_a (1/mm)", "sigma_s' (1/mm)", "g", "g constrained"],
                           [[f"{fit.sigma_a:.5g} +- {fit.sigma_a_stderr:.2g}",
                             f"{fit.sigma_s_prime:.5g} +- {fit.sigma_s_prime_stderr:.2g}",
                             f"{fit.g:.4f} +- {fit.g_stderr:.2g}", "yes" if fit.identifiable else "NO"]]))
    for text in fit.warnings:
        print(f"jaxsss: warning: {' '.join(text.split())}", file=sys.stderr)
    return 0 if fit.converged else 1


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _run_mco(args) -> int:
    from fitting import fit_mco, read_mco

    for name in _MCO_DECIDES:
        if getattr(args, name) != args.defaults[name]:
            raise CLIError(f"{_flag(name)} does not apply to an MCML run ({args.profile}): the file gives the "
                           "geometry, indices and photon count")
    if args.photons is not None and args.photons < 1000:
        raise CLIError(f"--photons {args.photons} must be >= 1000")
    free = None
    if args.free_layers is not None:
        try:
            free = tuple(int(v) for v in args.free_layers.split(","))
        except ValueError:
            raise CLIError(f"--free-layers {args.free_layers!r} is not a comma-separated list of integers") from None
    run = read_mco(args.profile)
    fit = fit_mco(run, model=args.model or "mc", free_layers=free, photons=args.photons or 100_000, seed=args.seed)
    return _print_layer_fit(args, fit, f"MCML run, {len(run.layers)} layer(s), {run.photons:g} photons")


def _print_layer_fit(args, fit, what: str) -> int:
    """Print a :class:`fitting.McoFit` (table or JSON) and its warnings; the exit status."""
    if not np.all(np.isfinite(np.concatenate([fit.sigma_a, fit.sigma_s_prime]))):
        raise CLIError(f"the fit of {fit.source} produced a non-finite value; refusing to print it")
    if args.json:
        print_json({**fit.to_dict(), "file": fit.source})
    else:
        print(f"{fit.source}: {what}; model {fit.model} ({fit.method}), {fit.status}, {fit.simulations} simulations, "
              f"{fit.seconds:.1f} s")
        known = bool(np.all(np.isfinite(fit.input_sigma_a)))  # a .mco run's input; unknown for a profile file
        rows = [[str(i), f"{a:.5g} +- {sa:.2g}", f"{s_:.5g} +- {ss:.2g}"] + ([f"{ia:g}", f"{is_:g}"] if known else [])
                for i, a, sa, s_, ss, ia, is_ in zip(fit.free_layers, fit.sigma_a, fit.sigma_a_stderr,
                                                      fit.sigma_s_prime, fit.sigma_s_prime_stderr, fit.input_sigma_a,
                                                      fit.input_sigma_s_prime)]
        print(format_table(["layer", "sigma_a (1/mm)", "sigma_s' (1/mm)"]
                           + (["run's sigma_a", "run's sigma_s'"] if known else []), rows))
    for text in fit.warnings:
        print(f"jaxsss: warning: {' '.join(text.split())}", file=sys.stderr)
    return 0 if fit.converged else 1


def run(args) -> int:
    from fitting import fit_profile, read_profile

    if str(args.profile).lower().endswith(".mco"):
        return _run_mco(args)
    slab_mc = (args.model == "mc" and args.thickness is not None)
    for name in _MCO_ONLY:
        if getattr(args, name) != args.defaults[name] and not (slab_mc and name in _SLAB_MC_TAKES):
            also = " and to --model mc with --thickness" if name in _SLAB_MC_TAKES else ""
            raise CLIError(f"{_flag(name)} applies to MCML .mco runs{also} only")
    if args.eta is None:
        raise CLIError("--eta is required for a profile file (an MCML .mco run carries its own)")
    args.model = args.model or "dipole"
    if args.r_min is not None and args.r_max is not None and not args.r_min < args.r_max:
        raise CLIError(f"--r-min {args.r_min:g} must be below --r-max {args.r_max:g}")
    if args.max_steps < 1:
        raise CLIError(f"--max-steps {args.max_steps} must be >= 1")
    data = read_profile(args.profile)
    if args.model == "mc" and args.thickness is not None:
        return _run_mc_slab(args, data)
    if args.free_g:
        return _run_free_g(args, data)
    # warn=False: the fit's warnings (fit.warnings) are printed below as one line each.
    fit = fit_profile(data, eta=args.eta, model=args.model, thickness=args.thickness, relative=args.relative,
                      free_eta=args.free_eta, r_min=args.r_min, r_max=args.r_max, solver=args.solver,
                      max_steps=args.max_steps, fresnel=args.fresnel, warn=False, g=args.g)
    values = {k: float(np.asarray(getattr(fit, k))) for k in
              ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr")}
    if any(np.isnan(v) for v in values.values()):
        raise CLIError(f"the fit of {data.source} produced NaN; refusing to print it (check the data and --eta)")
    converged = bool(np.all(fit.converged))
    if args.json:
        d = fit.to_dict()
        d["converged"] = converged
        d["file"] = data.source
        print_json(d)
    else:
        print(f"{data.source}: {len(data.r)} radii, {data.r[0]:g} to {data.r[-1]:g} mm")
        print(fit)
    if args.plot:
        path = _plot(args.plot, data, fit)
        if not args.json:
            print(f"wrote {path}")
    for text in fit.warnings:
        print(f"jaxsss: warning: {' '.join(text.split())}", file=sys.stderr)
    return 0 if converged else 1
