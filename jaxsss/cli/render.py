"""``jaxsss render SCENE.toml -o out.png``: render a translucent object with any registered method
(:mod:`jaxsss.render.methods`: hierarchical, direct, cached, photon, layered).

Writes ``out.png`` (sRGB), ``out.npy`` (linear radiance, H x W x 3, W/(mm^2 sr)), ``out.exr`` and, with ``--json``,
the report (the same schema for every method): the end-to-end time split by stage (compilation apart), the
method's counts, the plan and the image statistics. ``--explain`` prints the scene plan and stops.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from jaxsss.cli._common import UNITS_EPILOG, CLIError, number

NAME = "render"
HELP = "render a scene file (TOML) of a translucent mesh with any registered render method"

METHOD_CHOICES = ("hierarchical", "direct", "cached", "photon", "layered")
"""The built-in methods (``--method``); the registry (:func:`jaxsss.render.method_names`) is checked at run time, so
a method registered by another module is accepted too."""

# command-line option -> (the methods' keyword, its check: (lo, open) for numbers)
_OPTIONS = {
    "eps": ("eps", "(0, inf)"),
    "photons": ("n_photons", "[1, inf)"),
    "samples": ("samples", "[1, inf)"),
    "cache_error": ("error_bound", "(0, inf)"),
    "cache_gradient": ("gradient", None),
    "one_pass": ("one_pass", None),
    "cache_always": ("always", None),
    "bssrdf": ("bssrdf", None),
}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description=(
            "Render a translucent mesh described by a TOML scene file (see examples/*.toml). Scene units: mm for "
            "positions and sizes, 1/mm for sigma_a and sigma_s', W/sr for point and spot light intensities, W/mm^2 "
            "for directional lights; images hold radiance in W/(mm^2 sr)."
        ),
        epilog=UNITS_EPILOG,
    )
    p.add_argument("scene", type=Path, help="scene file (TOML)")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="output PNG (sRGB); OUT.npy (linear) and OUT.exr are written beside it "
                        "(default: the scene name with .png in the current directory)")
    p.add_argument("--method", default=None, metavar="NAME",
                   help="render method, one of the registry's: " + ", ".join(METHOD_CHOICES) + " (default: the "
                        "scene's [render].method); cached = irradiance caching with gradients (Keng et al. 2006) "
                        "on top of the hierarchical sum; layered = single scattering ray-marched through the "
                        "scene's [layers] subsurface textures (Francois et al.), plus the outer layer's diffusion "
                        "where the plan says so; photon = photon diffusion (Donner and Jensen 2007): photons "
                        "traced into the mesh store volumetric sources, summed hierarchically with the blended "
                        "dipole, quadpole and multipole; [[blocker]] meshes cast volumetric shadows")
    p.add_argument("--photons", type=int, default=None, metavar="N",
                   help="photon method: photons traced from the lights, >= 1 (default: [render].photons)")
    p.add_argument("--samples", type=int, default=None, metavar="N",
                   help="layered method: samples per view ray, >= 1 (default: [layers].samples)")
    p.add_argument("--cache-error", type=number, default=None, metavar="A",
                   help="cached method: relative error bound a of the split-disk weights, > 0, dimensionless "
                        "(default 0.3; see docs/benchmarks.md for its speed and error end to end)")
    p.add_argument("--cache-gradient", choices=("far", "analytic", "autodiff", "none"), default=None,
                   help="cached method: grad S in the interpolation (Eq. 10): the far-field part of the analytic "
                        "gradient (default; the near-field term follows sample noise), the full analytic gradient "
                        "(Eq. 9), the same by autodiff, or none (plain weighted mean); W/mm^3")
    p.add_argument("--one-pass", action="store_true", default=None,
                   help="cached method: interpolate from the caches made so far (single pass) instead of all")
    p.add_argument("--cache-always", action="store_true", default=None,
                   help="cached method: cache even where the plan leaves caching out (below 20000 shaded points it "
                        "costs more end to end than it saves; see --explain)")
    p.add_argument("--debug-images", action="store_true",
                   help="cached method: also write OUT_caches.png, OUT_gradient.png and OUT_variance.png")
    p.add_argument("--bssrdf", choices=("auto", "dipole", "white", "white-oblique"), default=None,
                   help="hierarchical and direct methods: the profile kernel (jaxsss.render.bssrdf); auto (default) "
                        "takes the white Monte Carlo profiles where tables exist for (g, eta), with oblique "
                        "incidence where those exist, else the dipole plus single scattering; --explain says which")
    p.add_argument("--eps", type=number, default=None,
                   help="solid-angle threshold of the hierarchical sums, sr (Eq. 12; default: the scene's)")
    p.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), default=None,
                   help="image size in pixels (default: the scene's camera)")
    p.add_argument("--explain", action="store_true", help="print the scene plan (terms kept and left out) and exit")
    p.add_argument("--json", type=Path, default=None, metavar="REPORT", help="write the render report as JSON")
    p.add_argument("--no-exr", action="store_true", help="do not write the EXR beside the PNG")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary")
    p.set_defaults(run=run)
    return p


def method_options(args, entry) -> dict:
    """The options given on the command line, checked, as the method's keywords; an option the method does not take
    is a one-line error naming the methods that do."""
    from jaxsss.render import METHODS

    options = {}
    for attr, (keyword, allowed) in _OPTIONS.items():
        value = getattr(args, attr)
        if value is None:
            continue
        flag = "--" + attr.replace("_", "-")
        if keyword not in entry.options:
            takers = [m.name for m in METHODS.values() if keyword in m.options]
            raise CLIError(f"{flag} applies to --method {' / '.join(takers)}, not {entry.name}")
        if allowed is not None and not (value > 0 if allowed.startswith("(") else value >= 1):
            raise CLIError(f"{flag} {value:g} is outside the allowed range {allowed}")
        options[keyword] = value
    return options


def run(args) -> int:
    from jaxsss.render import explain_method, load_scene, render, resolve_method, write_outputs

    if args.resolution is not None and min(args.resolution) < 1:
        raise CLIError(f"--resolution {args.resolution} must be two positive integers")
    scene = load_scene(args.scene)
    try:
        entry = resolve_method(args.method or scene.render.method)
    except ValueError as err:
        raise CLIError(f"--method: {err}") from None
    options = method_options(args, entry)
    if args.debug_images and entry.name != "cached":
        raise CLIError(f"--debug-images applies to --method cached, not {entry.name}")
    if args.debug_images:
        options["always"] = True  # the debug images show the caches
    resolution = None if args.resolution is None else tuple(args.resolution)
    if args.explain:
        plan = explain_method(scene, entry.name, resolution=resolution, **options)
        print(f"scene plan for {args.scene} ({entry.name}):")
        print(plan.explain())
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps({"plan": plan.to_dict()}, indent=2, default=float) + "\n")
        return 0
    out = args.output or Path(args.scene.with_suffix(".png").name)
    result = render(scene, entry.name, resolution=resolution, progress=not args.quiet, **options)
    if args.debug_images and "placement" in result.prepared.extras:
        from jaxsss.render.cache import debug_images
        from jaxsss.render.output import write_png

        for name, img in debug_images(result.prepared).items():
            scaled = img / img.max() if img.max() > 0 else img
            write_png(out.with_name(f"{out.stem}_{name}.png"), np.repeat(scaled[..., None], 3, axis=-1))
    paths = write_outputs(out, result.image, result.report, exposure=scene.output.exposure, exr=not args.no_exr,
                          json_path=args.json)
    for item in plan_warnings(result.report):
        print(f"warning: {item['name']}: {item['reason'].removeprefix('WARNING: ')}", file=sys.stderr)
    if not args.quiet:
        print(f"rendered {args.scene} ({entry.name}) -> {', '.join(paths.values())}")
        print("  " + summary(result.report))
        stages = result.report["seconds"]
        print("  " + ", ".join(f"{k} {v:.2f} s" for k, v in stages.items())
              + f"; total {result.report['seconds_total']:.2f} s")
    return 0


def plan_warnings(report: dict) -> list[dict]:
    """The plan's items whose reason is a warning (a configuration where the model is known to be off), from a
    render's report; printed to stderr even with ``--quiet``."""
    plan = report.get("plan") or {}
    return [i for i in plan.get("items", ()) if i["reason"].startswith("WARNING")]


