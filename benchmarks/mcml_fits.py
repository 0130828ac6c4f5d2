"""Model bias against MCML: every shared MCML 1.2.2 run fitted with the fitting layer's models, recovered vs true.

What is measured (issue 15, acceptance "the dipole and multipole fits' bias on the same files is reported beside,
not hidden"). Each ``.mco`` file of ``shared/reference/mcml`` (half-spaces, slabs and a two-layer stack at several
``n``, ``g`` and albedos; found beside the repository) is read with :func:`fitting.read_mco` as a user would and fitted
absolutely with :func:`fitting.fit_profile` (per incident photon; weights from the per-bin standard errors that
:func:`fitting.mco.bin_standard_errors` estimates from the photon count; each model's default fit range; ``eta`` =
``n_layer / n_above`` from the file). One row per (file, model):

- ``dipole``: every file, ``R(r)`` only. On slabs and the stack this is the model a user without a slab model would
  reach for; its error there shows what ignoring the geometry costs.
- ``multipole``: files of finite thickness, ``R(r)`` and ``T(r)`` with the file's thickness (on a half-space the
  multipole is the dipole, so it is not repeated). ``T`` keeps the unscattered beam in its first bin (MCML's
  convention); the default fit range starts at ``l_u`` and leaves that bin out.
- ``mc``: half-spaces whose ``(g, eta)`` has a shipped white Monte Carlo table
  (:func:`jaxsss.mc.available_white_tables`), ``R(r)`` only.

The truth of a multi-layer stack is its deepest layer (the homogeneous models see the stack as one medium: the
bias then includes the top layer's effect). ``error = max(|sigma_a / truth - 1|, |sigma_s' / truth - 1|)``; the
percent errors, the fits' standard errors, the errors in units of those standard errors (``z``), the solver status,
warnings and fit range are extra keys. ``seconds`` is one fit after compilation, ``compile_seconds`` the first call.

- ``fit_mco mc``: every file, the transport-accurate route of ``jaxsss fit RUN.mco --model mc``
  (:func:`fitting.fit_mco`: white MC where a table exists, else replay Monte Carlo with a trust region from a dipole
  start, the deepest layer free); its ``seconds`` is the whole fit, simulations and compilation included.

More models: a row comes from a :class:`FitSpec` -- ``setup(run, data)`` returns the keyword arguments of
:func:`fitting.fit_profile` (or a string saying why the model does not apply) -- so a new forward model of the
fitting registry is one function added to :data:`SPECS`.

``--quick``: two files (the ``g = 0`` half-space and the 2 mm slab), one timed repeat.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results

NAME = "mcml_fits"
METRIC = "max |rel. error| of sigma_a, sigma_s' vs the MCML input"
QUICK_FILES = ("halfspace_n133_g0", "slab2mm_n14_g08")
PLOT_LIMIT_PCT = 1000.0  # bars beyond +-1000% are clipped and labelled with their value


def mcml_dir() -> Path:
    """``shared/reference/mcml`` in the nearest ancestor of this repository that has it."""
    here = Path(__file__).resolve().parents[1]
    for parent in [here, *here.parents]:
        candidate = parent / "shared" / "reference" / "mcml"
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"shared/reference/mcml not found above {here}")


class FitSpec(NamedTuple):
    """One model's rows: ``setup(run, data) -> dict`` of :func:`fitting.fit_profile` keyword arguments (``model``,
    ``R``/``T`` and their standard errors, ``thickness``, ``g`` ...; ``r`` and ``eta`` are added), or a ``str``: the
    reason the model does not apply to that run (recorded in the summary)."""

    label: str
    setup: Callable


def _geometry(run) -> str:
    if len(run.layers) > 1:
        return f"{len(run.layers)}-layer stack"
    return "half-space" if run.semi_infinite else f"slab {run.thickness:g} mm"


def _dipole(run, data):
    return {"model": "dipole", "R": data.R, "R_stderr": data.R_stderr}


def _multipole(run, data):
    if run.semi_infinite:
        return "semi-infinite: the multipole at d = inf is the dipole"
    if len(run.layers) > 1:
        return "several layers: the multipole is one homogeneous slab"
    return {"model": "multipole", "R": data.R, "R_stderr": data.R_stderr, "T": data.T, "T_stderr": data.T_stderr,
            "thickness": run.thickness}


def _mc(run, data):
    from fitting.models import has_white_table

    layer = run.layers[-1]
    if not run.semi_infinite or len(run.layers) > 1:
        return "the white-MC model is a homogeneous half-space"
    if not has_white_table(layer.g, run.eta):
        return f"(g={layer.g:g}, eta={run.eta:g}) is outside the white Monte Carlo family"
    return {"model": "mc", "R": data.R, "R_stderr": data.R_stderr, "g": layer.g}


SPECS: list[FitSpec] = [FitSpec("dipole", _dipole), FitSpec("multipole", _multipole), FitSpec("mc", _mc)]
"""The models fitted to every run; append a :class:`FitSpec` to add one."""


def fit_rows(path: Path, specs, repeats: int):
    """Rows for one ``.mco`` file and the reasons of the models that did not apply."""
    import fitting

    run = fitting.read_mco(path)
    data = run.to_profile()
    truth = run.layers[-1]
    rows, skipped = [], {}
    for spec in specs:
        kwargs = spec.setup(run, data)
        if isinstance(kwargs, str):
            skipped[spec.label] = kwargs
            continue
        kwargs = dict(kwargs, eta=run.eta, warn=False)
        timing = time_call(fitting.fit_profile, data.r, repeats=repeats, **kwargs)
        fit = timing.output
        est = {"sigma_a": float(fit.sigma_a), "sigma_s_prime": float(fit.sigma_s_prime)}
        se = {"sigma_a": float(fit.sigma_a_stderr), "sigma_s_prime": float(fit.sigma_s_prime_stderr)}
        true = {"sigma_a": truth.sigma_a, "sigma_s_prime": truth.sigma_s_prime}
        rel = {k: est[k] / true[k] - 1.0 for k in est}
        rows.append(make_row(
            NAME, f"fit_profile {spec.label}", path.stem, max(abs(v) for v in rel.values()), METRIC,
            timing.seconds, timing.compile_seconds,
            geometry=_geometry(run), n=truth.n, g=truth.g, eta=run.eta, photons=run.photons,
            outputs="+".join(fit.outputs), status="; ".join(sorted(set(fit.messages()))),
            warnings=list(fit.warnings), fit_r_min_mm=float(fit.r_min), fit_r_max_mm=float(fit.r_max),
            n_points=int(fit.n_points), reduced_chi2=float(fit.reduced_chi2), **_errors(est, se, true),
        ))
    return rows, skipped


def _errors(est: dict, se: dict, true: dict) -> dict:
    """Per parameter: true, fit, % error, standard error and z (the row fields of every model)."""
    out = {}
    for k in est:
        out[f"{k}_true"] = true[k]
        out[f"{k}_fit"] = est[k]
        out[f"{k}_err_pct"] = 100.0 * (est[k] / true[k] - 1.0)
        out[f"{k}_stderr"] = se[k]
        out[f"{k}_z"] = (est[k] - true[k]) / se[k] if se[k] > 0 and math.isfinite(se[k]) else None
    return out


def transport_row(path: Path, photons: int = 100_000):
    """The transport-accurate route of ``jaxsss fit RUN.mco --model mc`` (:func:`fitting.fit_mco`): white MC where a
    table exists, else replay Monte Carlo from a dipole start; the deepest layer free. Seconds include its
    simulations and compilation (a fresh fit is what a user waits for)."""
    import fitting

    fit = fitting.fit_mco(path, model="mc", photons=photons)
    run = fitting.read_mco(path)
    truth = run.layers[-1]
    est = {"sigma_a": float(fit.sigma_a[0]), "sigma_s_prime": float(fit.sigma_s_prime[0])}
    se = {"sigma_a": float(fit.sigma_a_stderr[0]), "sigma_s_prime": float(fit.sigma_s_prime_stderr[0])}
    true = {"sigma_a": truth.sigma_a, "sigma_s_prime": truth.sigma_s_prime}
    err = max(abs(est[k] / true[k] - 1.0) for k in est)
    return make_row(NAME, "fit_mco mc", path.stem, err, METRIC, fit.seconds, None, geometry=_geometry(run),
                    n=truth.n, g=truth.g, eta=run.eta, photons=run.photons, route=fit.method, status=fit.status,
                    warnings=list(fit.warnings), simulations=fit.simulations, reduced_chi2=fit.reduced_chi2,
                    **_errors(est, se, true))


def _bias_plot(rows, path: Path):
    """Bars of the percent errors in sigma_a and sigma_s' per file and model (the bias figure of the docs)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def label(r):  # "dipole", "mc" (the tabulated model), or "fit_mco replay|white_mc"
        method = r["method"].removeprefix("fit_profile ")
        return f"fit_mco {r.get('route', '')}" if method == "fit_mco mc" else method

    labels = [f"{r['setting']}\n{label(r)}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(7.0, 0.55 * len(rows) + 2), 5.2))
    for k, (key, name) in enumerate((("sigma_a_err_pct", "sigma_a"), ("sigma_s_prime_err_pct", "sigma_s'"))):
        vals = np.array([r[key] for r in rows])
        errs = np.array([100 * (r[key.replace("_err_pct", "_stderr")] or 0) / r[key.replace("_err_pct", "_true")]
                         for r in rows])
        shown = np.clip(vals, -PLOT_LIMIT_PCT, PLOT_LIMIT_PCT)
        ax.bar(x + (k - 0.5) * 0.4, shown, 0.4, yerr=np.where(shown == vals, errs, 0), capsize=2,
                      label=f"{name} (bar: 1 stderr)")
        for xi, v, s in zip(x, vals, shown):
            if v != s:  # off the scale: say the value
                ax.annotate(f"{v:.2g}%", (xi + (k - 0.5) * 0.4, s), fontsize=6, rotation=90, ha="center",
                            va="top" if s > 0 else "bottom", color="white")
    ax.axhspan(-3, 3, color="0.85", zorder=0, label="+-3% (the transport-accurate goal)")
    ax.set_yscale("symlog", linthresh=3)
    ticks = [-100, -30, -10, -3, 0, 3, 10, 30, 100, 300, 1000]
    ax.set_yticks(ticks, [f"{t:+d}" if t else "0" for t in ticks])
    ax.set_ylim(-100, PLOT_LIMIT_PCT * 1.05)
    ax.set_xticks(x, labels, rotation=90, fontsize=7)
    ax.set_ylabel("recovered / MCML input - 1 (%)")
    ax.set_title("Fits of MCML 1.2.2 runs: error per file and model", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    t0 = time.perf_counter()
    files = sorted(mcml_dir().glob("*.mco"))
    if args.quick:
        files = [f for f in files if f.stem in QUICK_FILES]
    repeats = 1 if args.quick else 3
    rows, skipped = [], {}
    for path in files:
        r, s = fit_rows(path, SPECS, repeats)
        r.append(transport_row(path))
        rows += r
        skipped[path.stem] = s
        for row in r:
            print(f"{row['setting']:>20} {row['method']:>22}: sigma_a {row['sigma_a_err_pct']:+7.1f}%  "
                  f"sigma_s' {row['sigma_s_prime_err_pct']:+7.1f}%  ({row['status']}, {row['seconds']:.2f} s)",
                  flush=True)
    by_model = {}
    for row in rows:
        by_model.setdefault(row["method"], []).append(row["error"])
    summary = {
        "max_abs_error_by_model": {k: max(v) for k, v in by_model.items()},
        "median_abs_error_by_model": {k: float(np.median(v)) for k, v in by_model.items()},
        "not_applicable": skipped,
        "files": [f.stem for f in files],
        "wall_seconds": time.perf_counter() - t0,
    }
    notes = [
        "data: MCML 1.2.2 .mco read by fitting.read_mco (bin centres; standard errors from the photon count, an "
        "upper bound: see fitting/mco.py); fits absolute, per incident photon, each model's default range",
        "truth of a multi-layer stack: its deepest layer",
        "seconds = one fit_profile call after compilation (min of repeats); compile_seconds = the first call; "
        "fit_mco mc rows: the whole transport-accurate fit (simulations and compilation included)",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, connect=False,
                                        title=f"{NAME}: max |error| of sigma_a, sigma_s' vs fit seconds")
    bias_png = _bias_plot(rows, Path(args.out) / f"{NAME}{args.tag}_bias.png")
    print(f"wrote {json_path}, {png_path} and {bias_png} ({summary['wall_seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
