"""Regenerate (or list) the oblique-incidence white Monte Carlo tables of the renderer's ``white`` BSSRDF.

``python -m jaxsss.render.make_oblique_tables --regenerate [--g G --n N] [--photons N] [--mu MU ...]`` runs
:func:`jaxsss.mc.white.generate_white_table` at the incidence cosines ``MU`` (in air) and writes each table to
``jaxsss/render/data/oblique_mu<MU>/`` under the usual white-table name, so that
:func:`jaxsss.mc.white.load_white_table` reads it with ``directory=``. Normal incidence (``mu = 1``) is the shipped
``jaxsss/mc/data`` table. ``--list`` prints what is there. ``--shifts`` measures the forward shift of oblique
profiles (:data:`jaxsss.render.bssrdf.SHIFT_RATIO`) and prints the table. See :mod:`jaxsss.render.bssrdf`.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from jaxsss.mc.white import GENERATION, _seed, generate_white_table, save, table_info
from jaxsss.render.bssrdf import OBLIQUE_MUS, SHIFT_ALBEDO, oblique_dir, oblique_pairs

PHOTONS = {0.0: 200_000, 0.9: 100_000}
"""Photons per oblique table (the normal-incidence tables have 1e6): the model interpolates between angles, so a
few per cent of noise in the far tail of one angle is averaged with its neighbours."""


def measure_shifts(albedos=SHIFT_ALBEDO, mus=OBLIQUE_MUS, photons: int = 100_000, g: float = 0.0, n: float = 1.0):
    """``(len(albedos), len(mus))``: the first moment of the exit positions along the beam, ``<x>``, over
    ``sin(theta_t) / sigma_t'``, from :func:`jaxsss.mc.simulate` runs (``sigma_s' = 1/mm``, ``R_xy`` on a 0.25 mm
    grid over +-40 mm; seed 5)."""
    import numpy as np

    from jaxsss.mc import Stack, simulate

    edges = np.linspace(-40.0, 40.0, 321)
    centres = 0.5 * (edges[1:] + edges[:-1])
    out = np.zeros((len(albedos), len(mus)))
    for i, ap in enumerate(albedos):
        sigma_a = (1.0 - ap) / ap
        for k, mu in enumerate(mus):
            angle = math.degrees(math.acos(mu))
            res = simulate(Stack.half_space(sigma_a, 1.0 / (1.0 - g), g, n), photons, seed=5, angle_deg=angle,
                           xy_edges=edges, progress=False)
            x = float((res.R_xy.sum(axis=1) * centres).sum() / res.R_xy.sum())
            sin_t = math.sin(math.radians(angle)) / n
            out[i, k] = x / (sin_t / (sigma_a + 1.0))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m jaxsss.render.make_oblique_tables",
                                description="Oblique-incidence white Monte Carlo tables (jaxsss.render.bssrdf).")
    p.add_argument("--regenerate", action="store_true", help="run the engine and write the tables")
    p.add_argument("--g", type=float, default=0.0, help="anisotropy (default 0)")
    p.add_argument("--n", type=float, default=1.0, help="absolute index, ambient 1 (default 1)")
    p.add_argument("--photons", type=int, default=None, help="photons per table (default: 2e5 for g = 0, 1e5 else)")
    p.add_argument("--mu", type=float, nargs="*", default=None,
                   help=f"incidence cosines in air (default: {' '.join(f'{m:g}' for m in OBLIQUE_MUS)})")
    p.add_argument("--shifts", action="store_true", help="measure the forward shifts (SHIFT_RATIO) and print them")
    args = p.parse_args(argv)
    if args.shifts:
        table = measure_shifts(photons=args.photons or 100_000, g=args.g, n=args.n)
        print(f"albedo rows {SHIFT_ALBEDO}, mu columns {OBLIQUE_MUS}")
        for ap, row in zip(SHIFT_ALBEDO, table):
            print(f"{ap:5g}: " + ", ".join(f"{v:.3f}" for v in row))
        return 0
    if not args.regenerate:
        for g, n in oblique_pairs():
            for mu in OBLIQUE_MUS:
                try:
                    info = table_info(g, n, oblique_dir(mu))
                except ValueError:
                    continue
                print(f"g={g:g} n={n:g} mu={mu:g}: photons={info['photons']} seconds={info['seconds']:.0f} "
                      f"R_diffuse={info['R_diffuse']:.5f} lost={info['lost_weight']:.4f}")
        return 0
    gen = GENERATION.get(args.g, GENERATION[0.9] if args.g > 0.5 else GENERATION[0.0])
    photons = args.photons or PHOTONS.get(args.g, 100_000)
    for mu in args.mu or OBLIQUE_MUS:
        t0 = time.perf_counter()
        angle = math.degrees(math.acos(mu))
        tab = generate_white_table(args.g, args.n, photons, path_max=gen["path_max"],
                                   seed=_seed(args.g, args.n) + round(1000 * mu),
                                   lanes=min(gen["lanes"], max(256, photons // 64)), angle_deg=angle)
        path = save(tab, oblique_dir(mu))
        print(f"g={args.g:g} n={args.n:g} mu={mu:g} ({angle:.2f} deg): {photons} photons in "
              f"{time.perf_counter() - t0:.1f} s, R_diffuse={tab['R_diffuse']:.5f}, lost {tab['lost_weight']:.4f} "
              f"-> {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
