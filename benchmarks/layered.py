"""Layered single scattering (Francois et al.): samples per view ray against the exact reference, time per frame.

What is measured. The example scene ``examples/layered_veins.toml`` (a UV-mapped sphere, the paper's fish layers
under a procedural vein texture, three point lights) at 800 x 600 (quick: 200 x 150). Geometry (camera rays, frames,
plane fits, shadow rays) is done once and timed on its own. Then:

- ``layered``: the whole-frame march (one jitted call) for N = 10, 20, 50, 100 samples (quick: 10, 50). ``seconds``
  is the minimum of repeated calls after compilation (``compile_seconds`` apart); ``fps = 1 / seconds`` (CPU).
- ``exact reference``: the true entry point by Embree ray casting towards each light and exact layer crossings by
  fine marching (``jaxsss.layered.reference``) on a random subset of the shaded pixels (1000; quick 150), with 512
  view steps and 64 light-path sub-steps (quick 256 / 32). Its ``seconds`` is extrapolated to the full frame
  (geometry + evaluation per pixel x shaded pixels). Its own quadrature error is estimated against the same
  reference with half the view steps (``reference_self_error``).
- ``planar only``: the march with as many samples as the reference's view steps, on the subset: the error of the
  planar approximations (Eqs. 9-12) on their own, without the N-sample march's.

Errors on the subset pixels, linear RGB: ``error`` is the relative RMS ``||I - I_ref|| / ||I_ref||``;
``mean_ciede2000`` the mean CIEDE2000 of the images as the PNG shows them (the scene's exposure, clipped, sRGB).

GPU estimate: XLA's cost analysis of one march step on one pixel chunk, times N and the number of chunks, gives the
floating-point operations per frame (``flops_per_frame``); ``gpu_seconds_estimate`` divides by an assumed sustained
1 TFLOP/s in float64 (a mid-range GPU's float32 peak is ~10-20 TFLOP/s and float64 is 1/32-1/2 of it; the march is
gather-bound, so this is an order of magnitude, not a measurement).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import numpy as np

from benchmarks._harness import make_row, parse_args, time_call, write_results
from benchmarks.render_eps import to_lab

NAME = "layered"
ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "layered_veins.toml"
ERROR_METRIC = "relative RMS vs exact reference (subset pixels, linear RGB)"
GPU_FLOPS = 1e12
CONFIG = {
    "quick": dict(resolution=(200, 150), samples=(10, 50), subset=150, n_view=256, n_light=32, repeats=2),
    "full": dict(resolution=(800, 600), samples=(10, 20, 50, 100), subset=1000, n_view=512, n_light=64, repeats=3),
}


def _errors(test, ref, exposure):
    import colour

    test, ref = np.asarray(test).reshape(-1, 3), np.asarray(ref).reshape(-1, 3)
    rel = float(np.sqrt(np.sum((test - ref) ** 2) / np.sum(ref**2)))
    de = colour.delta_E(to_lab(test, exposure), to_lab(ref, exposure), method="CIE 2000")
    return rel, float(np.mean(de)), float(np.max(de))


def _subset_geometry(sg, idx):
    from jaxsss.layered.march import PixelGeometry

    f = [np.asarray(getattr(sg, k))[idx] for k in PixelGeometry.__annotations__]
    return PixelGeometry(*(jax.numpy.asarray(a) for a in f))


def _flops_per_step(prepared, stack):
    from jaxsss.layered.march import march

    chunk = jax.tree_util.tree_map(lambda a: a[0], prepared.geom)
    lowered = jax.jit(lambda s, g: march(s, prepared.boundaries, g, prepared.lights, 1)).lower(stack, chunk)
    cost = lowered.compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", float("nan"))), int(prepared.geom.P.shape[0])


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    from jaxsss.layered import load_layered_scene, prepare_layered, prepare_reference, reference_radiance
    from jaxsss.layered.march import march
    from jaxsss.layered.render import COS_MIN
    from jaxsss.layered.tangents import surface_frames, wrap_for

    cfg = CONFIG["quick" if args.quick else "full"]
    t_start = time.perf_counter()
    scene, spec = load_layered_scene(SCENE)
    stack = spec.stack
    exposure = float(scene.output.exposure)
    t0 = time.perf_counter()
    prepared, sg, info = prepare_layered(scene, spec, resolution=cfg["resolution"])
    geometry_seconds = time.perf_counter() - t0
    q = prepared.n_points
    print(f"{SCENE.name} at {cfg['resolution'][0]}x{cfg['resolution'][1]}: {q} shaded pixels, geometry "
          f"{geometry_seconds:.1f} s, plane radius {info['plane_radius_mm']:.2f} mm", flush=True)

    # The exact reference on a subset of the shaded pixels.
    rng = np.random.default_rng(0)
    idx = np.sort(rng.choice(q, size=min(cfg["subset"], q), replace=False))
    sub = _subset_geometry(sg, idx)
    cos_p = np.einsum("ij,ij->i", sg.w_out[idx], sg.normal[idx])
    t_end = np.minimum(spec.effective_depth_max / np.maximum(cos_p, COS_MIN), sg.t_exit[idx])
    frames = surface_frames(scene.mesh, spec.wrap or wrap_for(scene.mesh_description), spec.tile)
    refs = {}
    for n_view in (cfg["n_view"] // 2, cfg["n_view"]):
        t0 = time.perf_counter()
        data = prepare_reference(info["geometry"], scene.mesh, frames, prepared.boundaries, sub, prepared.lights,
                                 t_end, n_view=n_view, n_light=cfg["n_light"])
        prep_s = time.perf_counter() - t0
        timing = time_call(reference_radiance, stack, data, repeats=1)
        refs[n_view] = (np.asarray(timing.output), prep_s, timing)
    ref, ref_prep, ref_timing = refs[cfg["n_view"]]
    self_err = _errors(refs[cfg["n_view"] // 2][0], ref, exposure)
    per_pixel = (ref_prep + ref_timing.seconds) / len(idx)
    ref_frame = per_pixel * q + geometry_seconds
    print(f"reference: {len(idx)} px, {cfg['n_view']} view steps x {cfg['n_light']} light steps: {ref_prep:.1f} s "
          f"geometry + {ref_timing.seconds:.2f} s -> full frame ~{ref_frame:.0f} s; own error (vs half the steps) "
          f"{self_err[0]:.2e}", flush=True)
    rows = [make_row(NAME, "exact reference", f"S={cfg['n_view']}", None, ERROR_METRIC, ref_frame,
                     ref_timing.compile_seconds, samples=cfg["n_view"], light_steps=cfg["n_light"],
                     seconds_is="extrapolated full frame: (ray casts + evaluation) per pixel x shaded pixels + "
                                "geometry", subset_pixels=len(idx), seconds_per_pixel=per_pixel,
                     reference_self_error=self_err[0], reference_self_ciede2000=self_err[1])]

    flops_step, n_chunks = _flops_per_step(prepared, stack)
    for n in cfg["samples"]:
        timing = time_call(lambda s: prepared.radiance(s, n), stack, repeats=cfg["repeats"])
        out = np.asarray(timing.output)[idx]
        rel, de, de_max = _errors(out, ref, exposure)
        flops = flops_step * n * n_chunks
        rows.append(make_row(NAME, "layered", f"N={n}", rel, ERROR_METRIC, timing.seconds, timing.compile_seconds,
                             samples=n, fps=1.0 / timing.seconds, mean_ciede2000=de, max_ciede2000=de_max,
                             median_seconds=timing.median_seconds, flops_per_frame=flops,
                             gpu_seconds_estimate=flops / GPU_FLOPS, gpu_fps_estimate=GPU_FLOPS / flops,
                             speedup_vs_reference=ref_frame / timing.seconds, shaded_pixels=q))
        print(f"N={n:<4d} rel RMS {rel:.3e}  dE00 mean {de:.3f} max {de_max:.2f}  {timing.seconds:.2f} s/frame "
              f"({1 / timing.seconds:.2f} fps CPU; compile {timing.compile_seconds:.1f} s)  {flops:.2e} flop -> "
              f"GPU ~{GPU_FLOPS / flops:.0f} fps", flush=True)

    # The planar approximations on their own: as many samples as the reference has view steps.
    n_big = cfg["n_view"]
    timing = time_call(lambda s: march(s, prepared.boundaries, sub, prepared.lights, n_big), stack, repeats=1)
    rel, de, de_max = _errors(timing.output, ref, exposure)
    rows.append(make_row(NAME, "planar only", f"N={n_big} subset", rel, ERROR_METRIC,
                         timing.seconds * q / len(idx), timing.compile_seconds, samples=n_big,
                         mean_ciede2000=de, max_ciede2000=de_max,
                         seconds_is="subset time extrapolated to the full frame"))
    print(f"planar approximation alone (N={n_big}): rel RMS {rel:.3e}  dE00 mean {de:.3f} max {de_max:.2f}")

    swept = [r for r in rows if r["method"] == "layered"]
    summary = {
        "scene": SCENE.name, "resolution": list(cfg["resolution"]), "shaded_pixels": q,
        "geometry_seconds": geometry_seconds, "plane_radius_mm": info["plane_radius_mm"],
        "subset_pixels": len(idx), "reference_view_steps": cfg["n_view"], "reference_light_steps": cfg["n_light"],
        "reference_self_error": self_err[0], "planar_only_error": rel, "planar_only_mean_ciede2000": de,
        "fps_by_samples": {str(r["samples"]): r["fps"] for r in swept},
        "error_by_samples": {str(r["samples"]): r["error"] for r in swept},
        "ciede2000_by_samples": {str(r["samples"]): r["mean_ciede2000"] for r in swept},
        "flops_per_step_per_chunk": flops_step, "chunks": n_chunks, "assumed_gpu_flops": GPU_FLOPS,
        "wall_seconds": time.perf_counter() - t_start,
    }
    notes = [
        "error: relative RMS over the subset pixels x linear RGB against the exact reference (true entry points by "
        "ray casting, exact layer crossings); mean_ciede2000 on the PNG encoding (scene exposure)",
        "layered seconds: whole-frame march after compilation, min of repeats; geometry (done once) is "
        "summary.geometry_seconds",
        "exact reference seconds: extrapolated from the subset to the full frame; planar only: the planar "
        "approximations with as many samples as the reference has view steps (their error alone)",
        f"gpu estimates: XLA cost-analysis flops / {GPU_FLOPS:.0e} flop/s (assumed, not measured)",
    ]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title=f"{NAME}: {SCENE.stem} {cfg['resolution'][0]}x"
                                        f"{cfg['resolution'][1]}; error vs seconds per frame (CPU)")
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
