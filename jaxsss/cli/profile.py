"""``jaxsss profile``: a diffusion profile R(r) (and T(r) for slabs) as a table, JSON, or a log-scale plot."""

from __future__ import annotations

import argparse
from typing import Callable, NamedTuple

import numpy as np

from jaxsss.cli._common import (
    UNITS_EPILOG,
    CLIError,
    add_fresnel_option,
    channel_labels,
    check_no_nan,
    fmt,
    format_table,
    medium_from_args,
    number,
    print_json,
    to_json_value,
)

NAME = "profile"
HELP = "diffusion profile R(r) (and T(r) for a slab) per channel"


class ProfileModel(NamedTuple):
    """A registered profile model: ``evaluate(r, medium, thickness) -> {"R": (N, C), ...}`` in 1/mm^2."""

    name: str
    summary: str
    needs_thickness: bool
    evaluate: Callable


def _dipole(r, medium, thickness):
    from jaxsss.profiles.dipole import dipole_profile

    return {"R": dipole_profile(r[:, None], medium)}


def _multipole(r, medium, thickness):
    # Imported lazily: the CLI works (for the other models) without the multipole module.
    try:
        from jaxsss.profiles.multipole import multipole_profile
    except ImportError as err:
        raise CLIError(f"the multipole model is not available in this installation ({err})") from None
    R, T = multipole_profile(r[:, None], medium, thickness)
    return {"R": R, "T": T}


MODELS: dict[str, ProfileModel] = {
    m.name: m
    for m in (
        ProfileModel("dipole", "semi-infinite medium (Jensen et al. 2001); R only", False, _dipole),
        ProfileModel("multipole", "slab of --thickness mm (Donner and Jensen 2005); R and T", True, _multipole),
    )
}
"""Registry of profile models, by name (the ``--model`` choices)."""

DESCRIPTION = """\
Evaluate a diffusion profile at the radii given by --r: the radiant exitance R(r) leaving the lit surface (and
T(r) leaving the far surface of a slab), per unit flux entering the medium at r = 0, in 1/mm^2.

Models:
""" + "\n".join(f"  {m.name:10s} {m.summary}" for m in MODELS.values()) + """

The medium comes from --sigma-a/--sigma-s-prime (1 or N values each; a single value broadcasts) with --eta, or
from --material NAME (its table's eta unless --eta is given).

--json prints one object with keys r (list of radii, mm) and R (and T for the multipole): R[i] is the value at
r[i] -- a number for a single channel, or a list with one number per channel. --plot FILE.png saves R (and T)
against r on a log y axis, one line per channel."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description=DESCRIPTION,
        epilog=UNITS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--model", choices=list(MODELS), default="dipole", help="profile model (default: dipole)")
    p.add_argument("--sigma-a", nargs="+", type=number, metavar="SA", help="absorption coefficient per channel, 1/mm, >= 0")
    p.add_argument(
        "--sigma-s-prime", nargs="+", type=number, metavar="SS", help="reduced scattering coefficient per channel, 1/mm, >= 0"
    )
    p.add_argument("--material", metavar="NAME", help="a measured material by name (see `jaxsss reparam --list-materials`)")
    p.add_argument("--eta", type=number, help="relative index n_inside / n_outside, > 0")
    p.add_argument("--thickness", type=number, metavar="D", help="slab thickness, mm, > 0 (multipole only; required there)")
    p.add_argument("--r", nargs="+", type=number, required=True, metavar="R", help="radii, mm, >= 0")
    add_fresnel_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--plot", metavar="FILE.png", help="also save a log-scale plot of the profile to FILE.png")
    p.set_defaults(run=run)
    return p


def _labels(quantity: str, n: int) -> list[str]:
    return [quantity] if n == 1 else [f"{quantity}[{c}]" for c in channel_labels(n)]


def _plot(path, r, values, n, model, title):
    from jaxsss.cli._plot import plot_channels, pyplot, save

    plt = pyplot()
    keys = list(values)
    fig, axes = plt.subplots(1, len(keys), figsize=(5.0 * len(keys), 4.0), squeeze=False)
    for ax, key in zip(axes[0], keys):
        plot_channels(ax, r, values[key], channel_labels(n) if n > 1 else [key])
        ax.set_xlabel("r [mm]")
        ax.set_ylabel(f"${key}(r)$ [1/mm$^2$]")
        ax.set_title(f"{model}: {'reflectance' if key == 'R' else 'transmittance'} {key}(r)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(title="channel" if n > 1 else None)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save(fig, path)


def run(args) -> int:
    from jaxsss.validate import check_range

    model = MODELS[args.model]
    if model.needs_thickness and args.thickness is None:
        raise CLIError(f"--model {model.name} needs --thickness D (slab thickness, mm)")
    if not model.needs_thickness and args.thickness is not None:
        raise CLIError(f"--thickness applies to slab models only, not --model {model.name}")
    if args.thickness is not None:
        check_range(args.thickness, "thickness", 0.0, None, lo_open=True)
    r = np.asarray(check_range(np.asarray(args.r, dtype=np.float64), "r", 0.0, None))
    medium, label = medium_from_args(args)
    n = int(np.asarray(medium.sigma_a).size)
    values = {k: np.asarray(v, dtype=np.float64).reshape(len(r), n) for k, v in model.evaluate(r, medium, args.thickness).items()}
    check_no_nan(values, what=f"{model.name} profile")
    eta = float(np.asarray(medium.eta))
    title = f"{model.name} profile, eta = {eta:g}" + (f", thickness {args.thickness:g} mm" if args.thickness else "")
    if label:
        title = f"{label}: {title}"
    if args.json:
        squeeze = (lambda v: v[:, 0]) if n == 1 else (lambda v: v)
        print_json({"r": to_json_value(r), **{k: to_json_value(squeeze(v)) for k, v in values.items()}})
    else:
        header = ["r [mm]"] + [h for k in values for h in _labels(k, n)]
        rows = [[fmt(r[i])] + [fmt(x) for v in values.values() for x in v[i]] for i in range(len(r))]
        print(f"{title}; {', '.join(values)} in 1/mm^2 per unit flux entering")
        print(format_table(header, rows, align_right_from=0))
    if args.plot:
        path = _plot(args.plot, r, values, n, model.name, title)
        if not args.json:
            print(f"wrote {path}")
    return 0
