"""The ``jaxsss`` command line (console script ``jaxsss = "jaxsss.cli:main"``; also ``python -m jaxsss``).

Subcommands live in their own modules and register themselves through :data:`COMMANDS`:

- ``reparam`` (:mod:`jaxsss.cli.reparam`): (Rd, l_d) <-> (sigma_a, sigma_s');
- ``profile`` (:mod:`jaxsss.cli.profile`): a diffusion profile R(r) (and T(r)) as a table, JSON or plot;
- ``render`` (:mod:`jaxsss.cli.render`): render a TOML scene of a translucent mesh;
- ``export`` (:mod:`jaxsss.cli.export`): a scene and its material for Mitsuba 3 or pbrt-v4;
- ``fit``, ``mc``: fit a measured profile (CSV, NumPy or MCML ``.mco``); run the Monte Carlo reference;
- ``run`` (:mod:`jaxsss.cli.run`): the project's main job (``make run``).

User errors print one line ``jaxsss: error: ...`` on stderr and give exit status 2 (see :mod:`jaxsss.cli._common`).
"""

from __future__ import annotations

import sys

from jaxsss.cli import export, fit, mc, profile, render, reparam, run
from jaxsss.cli._common import PROG, UNITS_EPILOG, CLIError, Parser, report_error

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS = (reparam, profile, mc, fit, render, export, run)
"""Subcommand modules; each provides ``add_parser(subparsers)`` which sets ``run(args) -> int`` as a default."""


def build_parser(only: str | None = None) -> Parser:
    """The command line's parser; ``only``: build that subcommand's parser alone (the others' ``add_parser`` may
    import the library to list its registries, which a process running another command need not pay for)."""
    parser = Parser(
        prog=PROG,
        description="jaxsss: differentiable diffusion models of translucent materials.",
        epilog=UNITS_EPILOG,
    )
    from jaxsss import __version__

    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        if only is None or command.NAME == only:
            command.add_parser(subparsers)
    return parser


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); return the exit status.

    ``--help`` and ``--version`` exit through ``SystemExit(0)`` as usual with argparse.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    # A known subcommand first: build its parser alone (start-up, issue 18); anything else gets the full parser
    # (top-level --help, unknown commands listed with the valid ones).
    only = argv[0] if argv and argv[0] in {c.NAME for c in COMMANDS} else None
    parser = build_parser(only)
    try:
        args = parser.parse_args(argv)
        return int(args.run(args) or 0)
    # User errors: ours, argparse's (via Parser.error), and the library's boundary validation.
    except (CLIError, ValueError, TypeError) as err:
        return report_error(str(err))
    except BrokenPipeError:  # output piped into `head` and closed: not an error worth a traceback
        sys.stderr.close()
        return 0
