"""``jaxsss run``: the project's main job (``make run`` calls ``jaxsss run --out-dir out``).

The job is an ordered list of :class:`Step` s (:data:`STEPS`) sharing a :class:`RunContext`. Today:

1. ``reparam``: the reparameterisation table of every Jensen et al. 2001 material -- sigma_a, sigma_s' (1/mm), Rd
   and l_d (mm) per channel at the table's eta;
2. ``dipole_profiles``: their dipole profiles R_d(r) for r from 0.01 to 50 mm, plotted on log axes to
   ``OUT_DIR/dipole_profiles.png``.

Later steps (rendering, fitting) append to :data:`STEPS`; a step reads what earlier ones left in
``RunContext.results``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from jaxsss.cli._common import UNITS_EPILOG, CLIError, channel_labels, check_no_nan, fmt, format_table

NAME = "run"
HELP = "the main job: Jensen 2001 materials -> reparameterisation table and dipole profile plot"

TABLE = "jensen2001"
R_MIN_MM, R_MAX_MM, N_RADII = 0.01, 50.0, 200


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


STEPS: list[Step] = [
    Step("reparam", "reparameterisation table of the Jensen 2001 materials", step_reparam),
    Step("dipole_profiles", "plot of their dipole profiles", step_dipole_profiles),
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
    p.set_defaults(run=run)
    return p


def run(args) -> int:
    out_dir = Path(args.out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise CLIError(f"cannot create --out-dir {str(out_dir)!r}: {err.strerror or err}") from None
    ctx = RunContext(out_dir=out_dir)
    for i, step in enumerate(STEPS, 1):
        ctx.say(f"== step {i}/{len(STEPS)}: {step.name}: {step.description}")
        step.run(ctx)
        ctx.say()
    return 0
