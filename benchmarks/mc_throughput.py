"""Monte Carlo throughput: the engine against MCML's C program and against its own earlier kernel, 1 vs 2 devices,
and the start-up of ``jaxsss mc``.

Rows:

- ``mcml <case>``: three media with MCML figures (MCML 1.2.2, ``gcc -O3``, one core of this 2-core machine,
  2026-11; :data:`MCML`): skin1 green and marble green half-spaces (Jensen et al. 2001 coefficients, g = 0), and the
  0.3 mm slab with g = 0.9 of ``/work/shared/reference/mcml/slab03mm_n133_g09``. Each is run, after a compiling
  warm-up, by (a) this engine on one device, (b) this engine on every device (one per core), (c) the engine's
  earlier kernel (commit ``OLD_COMMIT``, loaded from git into a temporary module) on one device -- interleaved
  round-robin, best of ``repeats``, so that the ratios hold on a shared machine. ``events_per_second_per_core``
  divides by the number of devices. ``ratio_to_mcml`` = seconds per photon / MCML's (goal: below 1 on both cores).
  With ``JAXSSS_MCML=/path/to/mcml`` (a locally built MCML 1.2.2; not part of the project), MCML itself is timed in
  the same run as well.
- ``cli vs api``: run time (without compilation) of ``jaxsss mc`` and of ``simulate()`` for 2e5 photons, each in a
  fresh process with one device per core.
- ``startup``: wall and CPU time of a whole ``jaxsss mc`` process (1000 photons) with an empty compilation cache
  (cold), the same cache again (warm), and the cache off; and of ``import jaxsss.cli`` alone.
- ``throughput`` and ``van de Hulst slab``: the albedo sweep and error-versus-photons rows of the earlier version of
  this benchmark (n = 1, g = 0, sigma_t = 1/mm; on every device).

For the 1- versus 2-device scaling the process asks JAX for one CPU device per usable core before JAX starts.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

from jaxsss.mc.engine import use_cpu_devices

if __name__ == "__main__":  # before JAX starts its backend: one CPU device per core
    use_cpu_devices()

import jax  # noqa: E402

from benchmarks._harness import make_row, parse_args, write_results  # noqa: E402
from jaxsss.mc import Stack, simulate  # noqa: E402
from jaxsss.mc import engine  # noqa: E402
from jaxsss.mc.engine import _auto_lanes  # noqa: E402

NAME = "mc_throughput"
ROOT = Path(__file__).resolve().parents[1]
OLD_COMMIT = "8064d56"  # the engine before issue 19 (kernel with in-place tallies)

MCML = {
    # case: (stack arguments, MCML seconds per 1e6 photons, source of the figure)
    "skin1 green": (("half_space", 0.17, 0.88, 0.0, 1.3), 1.73, "issue 19: MCML 1.2.2 gcc -O3, one core, 2026-11"),
    "marble green": (("half_space", 0.0041, 2.62, 0.0, 1.5), 30.3, "issue 19: MCML 1.2.2 gcc -O3, one core, 2026-11"),
    "slab 0.3 mm g=0.9": (("slab", 0.1, 20.0, 0.9, 1.33, 0.3), 2.8 / 2.0,
                          "reference/mcml/slab03mm_n133_g09.csv: 2e6 photons in 2.8 s, one core, 2026-11"),
}
MCML_MACHINE = "this 2-core AMD EPYC machine (shared), one core, MCML 1.2.2 built with gcc -O3, 2026-11"
CONFIG = {
    "quick": {"mcml_photons": {"skin1 green": 100_000, "marble green": 10_000, "slab 0.3 mm g=0.9": 200_000},
              "repeats": 1, "photons": {0.9: 100_000, 0.999: 10_000}, "sweep": [10_000, 100_000]},
    "full": {"mcml_photons": {"skin1 green": 1_000_000, "marble green": 200_000, "slab 0.3 mm g=0.9": 1_000_000},
             "repeats": 2, "photons": {0.9: 1_000_000, 0.999: 100_000}, "sweep": [10_000, 100_000, 1_000_000]},
}


def _stack(args) -> Stack:
    kind, *coef = args
    return getattr(Stack, kind)(*coef)


def old_kernel():
    """The engine's kernel at ``OLD_COMMIT``, jitted, from ``git show`` into a temporary module."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{OLD_COMMIT}:jaxsss/mc/_kernel.py"], check=True,
                         capture_output=True, text=True).stdout
    mod = types.ModuleType("jaxsss_mc_kernel_" + OLD_COMMIT)
    exec(compile(src, mod.__name__, "exec"), mod.__dict__)
    return jax.jit(mod.batch_kernel, static_argnums=0)


