"""The exit's current behind a smooth dielectric boundary: the table of Fresnel walks.

Light that reaches a point of the surface from an entry some transport lengths away is moving away from that entry,
and it leaves brighter in the directions that point along its flow than against it (:mod:`jaxsss.render.exit_current`,
where the index-matched orders >= 2 are tabulated). Behind a dielectric boundary the white kernels hold every order
and leave by the refracted exit (:func:`jaxsss.render.bssrdf.refracted_exit_distribution`), which depends on the exit
cosine only. Transport does not: on a point-lit sphere of chicken1 at ``eta = 1.4`` (radius 3.3 / 5.7 / 11 ``l_u``), a
Fresnel walk's radiance towards the camera, which sees the terminator from the light's side and so looks against the
flow, is 0.67-0.79 (red) and 0.41-0.72 (green) of its azimuthal mean in the bands from the terminator into the shadow.
Under a sky the same loss sits on the shadowed lower side of the held-out spheres, which were 10-30% too bright per
pixel in red there (docs/path_tracer.md, "Behind a dielectric boundary: the exit's current").

This module tabulates the current for those kernels as :mod:`jaxsss.render.exit_current` does at ``eta = 1``: a
pencil beam on the half-space (:func:`jaxsss.render.walk.pencil_beam_walk` with ``eta``: Fresnel at the entry and at
every crossing), every order, the radiance's first azimuthal harmonic about the entry fitted as ``a(d / l_u) psi(mu_o)``
per incidence node (1, 0.5, 0.1; cosines outside) and albedo, the exit cosine ``mu_o`` taken outside (Snell keeps the
azimuth). The table holds the relative indices :data:`jaxsss.render.dielectric_correction.DIELECTRIC_ETAS` (1.1-1.6),
linear in ``eta`` between them and held beyond (:func:`jaxsss.render.exit_current.current_amplitude` and
:func:`~jaxsss.render.exit_current.current_exit_distribution` with ``eta``).

The kernel keeps the current with both signs: ``L = max(L_M + t_o . J Y, 0)``
(:func:`jaxsss.render.bssrdf.current_radiance` with ``along_only=False``). At ``eta = 1`` the part against the flow is
left out, because there the kernels' exitance is short by about as much; behind the boundary the curvature ratio's
transport correction (:mod:`jaxsss.render.dielectric_correction`) has brought that exitance to within 1-8% of the walk's
at the terminator (0.65-0.88 of it deeper in the shadow), and the loss towards the eye is the larger error.

``python -m jaxsss.render.dielectric_current --regenerate`` remakes ``data/dielectric_current.npz``
(:data:`jaxsss.render.exit_current.CURRENT_PHOTONS` photons per walk, about 2.5 minutes per ``eta`` on one core).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["DIELECTRIC_CURRENT_TABLE", "generate_dielectric_current_table", "load_dielectric_current_table"]

DIELECTRIC_CURRENT_TABLE = Path(__file__).resolve().parent / "data" / "dielectric_current.npz"


def generate_dielectric_current_table(photons: int | None = None, seed: int = 53, progress: bool = True) -> dict:
    """The walks of :func:`jaxsss.render.exit_current.generate_exit_current_table` behind a smooth dielectric boundary
    at every :data:`jaxsss.render.dielectric_correction.DIELECTRIC_ETAS` (the same seeds at every ``eta``: common
    random numbers): ``ab`` ``(E, U, A, D, 2)``, ``psi`` ``(E, U, A, B)``, the tallies ``(E, U, A, 4, D, B)`` and
    metadata. ``photons`` per walk (None: :data:`jaxsss.render.exit_current.CURRENT_PHOTONS`)."""
    from jaxsss.render.dielectric_correction import DIELECTRIC_ETAS, DIELECTRIC_MUS
    from jaxsss.render.exit_current import CURRENT_PHOTONS, generate_exit_current_table

    photons = CURRENT_PHOTONS if photons is None else photons
    t0 = time.perf_counter()
    parts = [generate_exit_current_table(photons, seed, progress, eta, table_mus=DIELECTRIC_MUS)
             for eta in DIELECTRIC_ETAS]
    return {**_fit(np.stack([p["tallies"] for p in parts]), DIELECTRIC_MUS),
            **{k: parts[0][k] for k in ("mus", "albedo", "d", "d_edges", "mu_edges", "photons", "seed")},
            "eta": np.asarray(DIELECTRIC_ETAS), "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk(eta): isotropic half-space behind a smooth dielectric "
                      "boundary, orders >= 1, exit cosines outside"}


def _fit(tallies: np.ndarray, mus) -> dict:
    """``{"ab", "psi", "tallies"}``: the tallies ``(E, U, A, 4, D, B)`` kept in float32 (half the table's size), and
    :func:`jaxsss.render.exit_current.fit_exit_current` per ``eta`` from those, so that ``--refit`` gives them back."""
    from jaxsss.render.exit_current import fit_exit_current

    tallies = np.asarray(tallies, np.float32)
    fits = [fit_exit_current(t.astype(np.float64), mus) for t in tallies]
    return {"ab": np.stack([f[0] for f in fits]), "psi": np.stack([f[1] for f in fits]), "tallies": tallies}


def load_dielectric_current_table() -> dict:
    """The shipped table (:data:`DIELECTRIC_CURRENT_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(DIELECTRIC_CURRENT_TABLE)


def main(argv=None) -> int:
    from jaxsss.render.exit_current import CURRENT_PHOTONS
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.dielectric_current", path=DIELECTRIC_CURRENT_TABLE,
        photons=CURRENT_PHOTONS,
        description="The azimuthal (current) term of the white kernels' exit behind a smooth dielectric boundary, "
                    "every order (jaxsss.render.dielectric_current).",
        photons_help="photons per (eta, incidence, albedo) walk", load=load_dielectric_current_table,
        refit=lambda tab: _fit(tab["tallies"], tuple(tab["mus"])),
        generate=generate_dielectric_current_table,
        describe=lambda tab: (f"a, b {tab['ab'].shape} (eta, mu_i, albedo, d / l_u, a|b), psi {tab['psi'].shape} "
                              f"(eta, mu_i, albedo, mu_o bin outside) at eta {tab['eta'].tolist()}; "
                              f"{int(tab['photons'])} photons per walk, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
