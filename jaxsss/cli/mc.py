"""``jaxsss mc``: Monte Carlo photon transport (MCML family) in a half-space or a slab; totals and R(r), T(r)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from jaxsss.cli._common import UNITS_EPILOG, CLIError, check_no_nan, fmt, format_table, number, print_json

NAME = "mc"
HELP = "Monte Carlo transport reference: R, T, A and profiles R(r), T(r) with standard errors"

DESCRIPTION = """\
Trace photon packets (MCML: Henyey-Greenstein scattering, absorption by weight, Russian roulette, exact Fresnel
reflection and refraction at the faces) through a half-space, or a slab when --thickness is given, lit by a
collimated pencil beam at --angle degrees from the normal. The medium's index relative to the outside is --eta
(the same medium above and below a slab).

Prints the totals per incident photon: R_specular (first-surface reflection), R_diffuse (everything else leaving the
lit face), T (everything leaving the far face, unscattered light included; T_unscattered also shown), A (absorbed),
each with a standard error from per-photon second moments. --json prints one object with the keys R_specular,
R_diffuse, R_diffuse_stderr, T, T_stderr, T_unscattered, A, A_stderr, R_single, R_multiple, mean_exit_radius,
step_cap_hits, photons, seed, seconds, compile_seconds (included in seconds), devices (and r_mm, R, R_stderr, T,
T_stderr profiles when -o is not used but --r-max is). -o FILE.csv writes the radial profile on --r-bins equal bins
of [0, --r-max] mm: columns r_mm (bin centre), R, R_stderr (and T, T_stderr for a slab), per incident photon
per mm^2, with a '#' header of the parameters.

The photons are split over one JAX device per usable core (--devices N to choose, or JAX_NUM_CPU_DEVICES=N in the
environment; on a GPU machine, the GPUs): each device runs its share with its own random stream, so a result is
reproducible for a given seed and device count, and results for different counts agree within their standard
errors. Compiled programs are cached on disk (~/.cache/jaxsss/jax; JAXSSS_COMPILATION_CACHE=DIR or off), so only
the first run of a kind compiles."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(NAME, help=HELP, description=DESCRIPTION, epilog=UNITS_EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sigma-a", type=number, required=True, metavar="A", help="absorption coefficient, 1/mm, >= 0")
    p.add_argument("--sigma-s", type=number, required=True, metavar="S",
                   help="scattering coefficient (not reduced), 1/mm, >= 0")
    p.add_argument("--g", type=number, default=0.0, help="Henyey-Greenstein anisotropy, in (-1, 1) (default 0)")
    p.add_argument("--eta", type=number, default=1.0, metavar="N",
                   help="relative index n_inside / n_outside, > 0 (default 1)")
    p.add_argument("--thickness", type=number, metavar="D", help="slab thickness, mm, > 0 (default: half-space)")
    p.add_argument("--angle", type=number, default=0.0, metavar="DEG",
                   help="angle of incidence from the normal, degrees, in [0, 90) (default 0)")
    p.add_argument("--photons", type=int, required=True, metavar="N", help="number of incident photons, >= 1")
    p.add_argument("--seed", type=int, default=0, metavar="K", help="random seed, >= 0 (default 0)")
    p.add_argument("--r-max", type=number, metavar="R", help="outer edge of the radial profile, mm, > 0")
    p.add_argument("--r-bins", type=int, default=50, metavar="M", help="number of radial bins, >= 1 (default 50)")
    p.add_argument("--split-length", type=number, metavar="L",
                   help="radial splitting for far-field profiles: a weight window that decays like exp(-r/L) from "
                   "r = L to --r-max, mm, > 0 (use the diffusion length l_d = 1/sigma_tr; `jaxsss reparam` prints "
                   "it). Standard errors then come from 16 batch means; needs --r-max and >= 8 photons")
    p.add_argument("-o", "--output", metavar="FILE.csv", help="write the radial profile R(r) (and T(r)) to a CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--devices", type=int, metavar="N",
                   help="split the photons over N JAX devices, >= 1 (default: one CPU device per usable core, or "
                   "every GPU). Results are reproducible for a given N and agree in distribution across N")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (it shows only on a terminal)")
    p.set_defaults(run=run)
    return p


def _r_edges(args):
    if args.r_max is None:
        if args.output:
            raise CLIError("-o needs a radial grid: give --r-max R (mm) and optionally --r-bins M")
        return None
    if not args.r_max > 0:
        raise CLIError(f"--r-max={args.r_max:g} is outside the allowed range (0, inf)")
    if args.r_bins < 1:
        raise CLIError(f"--r-bins={args.r_bins} is outside the allowed range [1, inf)")
    return np.linspace(0.0, args.r_max, args.r_bins + 1)


