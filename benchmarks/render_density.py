"""Renderer sample-density sweep: the image error of pass 1's irradiance-sample density against a dense reference.

What is measured. The hierarchical renderer (eps = 0.02 for every run, so the octree's approximation error is small
next to the sampling error) with ``[render].density`` -- the multiplier on the paper's count ``A / (pi l_u^2)`` -- in
(0.25, 0.5, 1, 2) against a reference render at density 8, same camera and seed. Full: the default scene
(``examples/marble_teapot.toml``) at 256 x 256 (density 1 is about 55,000 samples; 8 is about 440,000). Quick: the
skin sphere (``examples/skin_sphere.toml``) at 96 x 96, densities (0.5, 1) against 4.

The sample positions differ between densities (a new blue-noise set each time), so the error combines the
discretisation of the irradiance integral, the near-field disc (whose radius is 3 sample radii, so it shrinks as the
density grows) and shadow-boundary aliasing. The reference is not noise-free: a second reference render with another
seed (``hierarchical (reference, seed 1)``) measures its own pixel noise, ``rel RMS(seed 1 vs seed 0) / sqrt(2)``,
and each row also reports ``error_less_reference_noise = sqrt(error^2 - noise_ref^2)``.

Error metrics over the pixels lit in the reference (RGB norm above 5% of the brightest pixel), on the linear RGB image
(all three channels): ``error`` is the relative RMS ``||I - I_ref||_2 / ||I_ref||_2``; ``max_relative_error`` the
largest per-pixel ``|I_p - I_ref,p| / |I_ref,p|``; ``mean_ciede2000`` the mean CIEDE2000 on the image as the PNG shows
it (exposure, clip, sRGB -> Lab). ``seconds`` is the whole render after compilation (JAX compile time, from
``jax.monitoring`` events, is subtracted and reported as ``compile_seconds``).
"""

from __future__ import annotations

import gc
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results
from benchmarks.render_eps import (
    image_errors,
    pass_timings,
    peak_rss_gb,
    scene_for,
    timed_render,
)

