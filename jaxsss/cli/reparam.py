"""``jaxsss reparam``: convert between (Rd, l_d) and (sigma_a, sigma_s') with the dipole (hierarchical paper Eq. 15-16)."""

from __future__ import annotations

import argparse

import numpy as np

from jaxsss.cli._common import (
    UNITS_EPILOG,
    CLIError,
    add_fresnel_option,
    broadcast_channels,
    channel_labels,
    check_no_nan,
    fmt,
    format_table,
    medium_from_args,
    number,
    print_json,
    to_json_value,
)

NAME = "reparam"
HELP = "convert (Rd, l_d) <-> (sigma_a, sigma_s') per channel"

DESCRIPTION = """\
Forward:  --rd R [G B] --ld R [G B] --eta E [--g G]   ->  sigma_a, sigma_s', alpha' (and sigma_s, sigma_t with --g)
Reverse:  --sigma-a ... --sigma-s-prime ... --eta E   ->  Rd, l_d
Named:    --material NAME                             ->  Rd, l_d of a measured material (its table's eta unless
                                                          --eta is given; see --list-materials)

Per-channel options take 1 or N values (any N; with 3 the columns are labelled R G B). A single value broadcasts
to the channel count of the other option, so `--rd 0.5 --ld 1 2 3` gives three channels; two different counts
above 1 are an error. eta and g are single values, shared by all channels.

Uses the dipole's total diffuse reflectance Rd(alpha', A) (Jensen and Buhler 2002, Eq. 15) and
sigma_t' = sigma_tr / sqrt(3 (1 - alpha')) with sigma_tr = 1 / l_d (Eq. 16).

A non-absorbing medium (sigma_a = 0, e.g. spectralon) has Rd = 1 and an infinite l_d: the table prints `inf`
and --json prints `null`. NaN is never printed.

--json prints one object with keys sigma_a, sigma_s_prime, alpha_prime, rd, ld, eta (plus sigma_s and sigma_t
when --g is given); each value is a list with one number per channel (eta repeated per channel)."""

