"""Regenerate (or list) the white Monte Carlo tables shipped in ``jaxsss/mc/data``.

``python -m jaxsss.mc.make_white_tables --regenerate [--g G --n N] [--photons N] [--path-max L] [--out DIR]``
runs the engine and writes the tables; ``--list`` prints the tables in ``--out`` with their metadata. Kept apart from
:mod:`jaxsss.mc.white` so that ``python -m`` does not re-import the module it runs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from jaxsss.mc.white import (
    GENERATION,
    STANDARD_PAIRS,
    TABLE_DIR,
    _seed,
    available_white_tables,
    generate_white_table,
    save,
    table_info,
)

def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m jaxsss.mc.make_white_tables",
        description="White (non-absorbing) Monte Carlo tables for jaxsss.mc.white_mc_profile. Each table is one "
        "half-space run with sigma_s = 1/mm, so radii and pathlengths are stored in optical units (1/sigma_s); "
        "R is per incident photon per unit area (specular excluded), binned over (r, pathlength).",
    )
    p.add_argument("--regenerate", action="store_true", help="run the engine and write the tables")
    p.add_argument("--g", type=float, default=None, help="one anisotropy (default: all shipped pairs)")
    p.add_argument("--n", type=float, default=None, help="one absolute index, ambient 1 (default: all shipped pairs)")
    p.add_argument("--photons", type=int, default=None,
                   help=f"photons per table (default: {GENERATION[0.0]['photons']} for g=0, "
                   f"{GENERATION[0.9]['photons']} for g=0.9)")
    p.add_argument("--path-max", type=float, default=None,
                   help="last pathlength edge, optical units (default: 1e4 for g=0, 3e4 for g=0.9)")
    p.add_argument("--out", type=Path, default=TABLE_DIR, help=f"directory for the .npz files (default {TABLE_DIR})")
    p.add_argument("--list", action="store_true", help="list the tables in --out with their metadata")
    args = p.parse_args(argv)
    if args.list or not args.regenerate:
        for g, n in available_white_tables(args.out):
            info = table_info(g, n, args.out)
            print(f"g={g:g} n={n:g}: photons={info['photons']} seconds={info['seconds']:.0f} "
                  f"R_diffuse={info['R_diffuse']:.5f}+-{info['R_diffuse_stderr']:.1e} lost={info['lost_weight']:.4f}")
        return 0
    pairs = [pr for pr in STANDARD_PAIRS if (args.g is None or pr[0] == args.g) and (args.n is None or pr[1] == args.n)]
    if not pairs:
        if args.g is None or args.n is None:
            print(f"error: no shipped pair matches g={args.g}, n={args.n}; give both --g and --n", file=sys.stderr)
            return 2
        pairs = [(args.g, args.n)]
    for g, n in pairs:
        gen = GENERATION.get(g, GENERATION[0.9] if g > 0.5 else GENERATION[0.0])
        photons = args.photons or gen["photons"]
        path_max = args.path_max or gen["path_max"]
        t0 = time.perf_counter()
        tab = generate_white_table(g, n, photons, path_max=path_max, seed=_seed(g, n),
                                   lanes=min(gen["lanes"], max(256, photons // 64)))
        path = save(tab, args.out)
        print(f"g={g:g} n={n:g}: {photons} photons in {time.perf_counter() - t0:.1f} s, R_diffuse="
              f"{tab['R_diffuse']:.5f}, lost weight {tab['lost_weight']:.4f}, {path.stat().st_size / 1024:.0f} KB "
              f"-> {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