def _write_csv(path, res, slab: bool, args) -> Path:
    path = Path(path)
    cols = [res.r_centres, res.R_r, res.R_r_stderr] + ([res.T_r, res.T_r_stderr] if slab else [])
    names = ["r_mm", "R", "R_stderr"] + (["T", "T_stderr"] if slab else [])
    medium = (f"sigma_a={args.sigma_a:g} 1/mm, sigma_s={args.sigma_s:g} 1/mm, g={args.g:g}, eta={args.eta:g}, "
              + (f"slab thickness={args.thickness:g} mm" if slab else "half-space"))
    header = [
        f"# jaxsss mc: {medium}, angle={args.angle:g} deg, photons={res.photons}, seed={res.seed}",
        f"# r_mm: bin centre (mm) of {len(res.R_r)} equal bins of [0, {args.r_max:g}] mm; R, T: per incident photon "
        "per mm^2 (1/mm^2); *_stderr: standard errors"
        + (f" from {res.batches} batch means (radial splitting, length {res.split_length:g} mm)"
           if res.stderr_method == "batches" else ""),
        f"# R_specular={res.R_specular:.8g}, R_diffuse={res.R_diffuse:.8g} +- {res.R_diffuse_stderr:.2g}, "
        f"T={res.T:.8g} +- {res.T_stderr:.2g}, A={res.A:.8g}",
        ",".join(names),
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:
        f.write("\n".join(header) + "\n")
        for row in zip(*cols):
            f.write(",".join(repr(float(v)) for v in row) + "\n")
    return path


def _devices(args) -> int | None:
    """Ask JAX for ``--devices`` CPU devices, or by default one per usable core unless the user already chose a
    number (``JAX_NUM_CPU_DEVICES``), before its backend starts; the count to pass to ``simulate``."""
    import jax

    from jaxsss.mc.engine import usable_cores, use_cpu_devices

    if args.devices is not None and args.devices < 1:
        raise CLIError(f"--devices={args.devices} is outside the allowed range [1, inf)")
    if args.devices is None and jax.config.jax_num_cpu_devices >= 0:
        return None  # the user's (or the test suite's) JAX_NUM_CPU_DEVICES
    try:
        use_cpu_devices(args.devices or usable_cores())
    except ValueError:  # JAX already runs (the CLI called in-process): use the devices it has
        pass
    return args.devices


def run(args) -> int:
    devices = _devices(args)
    from jaxsss.mc import Stack, simulate

    if args.photons < 1:
        raise CLIError(f"--photons={args.photons} is outside the allowed range [1, inf)")
    if args.seed < 0:
        raise CLIError(f"--seed={args.seed} is outside the allowed range [0, inf)")
    slab = args.thickness is not None
    if slab:
        stack = Stack.slab(args.sigma_a, args.sigma_s, args.g, args.eta, args.thickness)
    else:
        stack = Stack.half_space(args.sigma_a, args.sigma_s, args.g, args.eta)
    r_edges = _r_edges(args)
    split = {}
    if args.split_length is not None:
        if r_edges is None:
            raise CLIError("--split-length needs --r-max: splitting stops at the end of the radial grid")
        if not args.split_length > 0:
            raise CLIError(f"--split-length={args.split_length:g} is outside the allowed range (0, inf)")
        if args.photons < 8:
            raise CLIError(f"--photons={args.photons} is outside the allowed range with --split-length: [8, inf) "
                           "(standard errors come from batch means)")
        split = {"split_length": args.split_length, "split_start": min(args.split_length, 0.5 * args.r_max),
                 "split_stop": args.r_max}
    res = simulate(stack, args.photons, seed=args.seed, angle_deg=args.angle, r_edges=r_edges,
                   progress=False if args.no_progress else None, devices=devices, **split)
    totals = {
        "R_specular": res.R_specular, "R_diffuse": res.R_diffuse, "R_diffuse_stderr": res.R_diffuse_stderr,
        "T": res.T, "T_stderr": res.T_stderr, "T_unscattered": res.T_unscattered, "A": res.A,
        "A_stderr": res.A_stderr, "R_single": res.R_single, "R_multiple": res.R_multiple,
    }
    check_no_nan(totals, what="Monte Carlo")
    mean_r = res.mean_exit_radius if math.isfinite(res.mean_exit_radius) else None
    if args.output:
        path = _write_csv(args.output, res, slab, args)
    if args.json:
        obj = {k: float(v) for k, v in totals.items()}
        obj.update(mean_exit_radius=mean_r, step_cap_hits=res.step_cap_hits, photons=res.photons, seed=res.seed,
                   seconds=res.seconds, compile_seconds=res.compile_seconds, devices=res.devices)
        if r_edges is not None and not args.output:
            obj.update(r_mm=res.r_centres.tolist(), R=res.R_r.tolist(), R_stderr=res.R_r_stderr.tolist())
            if slab:
                obj.update(T_r=res.T_r.tolist(), T_r_stderr=res.T_r_stderr.tolist())
        print_json(obj)
        return 0
    geometry = f"slab {args.thickness:g} mm" if slab else "half-space"
    print(f"jaxsss mc: {geometry}, sigma_a={args.sigma_a:g}/mm, sigma_s={args.sigma_s:g}/mm, g={args.g:g}, "
          f"eta={args.eta:g}, angle={args.angle:g} deg; {res.photons} photons, seed {res.seed}, {res.seconds:.2f} s on "
          f"{res.devices} device{'s' if res.devices > 1 else ''}")
    rows = [
        ["R_specular", fmt(res.R_specular), ""],
        ["R_diffuse", fmt(res.R_diffuse), fmt(res.R_diffuse_stderr, 2)],
        ["  single", fmt(res.R_single), fmt(res.R_single_stderr, 2)],
        ["  multiple", fmt(res.R_multiple), fmt(res.R_multiple_stderr, 2)],
        ["T", fmt(res.T), fmt(res.T_stderr, 2)],
        ["  unscattered", fmt(res.T_unscattered), fmt(res.T_unscattered_stderr, 2)],
        ["A", fmt(res.A), fmt(res.A_stderr, 2)],
    ]
    if mean_r is not None:
        rows.append(["mean exit r [mm]", fmt(mean_r), fmt(res.mean_exit_radius_stderr, 2)])
    print(format_table(["quantity", "value", "stderr"], rows))
    if res.step_cap_hits:
        print(f"warning: {res.step_cap_hits} photons hit the step cap ({res.max_steps} events); their weight "
              f"{res.step_cap_weight:.3g} is in no tally")
    if args.output:
        print(f"wrote {path}")
    return 0
