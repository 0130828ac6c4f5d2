"""``jaxsss run``: the project's main job (``make run`` calls ``jaxsss run --out-dir out``).

The job is an ordered list of :class:`Step` s (:data:`STEPS`) sharing a :class:`RunContext`. Today:

1. ``render``: the default scene ``examples/marble_teapot.toml`` (a marble Utah teapot under a key and a fill light,
   512 x 512) with the hierarchical method, written to ``OUT_DIR/marble_teapot.png`` (and ``.npy``, ``.exr``,
   ``.json``), with the plan and per-pass timings;
2. ``fit_image``: the marble's sigma_a and sigma_s' recovered per channel from that image
   (:func:`fitting.fit_image`); truth, estimate, relative error and time are printed;
3. ``reparam``: the reparameterisation table of every Jensen et al. 2001 material -- sigma_a, sigma_s' (1/mm), Rd
   and l_d (mm) per channel at the table's eta;
4. ``dipole_profiles``: their dipole profiles R_d(r) for r from 0.01 to 50 mm, plotted on log axes to
   ``OUT_DIR/dipole_profiles.png``;
5. ``measure``: a simulated measurement of one named material (:data:`MEASURED`: skin1, green channel) with the
   Monte Carlo engine, written to ``OUT_DIR/measurement_skin1_G.csv`` (the ``jaxsss mc`` format);
6. ``fit_measurement``: that profile fitted with the white-Monte-Carlo model (``mc``) and, for comparison, the dipole;
   truth, estimate, standard error and relative error are printed.

Later steps (rendering, fitting) append to :data:`STEPS`; a step reads what earlier ones left in
``RunContext.results``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxsss.cli._common import (
    UNITS_EPILOG,
    CLIError,
    channel_labels,
    check_no_nan,
    fmt,
    format_table,
)

NAME = "run"
HELP = ("the main job: render the marble teapot and recover the marble from the image; then the Jensen 2001 "
        "reparameterisation table, dipole profile plot, and a simulated measurement fitted with the white-MC model and "
        "the dipole")

TABLE = "jensen2001"
MEASURED = ("skin1", 1)
"""The material and channel (G) of the simulated measurement. skin1's three channels all lie inside the g = 0.9
white-MC table's validity range (sigma_a / sigma_s' = 0.04-0.48 >= 6.7e-3); marble, cream and the milks do not."""
MEASURE_G, MEASURE_N = 0.9, 1.4
"""Anisotropy and index of the measurement: g = 0.9 (typical of tissue) and n = 1.4 -- the tables ship for n = 1 and
1.4 only, so skin1's table eta of 1.3 is replaced by 1.4 (said in the output)."""
MEASURE_PHOTONS = 100_000
MEASURE_BINS, MEASURE_R_MAX = 80, 10.0  # equal bins of [0, 10] mm: ~7 l_d of skin1's green channel
R_MIN_MM, R_MAX_MM, N_RADII = 0.01, 50.0, 200
DEFAULT_SCENE = "marble_teapot.toml"
FIT_PIXELS = 2048
"""Pixels of the image fit (a random subset of the object's pixels)."""


@dataclass
class RunContext:
    """What the steps share: the output directory, and results by step name."""

    out_dir: Path
    results: dict = field(default_factory=dict)

    def say(self, text: str = "") -> None:
        print(text, flush=True)


class Step(NamedTuple):
    name: str
    description: str
    run: Callable[[RunContext], None]


def _materials_medium(ctx: RunContext):
    """All materials of :data:`TABLE` as one Medium with shape (materials, channels); cached in the context."""
    if "materials" not in ctx.results:
        from jaxsss.data import list_materials, material
        from jaxsss.medium import Medium

        mats = [material(name, TABLE) for name in list_materials(TABLE)]
        medium = Medium(
            np.stack([m.sigma_a for m in mats]),
            np.stack([m.sigma_s_prime for m in mats]),
            np.array([[m.eta] for m in mats]),
        )
        ctx.results["materials"] = (mats, medium)
    return ctx.results["materials"]


