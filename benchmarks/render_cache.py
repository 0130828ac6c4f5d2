"""Irradiance-caching benchmark: the cached method's error against run time as the error bound ``a`` varies.

What is measured. For each example scene at 512 x 512 (full) the hierarchical image (same samples, same eps, the
scene's own settings) is the baseline; the cached method (``jaxsss render --method cached``) renders the same scene
with the error bound ``a`` swept. On the default scene (``examples/marble_teapot.toml``) it also renders

- the gradient variants at ``a = 0.3``: the paper's full analytic gradient (Eq. 9), the far-field part (the
  default) and no gradient (plain weighted mean);
- the one-pass variant (the paper's Figure 4) at ``a = 0.3``;
- a reference at 4x the sample density, against which both the hierarchical and the cached images are also measured:
  the hierarchical image is itself noisy at the pixel scale, and that noise is part of its distance to the cache.

Quick: the skin sphere at 64 x 64 with ``a`` in (0.3, 1), no reference.

**End to end, as a user runs it** (issue 16): ``jaxsss render examples/marble_teapot.toml --method M --resolution R R``
in a fresh process (``JAXSSS_COMPILATION_CACHE=off``: every run compiles), hierarchical against cached (a = 0.3,
``--cache-always``), at 256 and 512 px (not in quick mode: two fresh processes per size). ``seconds`` is the process's
wall clock (imports, scene, geometry, compilation, pass 2, writing the files); the report's stage split (``seconds``: plan, pass 1, tree,
geometry, compile, pass 2, other) goes in the row. This is what decides the plan's rule
(:func:`jaxsss.render.cache.caching_pays`).

Error metrics, over the pixels that hit the object:

- ``error`` = ``rms_paper``: the RMS difference of the **averaged RGB** of the images as displayed (exposure, clip,
  sRGB encoding, values in [0, 1]) -- the caching paper's "RMS on averaged RGB" (its anchor: 0.0046-0.0068);
- ``max_error``: the largest per-pixel absolute difference of the same averaged display values;
- ``relative_rms``: ``||I - I_ref||_2 / ||I_ref||_2`` on the linear RGB image;
- ``mean_ciede2000``: mean CIEDE2000 on the displayed image (colour-science);
- ``*_vs_reference``: the same against the 4x-density reference (default scene only).

``seconds`` is the whole render after compilation (JAX compile time, from ``jax.monitoring`` events, subtracted and
reported as ``compile_seconds``), the minimum of ``repeats`` runs; ``speedup`` is the hierarchical seconds over the
cached seconds, timed in the same process.
"""

from __future__ import annotations

import gc
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results
from benchmarks.render_eps import compile_clock, image_errors, pass_timings, peak_rss_gb, scene_for

NAME = "render_cache"
ROOT = Path(__file__).resolve().parents[1]
ERROR_METRIC = "RMS of averaged display RGB vs the hierarchical image (the caching paper's metric)"
DEFAULT_SCENE = "marble_teapot.toml"
CONFIG = {
    "quick": dict(resolution=64, repeats=1, reference_density=None,
                  scenes={"skin_sphere.toml": (0.3, 1.0)}, variants_a=None, end_to_end=()),
    "full": dict(resolution=512, repeats=2, reference_density=4.0,
                 scenes={"marble_teapot.toml": (0.05, 0.1, 0.3, 1.0, 3.0), "skin_sphere.toml": (0.3, 1.0),
                         "ketchup_torus.toml": (0.3, 1.0), "milk_box_on_floor.toml": (0.3, 1.0)},
                 variants_a=0.3, end_to_end=(256, 512)),
}


def display_mean(image, exposure: float) -> np.ndarray:
    """``(H, W)`` the averaged RGB of the image as the PNG shows it (exposure, clip, sRGB), in [0, 1]."""
    import colour

    linear = np.clip(np.nan_to_num(np.asarray(image, dtype=np.float64) * exposure), 0.0, 1.0)
    return np.asarray(colour.cctf_encoding(linear, function="sRGB")).mean(axis=-1)


def cache_errors(test, ref, hit, exposure: float) -> dict:
    """The module docstring's metrics of ``test`` against ``ref`` (both ``(H, W, 3)`` linear) over ``hit``."""
    d = (display_mean(test, exposure) - display_mean(ref, exposure))[hit]
    base = image_errors(np.asarray(test)[hit], np.asarray(ref)[hit], exposure, lit_fraction=0.0)
    return {"rms_paper": float(np.sqrt(np.mean(d**2))), "max_error": float(np.max(np.abs(d))),
            "relative_rms": base["relative_rms"], "mean_ciede2000": base["mean_ciede2000"],
            "max_ciede2000": base["max_ciede2000"]}


