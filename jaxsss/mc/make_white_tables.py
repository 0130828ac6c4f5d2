"""Regenerate (or list) the white Monte Carlo tables shipped in ``jaxsss/mc/data``.

``python -m jaxsss.mc.make_white_tables --family [--g G --n N] [--photons N] [--out DIR]`` generates the nodes of the
``(g, n)`` family of :mod:`jaxsss.mc.white_family` (default: every node of the grid that has no file yet, in order of
g; the nodes at g = 0 for n = 1 and 1.4 are re-binned from the single-pair tables, whose grids fall on the common
one). ``--family --list`` prints each node's photons, events and run seconds.

Cost of the shipped family (generated 2026-11-23 on the 2-core AMD EPYC machine, 2 JAX CPU devices, ``nice -n 10``
beside 3-4 other jobs, load average 8-16; run seconds exclude compilation, ~10-60 s per g under that load): two
pooled runs per node (``--family`` then ``--family --add 1``), 6e5 photons for g <= 0.8 and 3e5 for g = 0.9 and
0.95. Engine run time per node: g = 0: 20-28 s; 0.3: 23-43 s; 0.6: 39-77 s; 0.8: 73-125 s; 0.9: 63-117 s; 0.95:
104-156 s (higher n costs more: internal reflections); events per photon 124-236 at g = 0 up to 2200-4600 at
g = 0.95. The 40 generated nodes: 3000 s in all. The nodes g = 0, n = 1.0 and 1.4 are re-binned 10^6-photon tables
(216 s and 431 s with the older kernel). ``--family --list`` prints each node's figures.
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
    p.add_argument("--family", action="store_true", help="generate the (g, n) family's nodes (jaxsss.mc.white_family)")
    p.add_argument("--devices", type=int, default=None, help="JAX CPU devices to split photons over (default: cores)")
    p.add_argument("--add", type=int, default=0, metavar="K",
                   help="with --family: add a run of --photons (default: twice white_family.node_photons) with seed offset K "
                   "to every existing node and pool it (white_family.merge_nodes)")
    args = p.parse_args(argv)
    if args.family:
        return _family(args)
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


def _family(args) -> int:
    from jaxsss.mc import white_family as wf
    from jaxsss.mc.engine import use_cpu_devices

    out = wf.FAMILY_DIR if args.out == TABLE_DIR else args.out
    if args.list:
        for p in sorted(out.glob("node_g*_n*.npz")):
            t = wf.load_node(p)
            src = f", re-binned from {t['source']}" if "source" in t else ""
            print(f"g={t['g']:g} n={t['n']:g}: photons={int(t['photons'])} events={int(t['events']):.3g} "
                  f"seconds={float(t['seconds']):.0f} devices={int(t['devices'])} R_diffuse={float(t['R_diffuse']):.5f}"
                  f"{src} ({p.stat().st_size / 1024:.0f} KB)")
        return 0
    use_cpu_devices(args.devices)
    nodes = [(g, n) for g in wf.G_NODES for n in wf.N_NODES]
    if args.g is not None or args.n is not None:
        if args.g is None or args.n is None:
            print("error: --family with --g needs --n too (one node)", file=sys.stderr)
            return 2
        nodes = [(args.g, args.n)]
    for g, n in nodes:
        path = out / wf.node_file(g, n)
        if args.add:
            if not path.exists():
                continue
            old = wf.load_node(path)
            if "source" in old:  # re-binned from a 10^6-photon single-pair table
                continue
            t0 = time.perf_counter()
            extra = wf.generate_node(g, n, args.photons or 2 * wf.node_photons(g),
                                     seed=wf.node_seed(g, n) + 7919 * args.add)
            tab = wf.merge_nodes(old, extra)
            wf.save_node(tab, out)
            print(f"g={g:g} n={n:g}: +{extra['photons']} photons ({extra['seconds']:.0f} s run, "
                  f"{time.perf_counter() - t0:.0f} s here) -> {tab['photons']} photons, {tab['seconds']:.0f} s in all",
                  flush=True)
            continue
        if path.exists() and args.g is None:
            continue
        old = TABLE_DIR / f"white_g{g:.2f}_n{n:.2f}.npz"
        t0 = time.perf_counter()
        tab = None
        if old.exists() and args.photons is None:
            try:
                tab = wf.node_from_white_table(old)
            except ValueError as e:  # its pathlength grid is not on the common one (g = 0.9: 3e4 optical units)
                print(f"g={g:g} n={n:g}: not re-binned ({e}); generating", flush=True)
        if tab is None:
            tab = wf.generate_node(g, n, args.photons or wf.node_photons(g))
        path = wf.save_node(tab, out)
        print(f"g={g:g} n={n:g}: {tab['photons']} photons, {tab['events']:.3g} events, {tab['seconds']:.0f} s run "
              f"({time.perf_counter() - t0:.0f} s here), R_diffuse={tab['R_diffuse']:.5f}, "
              f"{path.stat().st_size / 1024:.0f} KB -> {path}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
