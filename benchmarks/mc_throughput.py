"""Monte Carlo throughput: photons per second at albedo 0.9 and 0.999 (half-space and slab), and error vs photons.

Media (n = 1, g = 0, sigma_t = 1/mm): a half-space, and a slab of optical thickness 2. Rows:

- ``throughput``: one run of ``N`` photons per (geometry, albedo) after a warm-up run that compiles the kernel
  (``compile_seconds`` is that warm-up's compile time, apart); ``error`` is the run's own standard error of R_diffuse.
- ``sweep``: the van de Hulst slab (a = 0.9, b = 2, g = 0.75; R = 0.09739, T = 0.66096) at increasing photon
  counts; ``error`` = |R - 0.09739| + |T - 0.66096| against run time, with the standard errors beside it.

The peer is MCML's C program: about 0.3-11 s per 1e6 photons on one core, depending on albedo. For a per-core figure
run ``taskset -c 0 python -m benchmarks.mc_throughput --tag _1core``.
"""

from __future__ import annotations

import sys

from benchmarks._harness import make_row, parse_args, write_results
from jaxsss.mc import Stack, simulate
from jaxsss.mc.engine import _auto_lanes

NAME = "mc_throughput"
CONFIG = {"quick": {"photons": {0.9: 100_000, 0.999: 10_000}, "sweep": [10_000, 30_000, 100_000]},
          "full": {"photons": {0.9: 1_000_000, 0.999: 100_000}, "sweep": [10_000, 100_000, 1_000_000, 3_000_000]}}


def run(quick: bool):
    cfg = CONFIG["quick" if quick else "full"]
    rows, summary = [], {}
    for geometry in ("half-space", "slab b=2"):
        for albedo, n in cfg["photons"].items():
            if geometry == "half-space":
                stack = Stack.half_space(1.0 - albedo, albedo, 0.0, 1.0)
            else:
                stack = Stack.slab(1.0 - albedo, albedo, 0.0, 1.0, 2.0)
            lanes = _auto_lanes(n)  # the warm-up compiles the very kernel the timed run uses
            warm = simulate(stack, 1000, seed=0, lanes=lanes, progress=False)
            res = simulate(stack, n, seed=1, lanes=lanes, progress=False)
            pps = n / res.seconds
            setting = f"{geometry} a={albedo}"
            print(f"  {setting:22s} {n:>9d} photons {res.seconds:7.2f} s  {pps:10.0f} photons/s  "
                  f"{res.events / n:8.1f} events/photon  compile {warm.compile_seconds:.2f} s", flush=True)
            rows.append(make_row(NAME, "throughput " + geometry, setting, res.R_diffuse_stderr,
                                 "stderr of R_diffuse", res.seconds, warm.compile_seconds, photons=n,
                                 photons_per_second=pps, seconds_per_1e6_photons=1e6 / pps,
                                 events_per_photon=res.events / n, lanes=lanes, events_per_second=res.events / res.seconds,
                                 R_diffuse=res.R_diffuse, T=res.T))
            summary[setting] = {"photons_per_second": pps, "seconds_per_1e6_photons": 1e6 / pps}
    stack = Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0)
    for n in cfg["sweep"]:
        warm = simulate(stack, 1000, seed=0, lanes=_auto_lanes(n), progress=False)
        res = simulate(stack, n, seed=2, lanes=_auto_lanes(n), progress=False)
        err = abs(res.R_diffuse - 0.09739) + abs(res.T - 0.66096)
        rows.append(make_row(NAME, "van de Hulst slab", n, err, "|R - R_ref| + |T - T_ref|", res.seconds,
                             warm.compile_seconds, photons=n, R=res.R_diffuse, R_stderr=res.R_diffuse_stderr,
                             T=res.T, T_stderr=res.T_stderr))
        print(f"  sweep {n:>9d} photons {res.seconds:7.2f} s  error {err:.2e}  (stderr R {res.R_diffuse_stderr:.1e}, "
              f"T {res.T_stderr:.1e})", flush=True)
    return rows, summary


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    rows, summary = run(args.quick)
    notes = ["seconds: wall time of one simulate() call after a compiling warm-up; compile_seconds: the warm-up's "
             "compile time", "peer: MCML C, ~0.3-11 s per 1e6 photons per core depending on albedo"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="Monte Carlo: error vs seconds", connect=True)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