# (JSON key, table label, unit), in output order.
QUANTITIES = (
    ("sigma_a", "sigma_a", "1/mm"),
    ("sigma_s_prime", "sigma_s'", "1/mm"),
    ("alpha_prime", "alpha'", "-"),
    ("rd", "Rd", "-"),
    ("ld", "l_d", "mm"),
    ("eta", "eta", "-"),
    ("sigma_s", "sigma_s", "1/mm"),
    ("sigma_t", "sigma_t", "1/mm"),
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description=DESCRIPTION,
        epilog=UNITS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    fwd = p.add_argument_group("forward (intuitive -> physical)")
    fwd.add_argument("--rd", nargs="+", type=number, metavar="RD", help="total diffuse reflectance per channel, in (0, 1)")
    fwd.add_argument("--ld", nargs="+", type=number, metavar="LD", help="diffuse mean free path l_d per channel, mm, > 0")
    rev = p.add_argument_group("reverse (physical -> intuitive)")
    rev.add_argument("--sigma-a", nargs="+", type=number, metavar="SA", help="absorption coefficient per channel, 1/mm, >= 0")
    rev.add_argument(
        "--sigma-s-prime", nargs="+", type=number, metavar="SS", help="reduced scattering coefficient per channel, 1/mm, >= 0"
    )
    rev.add_argument("--material", metavar="NAME", help="a measured material by name (case-insensitive)")
    common = p.add_argument_group("common")
    common.add_argument("--eta", type=number, help="relative index n_inside / n_outside, > 0 (one value for all channels)")
    common.add_argument("--g", type=number, help="Henyey-Greenstein anisotropy in (-1, 1); adds sigma_s and sigma_t (1/mm)")
    add_fresnel_option(common)
    common.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    common.add_argument(
        "--list-materials", action="store_true", help="list the measured materials (name, table, eta) and exit"
    )
    p.set_defaults(run=run)
    return p


def _forward(args) -> tuple[dict[str, np.ndarray], str]:
    if args.rd is None or args.ld is None:
        raise CLIError("the forward conversion needs both --rd and --ld")
    if args.eta is None:
        raise CLIError("--eta is required (n_inside / n_outside)")
    n, ch = broadcast_channels(rd=args.rd, ld=args.ld)
    if args.fresnel == "poly":
        # The NumPy path (jaxsss.reparam_np, checked against the library to 1e-12): no JAX import, no compilation.
        from jaxsss.reparam_np import from_rd_ld as from_rd_ld_np

        out = from_rd_ld_np(ch["rd"], ch["ld"], args.eta, args.g)
        _check_converged(out.pop("converged"), n, ch)
        values = {k: np.broadcast_to(out[k], (n,)) for k, _, _ in QUANTITIES if k in out}  # _finish's order
        return values, f"forward: Rd, l_d -> coefficients (eta = {args.eta:g}, F_dr {args.fresnel})"
    from jaxsss.reparam import from_rd_ld

    rep = from_rd_ld(ch["rd"], ch["ld"], args.eta, args.g, fresnel=args.fresnel)
    _check_converged(np.asarray(rep.converged), n, ch)
    m = rep.medium
    out = {
        "sigma_a": m.sigma_a,
        "sigma_s_prime": m.sigma_s_prime,
        "alpha_prime": rep.alpha_prime,
        "rd": rep.rd,
        "ld": rep.ld,
    }
    return _finish(out, m, n), f"forward: Rd, l_d -> coefficients (eta = {args.eta:g}, F_dr {args.fresnel})"


def _check_converged(converged, n, ch) -> None:
    converged = np.broadcast_to(converged, (n,))
    if not np.all(converged):
        labels = channel_labels(n)
        bad = ", ".join(f"{labels[i]} (rd={ch['rd'][i]:g})" for i in np.flatnonzero(~converged))
        raise CLIError(f"the Rd inversion did not converge for channel(s) {bad}")


def _reverse(args) -> tuple[dict[str, np.ndarray], str]:
    from jaxsss.reparam import to_rd_ld

    m, label = medium_from_args(args)
    rd, ld = to_rd_ld(m)
    n = int(np.asarray(m.sigma_a).size)
    out = {
        "sigma_a": m.sigma_a,
        "sigma_s_prime": m.sigma_s_prime,
        "alpha_prime": m.alpha_prime,
        "rd": rd,
        "ld": ld,
    }
    eta = float(np.asarray(m.eta))
    title = f"reverse: coefficients -> Rd, l_d (eta = {eta:g}, F_dr {args.fresnel})"
    return _finish(out, m, n), (f"{label}, " + title if label else title)


def _finish(out: dict, medium, n: int) -> dict[str, np.ndarray]:
    out["eta"] = medium.eta
    if medium.g is not None:
        out["sigma_s"] = medium.sigma_s
        out["sigma_t"] = medium.sigma_t
    return {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)) for k, v in out.items()}


def _list_materials() -> int:
    from jaxsss.data import list_materials, material

    rows = []
    for name in list_materials():
        m = material(name)
        rows.append([m.name, m.table, "-" if m.eta is None else fmt(m.eta)])
    print(format_table(["name", "table", "eta"], rows, align_right_from=2))
    return 0


def run(args) -> int:
    if args.list_materials:
        return _list_materials()
    forward = args.rd is not None or args.ld is not None
    reverse = args.sigma_a is not None or args.sigma_s_prime is not None or args.material is not None
    if forward and reverse:
        raise CLIError("give either --rd/--ld (forward) or --sigma-a/--sigma-s-prime/--material (reverse), not both")
    if not (forward or reverse):
        raise CLIError("nothing to convert: give --rd and --ld, --sigma-a and --sigma-s-prime, or --material NAME")
    values, title = _forward(args) if forward else _reverse(args)
    check_no_nan(values)
    if args.json:
        print_json({k: to_json_value(v) for k, v in values.items()})
        return 0
    n = next(iter(values.values())).size
    rows = [[label, unit, *(fmt(x, 7) for x in values[key])] for key, label, unit in QUANTITIES if key in values]
    print(title)
    print(format_table(["quantity", "unit", *channel_labels(n)], rows, align_right_from=2))
    return 0