def step_reparam(ctx: RunContext) -> None:
    from jaxsss.reparam import to_rd_ld

    mats, medium = _materials_medium(ctx)
    rd, ld = (np.asarray(x) for x in to_rd_ld(medium))
    sigma_a, sigma_s_prime = np.asarray(medium.sigma_a), np.asarray(medium.sigma_s_prime)
    check_no_nan({"rd": rd, "ld": ld})
    labels = channel_labels(rd.shape[-1])
    rows = []
    for i, m in enumerate(mats):
        for c, ch in enumerate(labels):
            first = c == 0
            rows.append(
                [m.name if first else "", fmt(m.eta) if first else "", ch]
                + [fmt(sigma_a[i, c], 4), fmt(sigma_s_prime[i, c], 4), fmt(rd[i, c], 5), fmt(ld[i, c], 5)]
            )
    ctx.say(f"Measured materials of {mats[0].citation}")
    ctx.say("at the table's eta (n_inside / n_outside); Rd and l_d from the dipole (Jensen and Buhler 2002, Eq. 15-16)")
    ctx.say(format_table(["material", "eta", "ch", "sigma_a [1/mm]", "sigma_s' [1/mm]", "Rd", "l_d [mm]"], rows, align_right_from=3))
    ctx.results["reparam"] = {"rd": rd, "ld": ld}


def step_dipole_profiles(ctx: RunContext) -> None:
    from jaxsss.cli._plot import plot_channels, pyplot, save
    from jaxsss.profiles.dipole import dipole_profile

    mats, medium = _materials_medium(ctx)
    r = np.geomspace(R_MIN_MM, R_MAX_MM, N_RADII)
    # r of shape (N, 1, 1) against the medium's (materials, channels): R has shape (N, materials, channels).
    R = np.asarray(dipole_profile(r[:, None, None], medium))
    check_no_nan({"R_d": R}, what="dipole profile")
    plt = pyplot()
    ncols = 4
    nrows = -(-len(mats) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.2 * ncols, 2.6 * nrows), sharex=True, sharey=True, squeeze=False)
    labels = channel_labels(R.shape[-1])
    for k, ax in enumerate(axes.flat):
        if k >= len(mats):
            ax.set_visible(False)
            continue
        plot_channels(ax, r, R[:, k, :], labels)
        ax.set_title(f"{mats[k].name} (eta {mats[k].eta:g})", fontsize=9)
        ax.grid(True, which="major", alpha=0.3)
        if k % ncols == 0:
            ax.set_ylabel(r"$R_d(r)$ [1/mm$^2$]")
        if k // ncols == nrows - 1:
            ax.set_xlabel("r [mm]")
    # Shared y range: nine decades below the largest value, so the materials can be compared panel to panel.
    top = float(np.max(R))
    axes[0, 0].set_ylim(top * 1e-9, top * 3.0)
    axes[0, 0].set_xlim(R_MIN_MM, R_MAX_MM)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle(f"Dipole profiles $R_d(r)$ per unit flux entering, {mats[0].citation}", fontsize=9)
    fig.tight_layout()
    path = save(fig, ctx.out_dir / "dipole_profiles.png")
    ctx.results["dipole_profiles"] = path
    ctx.say(f"wrote {path}")


def step_measure(ctx: RunContext, photons: int | None = None) -> None:
    """Simulate the measurement (pencil beam, normal incidence, half-space) and write it as a ``jaxsss mc`` CSV."""
    from jaxsss.data import material
    from jaxsss.mc import Stack, simulate

    photons = ctx.results.get("measure_photons", MEASURE_PHOTONS) if photons is None else photons
    name, c = MEASURED
    m = material(name, TABLE)
    sa, ssp = float(m.sigma_a[c]), float(m.sigma_s_prime[c])
    edges = np.linspace(0.0, MEASURE_R_MAX, MEASURE_BINS + 1)
    res = simulate(Stack.half_space(sa, ssp / (1.0 - MEASURE_G), MEASURE_G, MEASURE_N), photons, seed=2001,
                   r_edges=edges, progress=False)
    check_no_nan({"R": res.R_r}, what="Monte Carlo")
    keep = res.R_r_stderr > 0  # bins no photon reached carry no information (and no standard error)
    path = ctx.out_dir / f"measurement_{name}_{channel_labels(3)[c]}.csv"
    with path.open("w") as f:
        f.write(f"# jaxsss run: simulated measurement of {name} ({channel_labels(3)[c]}), sigma_a={sa:g} 1/mm, "
                f"sigma_s'={ssp:g} 1/mm, g={MEASURE_G:g}, eta={MEASURE_N:g}, photons={photons}\n")
        f.write("r_mm,R,R_stderr\n")
        for row in zip(res.r_centres[keep], res.R_r[keep], res.R_r_stderr[keep]):
            f.write(",".join(repr(float(v)) for v in row) + "\n")
    ctx.results["measure"] = {"path": path, "sigma_a": sa, "sigma_s_prime": ssp, "photons": photons}
    ctx.say(f"{name}, channel {channel_labels(3)[c]}: sigma_a = {sa:g}/mm, sigma_s' = {ssp:g}/mm, g = {MEASURE_G:g}, "
            f"eta = {MEASURE_N:g} (the white-MC tables have n = 1 and 1.4; {name}'s table eta is {m.eta:g})")
    ctx.say(f"{photons} photons in {res.seconds:.1f} s; R_diffuse = {res.R_diffuse:.5f} +- {res.R_diffuse_stderr:.1g}")
    ctx.say(f"wrote {path}")