def summary(report: dict) -> str:
    """One line of the report's counts: resolution, shaded points and the method's own."""
    r = report
    parts = [f"{r['resolution'][0]}x{r['resolution'][1]}", f"{r['n_shaded_points']} shaded points"]
    if "n_samples" in r:
        parts.append(f"{r['n_samples']} samples")
    if "interactions_per_point_mean" in r:
        parts.append(f"{r['interactions_per_point_mean']:.1f} interactions per point (max "
                     f"{r['interactions_per_point_max']})")
    if "n_caches" in r:
        parts.append(f"{r['n_caches']} caches ({100 * r['cache_ratio']:.2f}% of the shaded points), estimated "
                     f"interpolation error mean {r['interpolation_error_estimate_mean']:.3g}, max "
                     f"{r['interpolation_error_estimate_max']:.3g}")
    if "n_photons" in r:
        parts.append(f"{r['n_photons']} photons, {r['n_sources']} sources ({r['n_interactions_multipole']} pairs "
                     f"with the multipole, {r['n_pairs_blocked']} blocked)")
    if "samples" in r:
        parts.append(f"{r['samples']} samples per view ray"
                     + ("; outer-layer diffusion" if "diffusion" in r else "; no diffusion term (see --explain)"))
    return ", ".join(parts)