NAME = "render_density"
ROOT = Path(__file__).resolve().parents[1]
ERROR_METRIC = "relative RMS vs density-8 reference (lit pixels)"
EPS = 0.02
LIT_FRACTION = 0.05
CONFIG = {
    "quick": dict(scene="skin_sphere.toml", resolution=64, densities=(0.5, 1.0), reference=3.0),
    "full": dict(scene="marble_teapot.toml", resolution=256, densities=(0.25, 0.5, 1.0, 2.0), reference=8.0),
}


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    cfg = CONFIG["quick" if args.quick else "full"]
    if args.quick:
        cfg = dict(cfg, metric=ERROR_METRIC.replace("density-8", f"density-{cfg['reference']:g}"))
    metric = cfg.get("metric", ERROR_METRIC)
    path = ROOT / "examples" / cfg["scene"]
    res = (cfg["resolution"], cfg["resolution"])
    t_start = time.perf_counter()

    def run(density, seed=0):
        scene = scene_for(path, density=density, seed=seed)
        result, seconds, compile_s = timed_render(scene, eps=EPS, resolution=res)
        return scene, result, seconds, compile_s

    scene, ref_res, ref_seconds, ref_compile = run(cfg["reference"])
    exposure = float(scene.output.exposure)
    ref = ref_res.image.reshape(-1, 3)
    norm = np.linalg.norm(ref, axis=1)
    lit = np.flatnonzero(norm > LIT_FRACTION * norm.max())
    rep = ref_res.report
    rows = [make_row(NAME, "hierarchical (reference)", f"density={cfg['reference']:g}", None, metric, ref_seconds,
                     ref_compile, density=cfg["reference"], n_samples=rep["n_samples"],
                     interactions_per_point_mean=rep["interactions_per_point_mean"],
                     near_radius_mm=rep["near_radius_mm"], lit_pixels=len(lit), peak_rss_gb=peak_rss_gb(),
                     **pass_timings(rep))]
    print(f"{path.name} at {res[0]}x{res[1]}, eps {EPS}: reference density {cfg['reference']:g} = {rep['n_samples']} "
          f"samples, {ref_seconds:.1f} s (compile {ref_compile:.1f} s); {len(lit)} lit pixels", flush=True)
    del ref_res, rep
    gc.collect()

    # The reference's own noise: the same density with another seed (new sample positions).
    _, alt, alt_seconds, alt_compile = run(cfg["reference"], seed=1)
    alt_err = image_errors(alt.image.reshape(-1, 3)[lit], ref[lit], exposure, lit_fraction=0.0)
    ref_noise = alt_err["relative_rms"] / np.sqrt(2.0)
    rows.append(make_row(NAME, "hierarchical (reference, seed 1)", f"density={cfg['reference']:g} seed=1",
                         alt_err["relative_rms"], metric, alt_seconds, alt_compile, density=cfg["reference"], seed=1,
                         n_samples=alt.report["n_samples"], max_relative_error=alt_err["max_relative_error"],
                         mean_ciede2000=alt_err["mean_ciede2000"], reference_noise_estimate=ref_noise,
                         peak_rss_gb=peak_rss_gb(), **pass_timings(alt.report)))
    print(f"reference with seed 1: rel RMS {alt_err['relative_rms']:.2e} vs seed 0 -> the reference's own noise "
          f"~{ref_noise:.2e} (/sqrt 2)  dE00 {alt_err['mean_ciede2000']:.3f}", flush=True)
    del alt
    gc.collect()

    for density in cfg["densities"]:
        _, result, seconds, compile_s = run(density)
        rep = result.report
        err = image_errors(result.image.reshape(-1, 3)[lit], ref[lit], exposure, lit_fraction=0.0)
        rows.append(make_row(NAME, "hierarchical", f"density={density:g}", err["relative_rms"], metric, seconds,
                             compile_s, density=density, n_samples=rep["n_samples"],
                             max_relative_error=err["max_relative_error"], mean_ciede2000=err["mean_ciede2000"],
                             max_ciede2000=err["max_ciede2000"],
                             error_less_reference_noise=float(np.sqrt(max(err["relative_rms"]**2 - ref_noise**2,
                                                                          0.0))),
                             interactions_per_point_mean=rep["interactions_per_point_mean"],
                             near_radius_mm=rep["near_radius_mm"], peak_rss_gb=peak_rss_gb(), **pass_timings(rep)))
        print(f"density {density:<5g} {rep['n_samples']:>7d} samples  rel RMS {err['relative_rms']:.2e}  max rel "
              f"{err['max_relative_error']:.2e}  dE00 {err['mean_ciede2000']:.3f}  {seconds:6.1f} s (compile "
              f"{compile_s:.1f} s)  rho0 {rep['near_radius_mm']:.3f} mm", flush=True)
        del result, rep
        gc.collect()

    swept = [r for r in rows if r["method"] == "hierarchical"]
    summary = {
        "scene": path.name, "resolution": list(res), "eps": EPS, "reference_density": cfg["reference"],
        "reference_n_samples": rows[0]["n_samples"], "lit_pixels": len(lit),
        "relative_rms_by_density": {str(r["density"]): r["error"] for r in swept},
        "mean_ciede2000_by_density": {str(r["density"]): r["mean_ciede2000"] for r in swept},
        "error_less_reference_noise_by_density": {str(r["density"]): r["error_less_reference_noise"] for r in swept},
        "reference_seed1_vs_seed0_relative_rms": alt_err["relative_rms"],
        "reference_noise_estimate": ref_noise,
        "peak_rss_gb": peak_rss_gb(),
        "wall_seconds": time.perf_counter() - t_start,
    }
    if len(swept) >= 2:
        d = np.log([r["density"] for r in swept])
        e = np.log([max(r["error"], 1e-300) for r in swept])
        summary["error_vs_density_loglog_slope"] = float(np.polyfit(d, e, 1)[0])
    notes = [
        "error over the reference's lit pixels (RGB norm > 5% of the max), all three linear RGB channels",
        "every render uses eps = 0.02 and the same camera and seed; sample positions differ between densities",
        "each configuration is timed once (renders take seconds to minutes on a shared 2-core machine), not the minimum of repeats the plot axis mentions",
        "the reference's own noise is estimated from a second reference render with seed 1 (rel RMS / sqrt 2); "
        "error_less_reference_noise = sqrt(error^2 - reference noise^2)",
        "seconds: the whole render minus JAX compile time (jax.monitoring events); the reference row's error is "
        "null (it is the reference, error 0 by definition; left off the plot)",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title=f"{NAME}: {path.stem} {res[0]}x{res[1]}, eps {EPS}; "
                                        "error vs seconds", connect=True)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