def step_fit_measurement(ctx: RunContext) -> None:
    """Fit the measurement with the ``mc`` model and the dipole; print truth, estimate, standard error, error."""
    from fitting import fit_profile, read_profile

    meas = ctx.results["measure"]
    data = read_profile(meas["path"])
    rows = []
    fits = {}
    for model, kw in (("mc", {"g": MEASURE_G}), ("dipole", {})):
        fit = fit_profile(data, eta=MEASURE_N, model=model, warn=False, **kw)
        fits[model] = fit
        for key, label in (("sigma_a", "sigma_a"), ("sigma_s_prime", "sigma_s'")):
            est, se, truth = (float(np.asarray(getattr(fit, key))), float(np.asarray(getattr(fit, key + "_stderr"))),
                              meas[key])
            check_no_nan({key: est}, what=f"{model} fit")
            rows.append([model if key == "sigma_a" else "", label, fmt(truth, 4), fmt(est, 4), fmt(se, 2),
                         f"{100.0 * (est / truth - 1.0):+.2f}%"])
        status = "converged" if bool(np.all(fit.converged)) else "NOT CONVERGED"
        rows[-1].append(f"{status}, r >= {float(fit.r_min):.3g} mm, chi2/dof {float(fit.reduced_chi2):.2f}, "
                        f"{fit.seconds:.1f} s")
        rows[-2].append("")
    ctx.say(format_table(["model", "param", "truth [1/mm]", "estimate", "stderr", "rel. error", "fit"], rows,
                         align_right_from=2))
    for model, fit in fits.items():
        for text in fit.warnings:
            ctx.say(f"{model}: warning: {' '.join(text.split())}")
    ctx.say("mc: transport-accurate (white Monte Carlo table, same g and n); dipole: diffusion, biased near the source "
            "and for anisotropic scattering at these albedos -- its error is shown, not hidden")
    ctx.results["fit_measurement"] = fits


def _default_scene_path() -> Path:
    """``examples/marble_teapot.toml`` of the source tree (the default scene of ``make run``)."""
    import jaxsss

    path = Path(jaxsss.__file__).resolve().parents[1] / "examples" / DEFAULT_SCENE
    if not path.is_file():
        raise CLIError(f"the default scene {DEFAULT_SCENE} was not found at {path} (run from a source checkout)")
    return path


def step_render(ctx: RunContext) -> None:
    """Render the default scene (marble teapot, key and fill light) with the hierarchical method."""
    import dataclasses

    from jaxsss.render import load_scene, render, write_outputs

    scene = load_scene(_default_scene_path())
    resolution = ctx.results.get("resolution")
    if resolution is not None:
        scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, resolution=tuple(resolution)))
    if ctx.results.get("max_samples") is not None:
        scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render,
                                                                      max_samples=ctx.results["max_samples"]))
    result = render(scene, progress=ctx.results.get("progress", False))
    out = ctx.out_dir / "marble_teapot.png"
    paths = write_outputs(out, result.image, result.report, exposure=scene.output.exposure,
                          json_path=ctx.out_dir / "marble_teapot.json")
    r = result.report
    ctx.say(result.plan.explain())
    ctx.say(f"{r['resolution'][0]}x{r['resolution'][1]}: {r['n_samples']} irradiance samples, {r['n_shaded_points']} "
            f"shaded points, {r['interactions_per_point_mean']:.0f} interactions per point (eps {r['eps']:g})")
    ctx.say("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in r["seconds"].items()) +
            f"; total {r['seconds_total']:.1f} ({r['seconds_total_excluding_compile']:.1f} without compilation)")
    ctx.say(f"wrote {', '.join(paths.values())}")
    ctx.results["render"] = (scene, result)


