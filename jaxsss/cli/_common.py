"""Shared pieces of the ``jaxsss`` command line: parsing, channel handling, printing and the error contract.

Error contract (DESIGN.md, "Bad input"): a user error prints ONE line ``jaxsss: error: ...`` on stderr and exits
with status 2 -- no traceback, and never a NaN in the output. :class:`CLIError` (raised by the commands), argparse's
own errors (routed through :class:`Parser`), and ``ValueError``/``TypeError`` from the library all end that way.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Iterable, Sequence

import numpy as np

from jaxsss.serialize import json_ready as to_json_value  # noqa: F401  (re-exported for the commands)

PROG = "jaxsss"
EXIT_USAGE = 2

UNITS_EPILOG = (
    "Units: lengths (r, l_d, thickness) in mm; coefficients (sigma_a, sigma_s', sigma_s, sigma_t) in 1/mm; "
    "profiles R(r), T(r) in 1/mm^2 per unit flux entering the medium; eta = n_inside / n_outside (relative "
    "index of the medium); Rd, alpha', g dimensionless."
)


class CLIError(Exception):
    """A user error: printed as one ``jaxsss: error: ...`` line, exit status 2."""


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors become :class:`CLIError` (one line, exit 2) instead of usage + message."""

    def error(self, message):  # noqa: D401 - argparse API
        sub = self.prog.removeprefix(PROG).strip()
        raise CLIError(f"{sub}: {message}" if sub else message)


def one_line(text: str) -> str:
    """Collapse whitespace so that a message fits the one-line error contract."""
    return " ".join(str(text).split())


def report_error(message: str) -> int:
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return EXIT_USAGE


def number(text: str) -> float:
    """argparse ``type``: a finite float (``nan`` and ``inf`` are rejected here, with the value)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"invalid number {text!r} (must be finite)")
    return value


FRESNEL_METHODS = ("poly", "exact")
"""The names of :data:`jaxsss.fresnel.F_DR_METHODS` (a test checks they agree): building the parser then needs no
JAX import (issue 18: start-up)."""


def add_fresnel_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fresnel",
        choices=list(FRESNEL_METHODS),
        default="poly",
        help="diffuse Fresnel reflectance F_dr(eta): 'poly' (Groenhuis/Egan-Hilgeman fits, as in the papers; "
        "default) or 'exact' (quadrature of the Fresnel equations)",
    )


def broadcast_channels(**values: Sequence[float] | None) -> tuple[int, dict[str, np.ndarray]]:
    """Broadcast per-channel options to a common channel count.

    Each given option holds 1 or N values; single values broadcast to N. Different counts above 1 are an error that
    names the options. ``None`` entries are skipped. Returns ``(N, {name: float64 array of shape (N,)})``.
    """
    given = {k: np.asarray(v, dtype=np.float64) for k, v in values.items() if v is not None}
    counts = {k: v.size for k, v in given.items()}
    n = max(counts.values(), default=1)
    bad = {k: c for k, c in counts.items() if c not in (1, n)}
    if bad:
        shown = ", ".join(f"{option_name(k)} has {c}" for k, c in counts.items())
        raise CLIError(f"mismatched channel counts ({shown}); give each option 1 value or the same number of values")
    return n, {k: np.broadcast_to(v, (n,)).copy() for k, v in given.items()}


def option_name(key: str) -> str:
    return "--" + key.replace("_", "-")


def channel_labels(n: int) -> list[str]:
    """Column labels for ``n`` channels: R, G, B for three, otherwise 0..n-1."""
    return ["R", "G", "B"] if n == 3 else [str(i) for i in range(n)]


def check_no_nan(values: dict[str, np.ndarray], what: str = "result") -> None:
    """Refuse to print a NaN (DESIGN.md): raise :class:`CLIError` naming the quantity."""
    for key, arr in values.items():
        if np.any(np.isnan(np.asarray(arr, dtype=np.float64))):
            raise CLIError(f"{what} {key} is not a number (NaN) for these inputs; refusing to print it")


def fmt(x: float, digits: int = 6) -> str:
    """A number for a table: ``inf`` for infinity, ``digits`` significant digits otherwise."""
    x = float(x)
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def print_json(obj: dict) -> None:
    """Print one JSON object (strict JSON: ``allow_nan=False`` guarantees no NaN/Infinity tokens)."""
    print(json.dumps(obj, allow_nan=False))


def format_table(header: Sequence[str], rows: Iterable[Sequence[str]], *, align_right_from: int = 1) -> str:
    """Align columns: the first ``align_right_from`` columns left-aligned (labels), the rest right-aligned."""
    rows = [list(map(str, r)) for r in rows]
    widths = [max(len(str(h)), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]

    def line(cells):
        out = [
            c.ljust(w) if i < align_right_from else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))
        ]
        return "  ".join(out).rstrip()

    return "\n".join([line(list(map(str, header))), *(line(r) for r in rows)])


def medium_from_args(args, *, need_eta: bool = True):
    """Build a :class:`~jaxsss.medium.Medium` from ``--material`` or ``--sigma-a``/``--sigma-s-prime``/``--eta``.

    Returns ``(medium, label)`` where ``label`` describes the source (material and table) or is ``None``.
    """
    from jaxsss.data import material
    from jaxsss.medium import Medium

    g = getattr(args, "g", None)
    if args.material is not None:
        if args.sigma_a is not None or args.sigma_s_prime is not None:
            raise CLIError("--material cannot be combined with --sigma-a/--sigma-s-prime")
        mat = material(args.material)
        eta = args.eta if args.eta is not None else mat.eta
        if eta is None:
            raise CLIError(f"material {mat.name!r} ({mat.table}) has no tabulated eta; pass --eta")
        return Medium(mat.sigma_a, mat.sigma_s_prime, eta, g, fresnel=args.fresnel), f"{mat.name} ({mat.table})"
    if args.sigma_a is None or args.sigma_s_prime is None:
        raise CLIError("give both --sigma-a and --sigma-s-prime (or --material NAME)")
    if args.eta is None and need_eta:
        raise CLIError("--eta is required (n_inside / n_outside)")
    _, ch = broadcast_channels(sigma_a=args.sigma_a, sigma_s_prime=args.sigma_s_prime)
    return Medium(ch["sigma_a"], ch["sigma_s_prime"], args.eta, g, fresnel=args.fresnel), None
