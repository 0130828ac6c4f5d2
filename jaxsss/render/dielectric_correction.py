"""The curvature ratio's transport correction behind a dielectric boundary: a pencil beam's gain on a sphere over the
half-space, every order, with Fresnel at every crossing.

At a dielectric boundary (``eta != 1``) the white kernels hold every order of scattering, and their curvature ratio is
diffusion's (:mod:`jaxsss.render.curvature`: the dipole with Kelvin's image on a sphere over the plane, at the
boundary's ``A``, the source at the refracted depth). It was capped at a radius of ``6.7 l_u``
(:data:`jaxsss.render.curvature.KAPPA_MAX_ZR`), a knob chosen on images; under a sky at ``eta`` 1.33-1.4 that cap
left the red of chicken1 on a sphere of radius 20 mm (3.3 ``l_u``) 14% dark in sum, and lifting it alone made the
spheres too bright (docs/path_tracer.md, "Held out under the sky at a dielectric boundary").

This module measures what the ratio misses, as :mod:`jaxsss.render.curvature_correction` does at ``eta = 1``:

    Q(kappa l_u, d / l_u | mu_i, albedo, eta) = C_MC(d) / (C_Kelvin(d, kappa; depth mu_t, A(eta)) K(d)),

``C_MC`` a Fresnel walk's exitance at chord ``d`` on a sphere over the half-space's (every order >= 1;
:func:`jaxsss.render.walk.pencil_beam_walk` with ``eta``), ``C_Kelvin`` the diffusion ratio with no cap but the
chord's, ``K`` the cut beam's share (:func:`jaxsss.render.curvature_correction.renderer_model` at ``eta``). Tabulated
per incidence node (1, 0.5, 0.1, cosines outside), albedo, sphere radius (:data:`DIELECTRIC_RADII`, 1.47-25 ``l_u``)
and chord bin at the relative indices :data:`DIELECTRIC_ETAS`, linear in ``eta`` between them and held beyond.

Where it is used: the white kernels at ``eta != 1`` take the ratio to the table's smallest sphere
(:data:`KAPPA_MAX_DIELECTRIC`) and multiply it by ``min(Q, 1)``, the near part: there transport takes light away from
the ratio at a few transport lengths from the entry (``Q`` 0.85 at 2-4 ``l_u`` on a sphere of 4.94 ``l_u`` at 1.4,
albedo 0.97). The far part (``Q > 1``, light converging on the far side: 1.4 at 6-8 ``l_u`` there) is left out, as
from the light's side at ``eta = 1``: without an exit azimuth about the entry it puts the light where the eye sees the
terminator. Measured on seven sky scenes in docs/path_tracer.md ("At a dielectric boundary").

``python -m jaxsss.render.dielectric_correction --regenerate`` remakes ``data/dielectric_correction.npz``
(:data:`DIELECTRIC_PHOTONS` photons per walk, about 12 minutes per ``eta`` on one core).
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path

import numpy as np

from jaxsss.render.curvature_correction import (
    CORRECTION_D,
    CORRECTION_D_EDGES,
    CORRECTION_RADII,
    _tally,
    fit_curvature_correction,
)

__all__ = ["DIELECTRIC_ALBEDO", "DIELECTRIC_ETAS", "DIELECTRIC_KAPPA", "DIELECTRIC_MUS", "DIELECTRIC_PHOTONS",
           "DIELECTRIC_RADII", "DIELECTRIC_TABLE", "KAPPA_MAX_DIELECTRIC", "dielectric_log_correction_table",
           "generate_dielectric_correction", "load_dielectric_correction", "tally_eta"]

DIELECTRIC_ETAS = (1.1, 1.2, 1.3, 1.4, 1.5, 1.6)
"""Relative indices of the table, over the white Monte Carlo family's range (water 1.33, skin 1.4, wax and marble
1.44-1.5). Linear between them, held beyond (1.0-1.1 takes the first node)."""
DIELECTRIC_MUS = (1.0, 0.5, 0.1)
"""Incidence nodes of the dielectric tables (and of :mod:`jaxsss.render.dielectric_current`'s): the white-oblique
kernel's (1 and :data:`jaxsss.render.bssrdf.KERNEL_MUS`); the index-matched tables' node at 0.75 for lights behind
(:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`) has no dielectric walks yet."""
DIELECTRIC_ALBEDO = (0.3, 0.6, 0.8, 0.9, 0.97, 0.995)
"""Single-scattering albedos of the walks (linear in ``sqrt(1 - albedo)`` between, held beyond the ends): the
index-matched table's before its node at 0.999 (2026-12-02), which the Fresnel walks have not had (the near part
``Q < 1`` that is used here changes little above 0.97)."""
DIELECTRIC_PHOTONS = 200_000
"""Photons per walk: a fifth of the index-matched table's (every walk crosses a Fresnel boundary and is reflected
40-60% of the time, so a walk costs 2-3x as much; 12 minutes per ``eta`` on one core); the near part that is used sits
in bins of 10^3-10^5 photons."""
DIELECTRIC_RADII = CORRECTION_RADII + tuple(round(3.3 * 1.224**k, 2) for k in (-1, -2, -3, -4))
"""Sphere radii of the walks, transport lengths: the index-matched table's (24.9 down to 3.3) and four smaller ones
at the same ratio (2.7, 2.2, 1.8, 1.47): a teapot's handle and spout are that curved (its sums under a sky at 1.4 went
from 0.971 / 0.950 / 0.958 to 0.989 / 0.963 / 0.965 with them)."""
DIELECTRIC_KAPPA = (0.0,) + tuple(1.0 / a for a in DIELECTRIC_RADII)
"""Curvature nodes ``kappa l_u`` (0: the plane; linear between, held beyond ``1 / 1.47``)."""
KAPPA_MAX_DIELECTRIC = DIELECTRIC_KAPPA[-1]
"""The dielectric kernels' cap on the curvature, in units of ``sigma_t'``: the table's smallest sphere."""
DIELECTRIC_TABLE = Path(__file__).resolve().parent / "data" / "dielectric_correction.npz"


def tally_eta(eta: float, photons: int = DIELECTRIC_PHOTONS, seed: int = 47, progress: bool = True) -> dict:
    """``{"sphere": (U, A, R, 2, D), "plane": (U, A, 2, D), "log_q": (U, A, K, D)}`` at one ``eta``: the Fresnel
    walks on every node (the same seeds at every ``eta``: common random numbers) and their fit."""
    from jaxsss.render.walk import sphere_and_plane_tallies

    tally = functools.partial(_tally, eta=float(eta), min_order=1)
    sphere, plane = sphere_and_plane_tallies(tally, DIELECTRIC_MUS, DIELECTRIC_ALBEDO, DIELECTRIC_RADII, photons, seed,
                                             f"dielectric curvature correction, eta {eta:g}", progress)
    return {"sphere": sphere, "plane": plane,
            "log_q": fit_curvature_correction(sphere, plane, float(eta), DIELECTRIC_RADII, DIELECTRIC_MUS,
                                              DIELECTRIC_ALBEDO)}


def generate_dielectric_correction(photons: int = DIELECTRIC_PHOTONS, seed: int = 47, progress: bool = True) -> dict:
    """The table at every :data:`DIELECTRIC_ETAS`: ``log_q`` ``(E, U, A, K, D)``, the tallies and metadata."""
    t0 = time.perf_counter()
    parts = [tally_eta(eta, photons, seed, progress) for eta in DIELECTRIC_ETAS]
    return {**{k: np.stack([p[k] for p in parts]) for k in ("log_q", "sphere", "plane")},
            "eta": np.asarray(DIELECTRIC_ETAS), "mus": np.asarray(DIELECTRIC_MUS),
            "albedo": np.asarray(DIELECTRIC_ALBEDO), "radii": np.asarray(DIELECTRIC_RADII),
            "kappa": np.asarray(DIELECTRIC_KAPPA), "d": np.asarray(CORRECTION_D), "d_edges": CORRECTION_D_EDGES,
            "photons": photons, "seed": seed, "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk(eta): isotropic sphere and half-space behind a smooth "
                      "dielectric boundary, orders >= 1"}


def load_dielectric_correction() -> dict:
    """The shipped table (:data:`DIELECTRIC_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(DIELECTRIC_TABLE)


def dielectric_log_correction_table(r_lu, kappa_lu, mus, albedo, eta: float):
    """``(K, G, N, C)``: ``log Q`` at a concrete ``eta`` (linear between :data:`DIELECTRIC_ETAS`, held beyond), as
    :func:`jaxsss.render.curvature_correction.log_correction_table` (the same coordinates and interpolation)."""
    from jaxsss.render.curvature_correction import log_correction_table

    tab = load_dielectric_correction()
    w = np.interp(float(eta), tab["eta"], np.arange(len(tab["eta"])))
    lo = int(np.floor(w))
    hi, t = min(lo + 1, len(tab["eta"]) - 1), w - lo
    log_q = (1.0 - t) * tab["log_q"][lo] + t * tab["log_q"][hi]
    return log_correction_table(r_lu, kappa_lu, mus, albedo, log_q=log_q, kappa=DIELECTRIC_KAPPA,
                                table_mus=tuple(tab["mus"]), table_albedo=tuple(tab["albedo"]))


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.dielectric_correction", path=DIELECTRIC_TABLE,
        photons=DIELECTRIC_PHOTONS,
        description="The transport correction of the white kernels' curvature ratio behind a dielectric boundary "
                    "(jaxsss.render.dielectric_correction).",
        photons_help="photons per walk (15 spheres and a half-space per node and eta)",
        load=load_dielectric_correction,
        refit=lambda tab: {"log_q": np.stack([fit_curvature_correction(s, p, float(e), DIELECTRIC_RADII,
                                                                       tuple(tab["mus"]), tuple(tab["albedo"]))
                                              for s, p, e in zip(tab["sphere"], tab["plane"], tab["eta"])])},
        generate=generate_dielectric_correction,
        describe=lambda tab: (f"log Q {tab['log_q'].shape} (eta, mu_i, albedo, kappa l_u, d / l_u); "
                              f"{int(tab['photons'])} photons per walk, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