def _run(stack, n, seed, devices, kernel=None):
    """``simulate`` on ``devices`` (after a compiling warm-up); ``kernel``: a replacement jitted kernel (1 device)."""
    saved = engine._jitted, engine._COMPILED
    if kernel is not None:
        engine._jitted, engine._COMPILED = kernel, {}
    try:
        lanes = _auto_lanes(max(n // devices, 1))
        warm = simulate(stack, min(n, 2000), seed=0, devices=devices, lanes=lanes, progress=False)
        c0 = time.process_time()
        res = simulate(stack, n, seed=seed, devices=devices, lanes=lanes, progress=False)
        return res, warm.compile_seconds, time.process_time() - c0
    finally:
        engine._jitted, engine._COMPILED = saved


def _mcml_run(binary: str, stack_args, n: int) -> float | None:
    """Seconds of a local MCML binary for ``n`` photons of a one-layer medium (None when it fails)."""
    kind, sa, ss, g, n_idx, *d = stack_args
    thick_cm = d[0] / 10.0 if d else 1e8
    with tempfile.TemporaryDirectory() as tmp:
        mci = Path(tmp) / "case.mci"
        mci.write_text(f"1.0\n1\n{tmp}/case.mco A\n{n}\n0.01 0.01\n1 200 1\n1\n1.0\n"
                       f"{n_idx} {sa * 10} {ss * 10} {g} {thick_cm}\n1.0\n")
        t0 = time.perf_counter()
        proc = subprocess.run(["taskset", "-c", "0", binary, str(mci)], capture_output=True, text=True, cwd=tmp)
        dt = time.perf_counter() - t0
    return dt if proc.returncode == 0 else None


def mcml_rows(cfg) -> tuple[list, dict]:
    rows, summary = [], {}
    n_dev = len(jax.devices())
    old = old_kernel()
    mcml_bin = os.environ.get("JAXSSS_MCML")
    for case, (args, mcml_s, source) in MCML.items():
        stack, n = _stack(args), cfg["mcml_photons"][case]
        variants = {"engine, 1 device": dict(devices=1), f"engine, {n_dev} devices": dict(devices=n_dev),
                    f"engine {OLD_COMMIT} (before), 1 device": dict(devices=1, kernel=old)}
        if n_dev == 1:  # JAX already ran with one CPU device (e.g. under run_all after another benchmark)
            del variants["engine, 1 devices"]
        best = {}
        for rep in range(cfg["repeats"]):
            for label, kw in variants.items():
                res, comp, cpu = _run(stack, n, seed=1 + rep, **kw)
                if label not in best or res.seconds < best[label][0].seconds:
                    best[label] = (res, comp, cpu)
        local_mcml = None
        if mcml_bin:
            local_mcml = min(filter(None, (_mcml_run(mcml_bin, args, n) for _ in range(cfg["repeats"]))),
                             default=None)
        one = best["engine, 1 device"][0].seconds
        old_s = best[f"engine {OLD_COMMIT} (before), 1 device"][0].seconds
        for label, (res, comp, cpu) in best.items():
            s6 = 1e6 * res.seconds / n
            extra = dict(photons=n, devices=res.devices, lanes=res.lanes, seconds_per_1e6_photons=s6,
                         cpu_seconds=cpu, events_per_photon=res.events / n,
                         events_per_second_per_core=res.events / res.seconds / res.devices,
                         lane_occupancy=res.lane_occupancy,
                         mcml_seconds_per_1e6=mcml_s, mcml_source=source, ratio_to_mcml=s6 / mcml_s,
                         speedup_vs_1_device=one / res.seconds, speedup_vs_before=old_s / res.seconds,
                         R_diffuse=res.R_diffuse, T=res.T)
            if local_mcml is not None:
                extra.update(mcml_same_run_seconds_per_1e6=1e6 * local_mcml / n,
                             ratio_to_mcml_same_run=res.seconds / local_mcml)
            rows.append(make_row(NAME, "mcml " + case, label, res.R_diffuse_stderr, "stderr of R_diffuse",
                                 res.seconds, comp, **extra))
            print(f"  {case:18s} {label:32s} {s6:7.2f} s/1e6  {extra['events_per_second_per_core']:9.3g} ev/s/core "
                  f"occ {res.lane_occupancy:.2f}  x{s6 / mcml_s:5.2f} MCML  x{one / res.seconds:4.2f} vs 1 dev  x{old_s / res.seconds:4.2f} vs "
                  f"before  Rd {res.R_diffuse:.5f}+-{res.R_diffuse_stderr:.5f}"
                  + (f"  (MCML here {1e6 * local_mcml / n:.2f} s/1e6)" if local_mcml else ""), flush=True)
            summary[f"{case}: {label}"] = {"seconds_per_1e6_photons": s6, "ratio_to_mcml": s6 / mcml_s}
    return rows, summary


def _process_seconds(argv, env) -> tuple[float, float]:
    """Wall seconds and CPU seconds (user + system) of a child process; CPU time is the load-robust figure."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, env=env, check=True, capture_output=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def startup_rows() -> tuple[list, dict]:
    """Cold (empty cache), warm and cache-off wall time of a ``jaxsss mc`` process, and of the import alone."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cli = [sys.executable, "-m", "jaxsss", "mc", "--sigma-a", "0.17", "--sigma-s", "0.88", "--eta", "1.3",
           "--photons", "1000", "--json"]
    rows, summary = [], {}
    with tempfile.TemporaryDirectory() as cache:
        env_cache = dict(env, JAXSSS_COMPILATION_CACHE=cache)
        timings = {
            "import jaxsss.cli": _process_seconds([sys.executable, "-c", "import jaxsss.cli"], env_cache),
            "jaxsss mc, cold cache": _process_seconds(cli, env_cache),
            "jaxsss mc, warm cache": _process_seconds(cli, env_cache),
            "jaxsss mc, warm cache (again)": _process_seconds(cli, env_cache),
            "jaxsss mc, cache off": _process_seconds(cli, dict(env, JAXSSS_COMPILATION_CACHE="off")),
        }
        # Per photon, the CLI runs the very same simulate() call: its run time (seconds minus compile_seconds)
        # against the API's on as many devices, each in a fresh process, in the same run.
        n = 200_000
        out = subprocess.run(cli[:-2] + [str(n), "--json"], env=env_cache, check=True, capture_output=True,
                             text=True, cwd=ROOT).stdout
        got = json.loads(out)
        cli_s = got["seconds"] - got["compile_seconds"]  # seconds includes the compilation (or cache load)
        # The API in a fresh process too (one run after start, like the CLI; a warmed-up process runs faster).
        api_code = ("from jaxsss.mc import use_cpu_devices; use_cpu_devices()\n"
                    "from jaxsss.mc import Stack, simulate\n"
                    f"r = simulate(Stack.half_space(0.17, 0.88, 0.0, 1.3), {n}, progress=False)\n"
                    "print(r.seconds - r.compile_seconds)")
        api_s = float(subprocess.run([sys.executable, "-c", api_code], env=env_cache, check=True,
                                     capture_output=True, text=True, cwd=ROOT).stdout.split()[-1])
    rows.append(make_row(NAME, "cli vs api", "skin1 green, 2e5 photons", None, "none", cli_s, None, photons=n,
                         api_seconds=api_s, cli_over_api=cli_s / api_s))
    summary["cli seconds / api seconds (2e5 photons, same devices)"] = cli_s / api_s
    print(f"  jaxsss mc {cli_s:.2f} s vs simulate() {api_s:.2f} s for {n} photons (ratio {cli_s / api_s:.2f})")
    for label, (s, cpu) in timings.items():
        rows.append(make_row(NAME, "startup", label, None, "none", s, None, photons=1000, cpu_seconds=cpu))
        summary["startup: " + label] = {"wall_seconds": s, "cpu_seconds": cpu}
        print(f"  startup {label:32s} {s:6.2f} s wall  {cpu:6.2f} s CPU", flush=True)
    return rows, summary


def sweep_rows(cfg) -> tuple[list, dict]:
    rows, summary = [], {}
    for geometry in ("half-space", "slab b=2"):
        for albedo, n in cfg["photons"].items():
            if geometry == "half-space":
                stack = Stack.half_space(1.0 - albedo, albedo, 0.0, 1.0)
            else:
                stack = Stack.slab(1.0 - albedo, albedo, 0.0, 1.0, 2.0)
            res, comp, _ = _run(stack, n, 1, len(jax.devices()))
            pps = n / res.seconds
            setting = f"{geometry} a={albedo}"
            print(f"  {setting:22s} {n:>9d} photons {res.seconds:7.2f} s  {pps:10.0f} photons/s  "
                  f"{res.events / n:8.1f} events/photon  compile {comp:.2f} s", flush=True)
            rows.append(make_row(NAME, "throughput " + geometry, setting, res.R_diffuse_stderr,
                                 "stderr of R_diffuse", res.seconds, comp, photons=n, devices=res.devices,
                                 photons_per_second=pps, seconds_per_1e6_photons=1e6 / pps,
                                 events_per_photon=res.events / n, lanes=res.lanes,
                                 events_per_second=res.events / res.seconds, R_diffuse=res.R_diffuse, T=res.T))
            summary[setting] = {"photons_per_second": pps, "seconds_per_1e6_photons": 1e6 / pps}
    stack = Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0)
    for n in cfg["sweep"]:
        res, comp, _ = _run(stack, n, 2, len(jax.devices()))
        err = abs(res.R_diffuse - 0.09739) + abs(res.T - 0.66096)
        rows.append(make_row(NAME, "van de Hulst slab", n, err, "|R - R_ref| + |T - T_ref|", res.seconds, comp,
                             photons=n, R=res.R_diffuse, R_stderr=res.R_diffuse_stderr, T=res.T,
                             T_stderr=res.T_stderr))
        print(f"  sweep {n:>9d} photons {res.seconds:7.2f} s  error {err:.2e}  (stderr R {res.R_diffuse_stderr:.1e}, "
              f"T {res.T_stderr:.1e})", flush=True)
    return rows, summary


def run(quick: bool):
    try:  # one CPU device per core, if JAX has not started yet (python -m benchmarks.mc_throughput does it first)
        use_cpu_devices()
    except ValueError:
        pass
    cfg = CONFIG["quick" if quick else "full"]
    rows, summary = [], {"devices": len(jax.devices()), "uptime_before": os.getloadavg()}
    for part in (mcml_rows(cfg), startup_rows(), sweep_rows(cfg)):
        rows += part[0]
        summary.update(part[1])
    summary["uptime_after"] = os.getloadavg()
    return rows, summary


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    rows, summary = run(args.quick)
    notes = [
        "seconds: wall time of one simulate() call after a compiling warm-up (best of the interleaved repeats); "
        "compile_seconds: the warm-up's compile time (0-0.3 s when the persistent cache has the program)",
        f"MCML reference figures: {MCML_MACHINE}; see the mcml_source of each row",
        "load averages (1, 5, 15 min) before and after are in the summary: the machine is shared",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="Monte Carlo: error vs seconds", connect=True)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