def timed(fn, repeats: int):
    """``(result, seconds excluding compile (min over repeats), compile seconds of the first run)``."""
    best, compile_s, result = np.inf, None, None
    for _ in range(repeats):
        gc.collect()
        with compile_clock() as c:
            result = fn()
        best = min(best, max(c["wall"] - c["compile"], 1e-9))
        compile_s = c["compile"] if compile_s is None else compile_s
    return result, best, compile_s


def end_to_end(resolution: int, method: str, out_dir: Path) -> tuple[float, dict, np.ndarray]:
    """``(wall seconds, report, linear image)`` of ``jaxsss render`` on the default scene in a fresh process."""
    import json
    import os
    import subprocess

    out = out_dir / f"e2e_{method}_{resolution}.png"
    cmd = [sys.executable, "-m", "jaxsss", "render", str(ROOT / "examples" / DEFAULT_SCENE), "--method", method,
           "--resolution", str(resolution), str(resolution), "-o", str(out), "--json", str(out.with_suffix(".json")),
           "--quiet", "--no-exr"] + (["--cache-always"] if method == "cached" else [])
    env = {**os.environ, "JAXSSS_COMPILATION_CACHE": "off", "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    wall = time.perf_counter() - t0
    report = json.loads(out.with_suffix(".json").read_text())
    image = np.load(out.with_suffix(".npy"))
    for suffix in (".png", ".json", ".npy"):
        out.with_suffix(suffix).unlink()
    return wall, report, image


def end_to_end_rows(resolutions, out_dir: Path) -> tuple[list, dict]:
    """The end-to-end rows (module docstring) and a summary of the cached method's gain per resolution."""
    rows, gains = [], {}
    exposure = float(scene_for(ROOT / "examples" / DEFAULT_SCENE).output.exposure)
    for res in resolutions:
        hier_s, hier, hier_img = end_to_end(res, "hierarchical", out_dir)
        cached_s, cached, cached_img = end_to_end(res, "cached", out_dir)
        hit = np.any(hier_img != 0, axis=-1)
        e = cache_errors(cached_img, hier_img, hit, exposure)
        for method, seconds, rep, err in (("hierarchical end to end", hier_s, hier, None),
                                          ("cached end to end", cached_s, cached, e["rms_paper"])):
            rows.append(make_row(NAME, method, f"{DEFAULT_SCENE} {res}px", err, ERROR_METRIC, seconds,
                                 rep["seconds"]["compile"], scene=DEFAULT_SCENE, resolution=res, a=0.3,
                                 n_shaded_points=rep["n_shaded_points"], n_caches=rep.get("n_caches"),
                                 seconds_total_in_report=rep["seconds_total"], speedup=hier_s / seconds,
                                 **{f"stage_{k}_seconds": v for k, v in rep["seconds"].items()}))
        gains[f"{res}px"] = {"hierarchical_seconds": hier_s, "cached_seconds": cached_s, "speedup": hier_s / cached_s,
                             "n_shaded_points": hier["n_shaded_points"], "rms_paper": e["rms_paper"],
                             "hierarchical_stages": hier["seconds"], "cached_stages": cached["seconds"]}
        print(f"end to end {res}x{res}: hierarchical {hier_s:.1f} s, cached {cached_s:.1f} s "
              f"(x{hier_s / cached_s:.2f}), {hier['n_shaded_points']} shaded points, RMS {e['rms_paper']:.4f}",
              flush=True)
    return rows, gains


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    from jaxsss.render import render

    cfg = CONFIG["quick" if args.quick else "full"]
    res = (cfg["resolution"], cfg["resolution"])
    rows, summary = [], {"resolution": list(res), "scenes": {}}
    t_start = time.perf_counter()
    for scene_name, bounds in cfg["scenes"].items():
        path = ROOT / "examples" / scene_name
        scene = scene_for(path)
        exposure = float(scene.output.exposure)
        # The dipole, as the cached method's caches (the plan's auto picks the white kernel for these materials).
        hier, hier_s, hier_c = timed(lambda: render(scene, resolution=res, bssrdf="dipole"), cfg["repeats"])
        hit = np.zeros(res[1] * res[0], dtype=bool)
        hit[np.asarray(hier.prepared.state.query_pixel)] = True
        hit = hit.reshape(res[1], res[0])
        rep = hier.report
        rows.append(make_row(NAME, "hierarchical", scene_name, None, ERROR_METRIC, hier_s, hier_c, scene=scene_name,
                             n_samples=rep["n_samples"], hit_pixels=int(hit.sum()), speedup=1.0,
                             peak_rss_gb=peak_rss_gb(), **pass_timings(rep)))
        print(f"{scene_name} {res[0]}x{res[1]}: hierarchical {hier_s:.2f} s (compile {hier_c:.1f} s), "
              f"{rep['n_samples']} samples, {int(hit.sum())} hit pixels", flush=True)
        ref = None
        if cfg["reference_density"] and scene_name == DEFAULT_SCENE:
            dense = scene_for(path, density=cfg["reference_density"])
            ref_result, ref_s, ref_c = timed(lambda: render(dense, resolution=res, bssrdf="dipole"), 1)
            ref = ref_result.image
            e = cache_errors(hier.image, ref, hit, exposure)
            rows[-1].update({f"{k}_vs_reference": v for k, v in e.items()})
            rows.append(make_row(NAME, "hierarchical (reference)", f"{scene_name} density={cfg['reference_density']:g}",
                                 None, ERROR_METRIC, ref_s, ref_c, scene=scene_name,
                                 n_samples=ref_result.report["n_samples"], peak_rss_gb=peak_rss_gb()))
            print(f"  reference (density {cfg['reference_density']:g}, {ref_result.report['n_samples']} samples) "
                  f"{ref_s:.1f} s; hierarchical vs reference: RMS {e['rms_paper']:.4f}, rel {e['relative_rms']:.4f}",
                  flush=True)
            del ref_result
        runs = [(a, "far", False) for a in bounds]
        if cfg["variants_a"] is not None and scene_name == DEFAULT_SCENE:
            a = cfg["variants_a"]
            runs += [(a, "analytic", False), (a, "none", False), (a, "far", True)]
        for a, gradient, one_pass in runs:
            result, seconds, compile_s = timed(
                lambda: render(scene, "cached", error_bound=a, resolution=res, gradient=gradient, one_pass=one_pass,
                               always=True),
                cfg["repeats"])
            r = result.report
            e = cache_errors(result.image, hier.image, hit, exposure)
            extra = {}
            if ref is not None:
                extra = {f"{k}_vs_reference": v for k, v in cache_errors(result.image, ref, hit, exposure).items()}
            method = "cached" + ("" if gradient == "far" else f" ({gradient} gradient)") + (
                " one-pass" if one_pass else "")
            rows.append(make_row(NAME, method, f"{scene_name} a={a:g}", e["rms_paper"], ERROR_METRIC, seconds,
                                 compile_s, scene=scene_name, a=a, gradient=gradient, one_pass=one_pass,
                                 n_caches=r["n_caches"], cache_ratio=r["cache_ratio"], speedup=hier_s / seconds,
                                 max_error=e["max_error"], relative_rms=e["relative_rms"],
                                 mean_ciede2000=e["mean_ciede2000"], max_ciede2000=e["max_ciede2000"],
                                 interpolation_error_estimate_mean=r["interpolation_error_estimate_mean"],
                                 peak_rss_gb=peak_rss_gb(), **extra, **pass_timings(r)))
            print(f"  {method:<28s} a={a:<5g} caches {r['n_caches']:>6d} ({100 * r['cache_ratio']:5.2f}%)  RMS "
                  f"{e['rms_paper']:.4f}  max {e['max_error']:.3f}  rel {e['relative_rms']:.4f}  dE00 "
                  f"{e['mean_ciede2000']:.3f}  {seconds:6.2f} s  x{hier_s / seconds:5.1f}"
                  + (f"  (vs reference RMS {extra['rms_paper_vs_reference']:.4f})" if extra else ""), flush=True)
            del result
        best = [row for row in rows if row.get("scene") == scene_name and row["method"] == "cached"
                and row["gradient"] == "far" and not row["one_pass"] and row["error"] <= 0.005]
        summary["scenes"][scene_name] = {
            "hierarchical_seconds": hier_s,
            "best_speedup_at_rms_0.005": max((row["speedup"] for row in best), default=None),
        }
        del hier
        gc.collect()
    e2e_rows, summary["end_to_end"] = end_to_end_rows(cfg["end_to_end"], Path(args.out))
    rows += e2e_rows
    summary["wall_seconds"] = time.perf_counter() - t_start
    summary["peak_rss_gb"] = peak_rss_gb()
    notes = [
        "error = RMS of the averaged display RGB (exposure, clip, sRGB; [0, 1]) over the pixels that hit the object, "
        "against the hierarchical image with the same samples (the caching paper's metric); the hierarchical row's "
        "error is null (it is the baseline)",
        "seconds: minimum over repeats of the whole render minus JAX compile time; speedup = hierarchical seconds / "
        "cached seconds in the same process",
        "cached rows use the far-field gradient unless the method names another; '*_vs_reference' columns compare "
        "against a 4x-density hierarchical render (default scene)",
        "'end to end' rows: wall clock of `jaxsss render` in a fresh process with the persistent compilation cache "
        "off (compile included; compile_seconds is the report's compile stage); stage_*_seconds: the report's split",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out,
                                        quick=args.quick, summary=summary, notes=notes,
                                        title=f"{NAME}: {res[0]}x{res[1]}; display RMS vs seconds", connect=False)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