def step_fit_image(ctx: RunContext) -> None:
    """Recover the marble's sigma_a and sigma_s' per channel from the rendered image."""
    from fitting import fit_image

    scene, result = ctx.results["render"]
    truth = scene.material.medium
    fit = fit_image(scene, result.image, max_pixels=FIT_PIXELS)
    rows = []
    for key, label in (("sigma_a", "sigma_a"), ("sigma_s_prime", "sigma_s'")):
        est, tru = np.asarray(getattr(fit, key)), np.asarray(getattr(truth, key))
        check_no_nan({key: est}, what="image fit")
        for c, name in enumerate(channel_labels(len(est))):
            rows.append([label if c == 0 else "", name, fmt(float(tru[c]), 4), fmt(float(est[c]), 4),
                         f"{100.0 * (est[c] / tru[c] - 1.0):+.3f}%"])
    ctx.say(format_table(["param", "ch", "truth [1/mm]", "estimate", "rel. error"], rows, align_right_from=2))
    sec = fit.seconds
    ctx.say(f"{fit.message} in {int(fit.n_steps)} steps on {fit.n_pixels} pixels; seconds: prepare "
            f"{sec['prepare']:.1f}, start {sec['start']:.1f}, compile {sec['compile']:.1f}, solve {sec['solve']:.1f}; "
            f"relative RMS residual {float(fit.rms_relative):.2e}")
    ctx.say("the model keeps every pair (no cut-off radius) while the image was rendered with the plan's cut-off, so "
            "the recovery error shows what that shortcut costs")
    ctx.results["fit_image"] = fit


STEPS: list[Step] = [
    Step("render", "render the default scene: a marble teapot under a key and a fill light", step_render),
    Step("fit_image", "recover the marble's sigma_a and sigma_s' from that image: truth, estimate, error, time",
         step_fit_image),
    Step("reparam", "reparameterisation table of the Jensen 2001 materials", step_reparam),
    Step("dipole_profiles", "plot of their dipole profiles", step_dipole_profiles),
    Step("measure", "Monte Carlo measurement of skin1 (green channel, g 0.9, n 1.4)", step_measure),
    Step("fit_measurement", "fit it with the white-MC model and the dipole: truth, estimate, stderr", step_fit_measurement),
]
"""The job, in order."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    description = "Run the main job, step by step:\n" + "\n".join(
        f"  {i}. {s.name}: {s.description}" for i, s in enumerate(STEPS, 1)
    )
    p = subparsers.add_parser(
        NAME, help=HELP, description=description, epilog=UNITS_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out-dir", default="out", metavar="DIR", help="directory for the job's files (default: out)")
    p.add_argument("--photons", type=int, default=MEASURE_PHOTONS, metavar="N",
                   help=f"photons of the simulated measurement, >= 1000 (default {MEASURE_PHOTONS})")
    p.add_argument("--resolution", type=int, nargs=2, default=None, metavar=("W", "H"),
                   help="image size of the render, pixels (default: the scene's, 512 x 512)")
    p.add_argument("--max-samples", type=int, default=None, metavar="N",
                   help="cap on the render's irradiance samples, >= 16 (default: the scene's [render].max_samples)")
    p.add_argument("--progress", action="store_true", help="show progress bars for the render passes")
    p.set_defaults(run=run)
    return p


def run(args) -> int:
    out_dir = Path(args.out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise CLIError(f"cannot create --out-dir {str(out_dir)!r}: {err.strerror or err}") from None
    if args.photons < 1000:
        raise CLIError(f"--photons={args.photons} is outside the allowed range [1000, inf)")
    ctx = RunContext(out_dir=out_dir)
    ctx.results["measure_photons"] = args.photons
    if args.resolution is not None:
        if min(args.resolution) < 1:
            raise CLIError(f"--resolution {args.resolution} must be two positive integers")
        ctx.results["resolution"] = args.resolution
    if args.max_samples is not None:
        if args.max_samples < 16:
            raise CLIError(f"--max-samples {args.max_samples} is outside the allowed range [16, inf)")
        ctx.results["max_samples"] = args.max_samples
    ctx.results["progress"] = args.progress
    for i, step in enumerate(STEPS, 1):
        ctx.say(f"== step {i}/{len(STEPS)}: {step.name}: {step.description}")
        step.run(ctx)
        ctx.say()
    return 0
