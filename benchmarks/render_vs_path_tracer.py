"""jaxsss's renderer against a real path tracer (Mitsuba 3's volumetric path tracer): error against seconds.

What is measured. For each reference scene (``tests/export/references/*.toml``: index-matched spheres, one point
light) a high-spp Mitsuba reference is committed next to the scene (``<name>.npz``: ``image`` (H, W, 3) linear
radiance and ``coverage`` (H, W), Mitsuba's object mask; ``<name>.json``: command, variant, spp, seeds, Mitsuba
version, seconds, and the reference's own noise). Against it:

- jaxsss: ``jaxsss.render.render(scene, method=m, bssrdf=k)`` for ``hierarchical`` (the plan's eps, and 0.05 and 0.2;
  quick: the plan's)
  and ``direct``, with the old kernel (``dipole``: the dipole plus single scattering) and the new ones (``white``,
  ``white-oblique``; :mod:`jaxsss.render.bssrdf`): ``seconds`` is the whole render (plan, pass 1, tree, pass 2)
  after one warm-up render of the same scene, as Mitsuba's below; the warm-up's JAX compilation is
  ``compile_seconds`` (from jax.monitoring) and its time without compilation ``first_call_seconds`` (it also loads
  the profile tables once per process; until 2026-11-27 that was the row's ``seconds``);
- Mitsuba ``volpathmis`` (the scene exported by :mod:`jaxsss.export.mitsuba`) at increasing spp with seeds that
  differ from the reference's: ``seconds`` is ``mi.render`` after one warm-up render per scene at the smallest spp
  (the warm-up's extra time, the LLVM kernel compilation, is that row's ``compile_seconds``; the kernels are
  reused at every spp); scene loading is apart (``load_seconds``).

Error (``jaxsss.export.compare``): ``error`` = the largest over R, G, B of the mean absolute relative error over lit,
fully covered pixels (``mare_lit``); rows also carry ``mare_lit``, ``mare_band`` (terminator band, |cos| <= 0.1),
``bias_lit``, ``sum_ratio`` and ``mare_binned`` (the error of 4 x 4 pixel sums: the model's own error where the
reference is noisy) per channel. A Mitsuba row's error includes the reference's own noise
(``reference_noise_mare`` in the summary, about 1/sqrt(ref_spp / spp) of it).

Outputs: ``render_vs_path_tracer.json`` / ``.png`` (error against seconds) and ``render_vs_path_tracer_maps.png``
(per scene: reference, jaxsss hierarchical, and its signed relative error per channel). The summary's
``equal_error`` per scene (:func:`equal_error`, also printed): the seconds Mitsuba needs for the error of jaxsss's
own choice of kernel (hierarchical, the plan's eps), by the line through its two highest-spp rows and at ``1/sqrt(spp)``,
and the ratios to jaxsss's seconds.

The orders apart (``summary[scene]["order_split"]``, printed last): for a scene with a first-order reference
(:data:`FIRST_ORDER_REFERENCES`: Mitsuba at ``max_depth = 2``, the light scattered once), jaxsss's marched first
order against it and the rest of jaxsss's image (the orders >= 2) against the whole reference less it.

``--references`` regenerates the references instead (slow: minutes per scene at ``REFERENCE_SPP`` with the LLVM
variant; run it under ``nice``). Mitsuba runs with ``llvm_ad_rgb`` when ``DRJIT_LIBLLVM_PATH`` names a libLLVM
(default here: Debian's libLLVM 19 if present), else ``scalar_rgb``.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REFERENCES = ROOT / "tests" / "export" / "references"
NAME = "render_vs_path_tracer"
SCENES = ("skin1_sphere", "g09_sphere", "skin1_sphere_env", "marble_teapot", "skin1_sphere_env13", "ketchup_sphere",
          "skin1_sphere_arealight", "chicken1_sphere")
FIT_VIEWS = ("skin1_sphere_zoom",)
"""References made with ``--references`` for fits only (notebooks/render_and_fit.ipynb), not benchmarked: the skin1
sphere through a narrow lens at its terminator, a second view in which the diffusion blur spans many pixels."""
CHECKS = ("marble_sphere_env", "skin1_teapot_env")
"""References made with ``--references`` for tests only, not benchmarked: marble (albedo 0.999) on the 20 mm sphere at
eta 1.5 under skin1_sphere_env's sky, 44 transport lengths in radius, where the plan leaves the exit's current out
(:data:`jaxsss.render.plan.EXIT_CURRENT_MAX_RADIUS`); skin1 on the teapot at eta 1.4 under the same sky, which mirrors
itself in its boundary (:func:`jaxsss.render.shading.seen_in_mirror`)."""
FIRST_ORDER_REFERENCES = {"chicken1_sphere_first_order": "chicken1_sphere"}
"""References of the light scattered once (Mitsuba at ``max_depth = 2``, eta = 1), by the scene they share: the
reference for :mod:`jaxsss.render.first_order` alone (tests/export/test_compare_bssrdf.py), and with the whole
reference the orders >= 2 by difference (docs/path_tracer.md, "The orders, path-traced apart")."""
REFERENCE_SPP = {"skin1_sphere": 8192, "g09_sphere": 24576, "skin1_sphere_env": 65536, "marble_teapot": 16384,
                 "skin1_sphere_env13": 32768, "ketchup_sphere": 8192, "skin1_sphere_zoom": 32768,
                 "skin1_sphere_arealight": 8192, "chicken1_sphere": 8192, "chicken1_sphere_first_order": 32768,
                 "marble_sphere_env": 4096, "skin1_teapot_env": 16384}
REFERENCE_SEEDS = (0, 1)  # two halves, averaged; their difference measures the reference's noise
LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
ERROR_METRIC = "max over RGB of mean |relative error| over lit fully covered pixels vs the Mitsuba reference"
CONFIG = {
    "quick": dict(mitsuba_spp=(16, 64, 256),
                  jaxsss=(("hierarchical", "plan", "dipole"), ("hierarchical", "plan", "white"),
                          ("hierarchical", "plan", "white-oblique"), ("direct", None, "white-oblique"))),
    "full": dict(mitsuba_spp=(16, 64, 256, 1024, 4096),
                 jaxsss=(("hierarchical", "plan", "dipole"), ("hierarchical", 0.2, "dipole"), ("direct", None, "dipole"),
                         ("hierarchical", "plan", "white"), ("hierarchical", 0.05, "white-oblique"),
                         ("hierarchical", "plan", "white-oblique"), ("hierarchical", 0.2, "white-oblique"),
                         ("direct", None, "white-oblique"))),
}
"""jaxsss rows: (method, eps, BSSRDF kernel of :mod:`jaxsss.render.bssrdf`); eps ``"plan"``: the plan's own
(:data:`jaxsss.render.plan.EPS_WHITE` for the white kernels, ``EPS_DEFAULT`` for the dipole), ``None`` for the direct
sum. ``"auto"`` would pick the kernel per material; the rows name it so that old and new are compared on every
scene."""


def llvm_env() -> None:
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        for cand in LLVM_CANDIDATES:
            if Path(cand).is_file():
                os.environ["DRJIT_LIBLLVM_PATH"] = cand
                break


def load_reference(name: str, directory: Path = REFERENCES):
    """``(scene, image (H, W, 3), coverage (H, W), sidecar dict)`` of a committed reference in ``directory`` (the
    scene its sidecar names: a first-order reference shares its scene's)."""
    from jaxsss.render import load_scene

    data = np.load(directory / f"{name}.npz")
    meta = json.loads((directory / f"{name}.json").read_text())
    return (load_scene(directory / meta["scene"]), data["image"].astype(np.float64),
            data["coverage"].astype(np.float64), meta)


def skin1_env_sky() -> np.ndarray:
    """The sky of ``skin1_sphere_env`` (``(32, 64, 3)``, lat-long, for ``rotate_deg = [90, 0, 0]``): a blue sky
    brightening towards the zenith, a darker ground, and a soft sun (Gaussian, 10 degrees) towards skin1_sphere's
    point light."""
    from jaxsss.render.environment import uv_to_direction

    h, w = 32, 64
    uv = np.stack(np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h), axis=-1)
    local = uv_to_direction(uv)
    world = np.stack([local[..., 0], -local[..., 2], local[..., 1]], axis=-1)  # rotate_deg [90, 0, 0]: z up
    up = world[..., 2:]
    sky = np.where(up > 0, np.array([0.35, 0.45, 0.65]) * (0.6 + 0.4 * up), np.array([0.12, 0.10, 0.08]))
    sun = np.array([-90.0, -70.0, 50.0]) / np.linalg.norm([-90.0, -70.0, 50.0])
    angle = np.arccos(np.clip(world @ sun, -1.0, 1.0))
    return sky + 60.0 * np.exp(-0.5 * (angle / np.radians(10.0)) ** 2)[..., None] * np.array([1.0, 0.92, 0.8])


SKIES = {"skin1_sphere_env": ("skin1_sphere_env_sky.npy", skin1_env_sky),
         "skin1_sphere_env13": ("skin1_sphere_env_sky.npy", skin1_env_sky),
         "marble_sphere_env": ("skin1_sphere_env_sky.npy", skin1_env_sky),
         "skin1_teapot_env": ("skin1_sphere_env_sky.npy", skin1_env_sky),
         "g05_sphere_env14": ("skin1_sphere_env_sky.npy", skin1_env_sky)}
"""Environment maps of reference scenes, written next to their scene file before a reference is rendered."""


def make_reference(name: str, directory: Path = REFERENCES, spp: int | None = None,
                   command: str | None = None) -> dict:
    """Render and write ``<directory>/<name>.npz`` and ``<name>.json`` (two half-spp renders with seeds
    :data:`REFERENCE_SEEDS`) of the scene ``<directory>/<name>.toml`` (a first-order reference: its scene's).

    Args:
        name: the reference's name.
        directory: where the scene file is and the reference goes.
        spp: samples per pixel in all (default :data:`REFERENCE_SPP`).
        command: the command line recorded in the sidecar (default this module's ``--references NAME``).
    """
    import mitsuba as mi

    from jaxsss.export import mitsuba as xm
    from jaxsss.export.compare import compare_images, pixel_geometry
    from jaxsss.render import load_scene

    if name in SKIES:
        file, make = SKIES[name]
        np.save(directory / file, make())
    scene_name = FIRST_ORDER_REFERENCES.get(name, name)
    max_depth = 2 if name in FIRST_ORDER_REFERENCES else -1
    scene = load_scene(directory / f"{scene_name}.toml")
    variant = xm.select_variant()
    spp = REFERENCE_SPP[name] if spp is None else spp
    halves = [xm.render_mitsuba(scene, spp=spp // 2, seed=s, max_depth=max_depth) for s in REFERENCE_SEEDS]
    t0 = time.perf_counter()
    coverage = xm.object_coverage(scene, spp=1024, seed=7)
    coverage_seconds = time.perf_counter() - t0
    image = 0.5 * (halves[0].image + halves[1].image)
    # Noise of the average of two halves: half the mean |relative difference| between them (each half has twice
    # the variance of the average, and their difference twice that of one half).
    noise = compare_images(halves[0].image, halves[1].image, pixel_geometry(scene), coverage=coverage)
    if command is None:
        command = shlex.join(["benchmarks/render_vs_path_tracer.py", "--references", name])
    meta = {
        "scene": f"{scene_name}.toml",
        "command": f"nice -n 10 python {command}",
        "renderer": "mitsuba", "mitsuba_version": mi.__version__, "variant": variant,
        "integrator": "volpathmis (jaxsss.export.mitsuba.scene_dict)", "max_depth": max_depth, "spp": spp,
        "seeds": list(REFERENCE_SEEDS), "spp_per_seed": spp // 2,
        "seconds": sum(h.seconds for h in halves), "load_seconds": sum(h.load_seconds for h in halves),
        "coverage_spp": 1024, "coverage_seconds": coverage_seconds,
        "noise_mare_lit": [0.5 * v for v in noise["mare_lit"]],
        "noise_mare_binned": [0.5 * v for v in noise["mare_binned"]],
        # Mitsuba's float32 rays skip a layer below the boundary: its optical depth (an upper bound over the object;
        # the first order at incidence cosine mu is exp(-depth / mu) of the exact one; jaxsss.export.mitsuba).
        "skipped_layer_optical_depth": [float(v) for v in xm.skipped_layer(scene)],
        "units": "image: linear radiance W/(mm^2 sr), float32; coverage: fraction of each pixel on the object",
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "load_average_1min": os.getloadavg()[0],
    }
    np.savez_compressed(directory / f"{name}.npz", image=image.astype(np.float32),
                        coverage=coverage.astype(np.float32))
    (directory / f"{name}.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


def jaxsss_rows(name, scene, ref, coverage, pixels, settings):
    from benchmarks._harness import make_row
    from benchmarks.render_eps import compile_clock
    from jaxsss.export.compare import compare_images
    from jaxsss.render import make_plan, render

    rows, images = [], {}
    for method, eps, bssrdf in settings:
        if eps == "plan":
            eps = make_plan(scene, method=method, bssrdf=bssrdf).eps
        kwargs = {"method": method, "bssrdf": bssrdf} if eps is None else {"method": method, "eps": eps,
                                                                            "bssrdf": bssrdf}
        with compile_clock() as c:
            render(scene, **kwargs)  # the warm-up, as Mitsuba's: compilation and one-time loads (tables, plan)
        with compile_clock() as warm:
            result = render(scene, **kwargs)  # timed: the whole render again (plan, pass 1, tree, pass 2)
        m = compare_images(result.image, ref, pixels, coverage=coverage)
        label = (method if eps is None else f"{method} eps={eps:g}") + f" {bssrdf}"
        images[label] = result.image
        rows.append(make_row(NAME, f"{name}: jaxsss {method} {bssrdf}", label, max(m["mare_lit"]), ERROR_METRIC,
                             max(warm["wall"] - warm["compile"], 1e-9), c["compile"], scene=name, renderer="jaxsss",
                             bssrdf=bssrdf, first_call_seconds=max(c["wall"] - c["compile"], 1e-9), **m))
    return rows, images


def order_split(scene, ref, coverage, pixels, first_ref) -> dict:
    """jaxsss's default render split into the marched first order and the rest (the orders >= 2), each against its
    path-traced part: ``first_ref`` (Mitsuba at ``max_depth = 2``) and ``ref - first_ref``."""
    from jaxsss.export.compare import compare_images, error_by_cos
    from jaxsss.render import render

    result = render(scene)
    first = result.prepared.state.first_order_image(scene.material.medium)
    if first is None:
        return {"first_order": None, "why": "the plan does not march the first order"}
    first, image = np.asarray(first), np.asarray(result.image)
    keep = ("mare_lit", "mare_binned", "sum_ratio")
    one = compare_images(first, first_ref, pixels, coverage=coverage)
    rest = compare_images(image - first, ref - first_ref, pixels, coverage=coverage)
    return {"first_order": {k: one[k] for k in keep}, "orders_2_up": {k: rest[k] for k in keep},
            "orders_2_up_by_cos": error_by_cos(image - first, ref - first_ref, pixels, coverage=coverage)}


def mitsuba_rows(name, scene, ref, coverage, pixels, spps):
    from benchmarks._harness import make_row
    from jaxsss.export import mitsuba as xm
    from jaxsss.export.compare import compare_images

    rows = []
    warm = xm.render_mitsuba(scene, spp=spps[0], seed=99)  # compiles the LLVM kernels (reused for every spp)
    for spp in spps:
        r = xm.render_mitsuba(scene, spp=spp, seed=1000 + spp)
        m = compare_images(r.image, ref, pixels, coverage=coverage)
        compile_s = max(warm.seconds - r.seconds, 0.0) if spp == spps[0] else None
        rows.append(make_row(NAME, f"{name}: mitsuba {r.variant}", f"{spp} spp", max(m["mare_lit"]), ERROR_METRIC,
                             r.seconds, compile_s, scene=name, renderer="mitsuba", spp=spp,
                             load_seconds=r.load_seconds, **m))
    return rows


def equal_error(jaxsss_row: dict, mitsuba_rows: list, reference_noise=None) -> dict:
    """Mitsuba's seconds at jaxsss's error, and the ratio, three ways:

    - the line through the two highest-spp Mitsuba rows in log error against log seconds;
    - from the highest row at the Monte Carlo rate ``error ~ 1/sqrt(spp)``;
    - the same with the reference's own noise apart (given ``reference_noise``): both renderers are measured against
      a reference with noise ``f`` per channel, so the path tracer's error per channel is ``e^2 = f^2 + c^2 /
      seconds``, ``c`` from the highest row, and it reaches jaxsss's error ``E`` (the largest over the channels)
      when every channel has, at ``max c^2 / (E^2 - f^2)``. Near the floor the plain estimates understate the path
      tracer's seconds (they extrapolate a convergence the floor slows); where ``E`` is at or under a channel's
      floor the path tracer cannot be measured to reach it against this reference (``mitsuba_seconds_floor`` None).

    Args:
        jaxsss_row: one jaxsss row (``error``, ``seconds``).
        mitsuba_rows: the scene's Mitsuba rows at two or more spp (with ``mare_lit`` per channel for the floor).
        reference_noise: the reference's noise per channel (its sidecar's ``noise_mare_lit``), or None.

    Returns:
        ``error``, ``seconds``; ``slope`` of the line; ``mitsuba_seconds`` and ``ratio`` by the line;
        ``mitsuba_seconds_sqrt`` and ``ratio_sqrt`` at ``1/sqrt(spp)``; ``mitsuba_seconds_floor`` and
        ``ratio_floor`` with the noise apart (None without ``reference_noise``). A ratio above 1: jaxsss is faster.
    """
    if len(mitsuba_rows) < 2:
        raise ValueError(f"equal_error(mitsuba_rows=...) has {len(mitsuba_rows)} rows; it needs at least 2")
    a, b = sorted(mitsuba_rows, key=lambda r: r["seconds"])[-2:]
    e, t = jaxsss_row["error"], jaxsss_row["seconds"]
    slope = math.log(b["error"] / a["error"]) / math.log(b["seconds"] / a["seconds"])
    line = b["seconds"] * (e / b["error"]) ** (1.0 / slope)
    sqrt = b["seconds"] * (b["error"] / e) ** 2
    floor = None
    if reference_noise is not None:
        f2 = np.asarray(reference_noise, dtype=float) ** 2
        # c^2 per channel from the highest row, >= 0 (a channel already at its floor there needs no more time).
        c2 = np.maximum(np.asarray(b["mare_lit"], dtype=float) ** 2 - f2, 0.0) * b["seconds"]
        if e * e > f2.max():
            floor = float(np.max(c2 / (e * e - f2)))
    return {"error": e, "seconds": t, "slope": slope, "mitsuba_seconds": line, "ratio": line / t,
            "mitsuba_seconds_sqrt": sqrt, "ratio_sqrt": sqrt / t, "mitsuba_seconds_floor": floor,
            "ratio_floor": None if floor is None else floor / t}


def format_equal_error(name: str, q: dict) -> str:
    """One printed line of :func:`equal_error`'s result for scene ``name``."""
    floor = ("under the reference's noise" if q["mitsuba_seconds_floor"] is None else
             f"{q['mitsuba_seconds_floor']:.1f} s: {q['ratio_floor']:.1f}x")
    return (f"{name}: {q['setting']} error {q['error']:.3f} in {q['seconds']:.2f} s; Mitsuba at equal error "
            f"{q['mitsuba_seconds']:.1f} s (slope {q['slope']:.2f}): {q['ratio']:.1f}x, at 1/sqrt(spp) "
            f"{q['mitsuba_seconds_sqrt']:.1f} s: {q['ratio_sqrt']:.1f}x; the reference's noise apart {floor}")


def error_vs_seconds_plot(rows, path):
    """One panel per scene: error (max over RGB of mare_lit) against seconds, Mitsuba's spp sweep as a line, each
    jaxsss row as a labelled marker (the harness's single panel is unreadable with six scenes)."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    cols = 3
    fig, axes = plt.subplots(-(-len(scenes) // cols), cols, figsize=(4.6 * cols, 3.6 * -(-len(scenes) // cols)),
                             squeeze=False, layout="constrained")
    for ax, name in zip(axes.flat, scenes):
        mine = [r for r in rows if r["scene"] == name]
        mi = sorted((r for r in mine if r["renderer"] == "mitsuba"), key=lambda r: r["spp"])
        ax.plot([r["seconds"] for r in mi], [r["error"] for r in mi], "o-", color="0.4", label="Mitsuba")
        for r in mi:
            ax.annotate(f"{r['spp']} spp", (r["seconds"], r["error"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        for r in (r for r in mine if r["renderer"] == "jaxsss"):
            ax.plot(r["seconds"], r["error"], "s" if r["setting"].startswith("hierarchical") else "^",
                    label=r["setting"])
        ax.set(xscale="log", yscale="log", title=name, xlabel="seconds (compilation apart)")
        for axis in (ax.xaxis, ax.yaxis):  # minor labels of a short log range overlap
            axis.set_minor_formatter(NullFormatter())
            axis.set_major_formatter(ScalarFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="upper right")
    for ax in axes.flat[len(scenes):]:
        ax.set_axis_off()
    axes[0, 0].set_ylabel("max over RGB of mare_lit")
    fig.suptitle("jaxsss vs Mitsuba volpathmis: error against the high-spp reference vs seconds")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def error_maps_plot(panels, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(panels), 5, figsize=(13, 2.8 * len(panels)), squeeze=False)
    for row, (name, ref, test, emap) in zip(axes, panels):
        peak = np.nanmax(ref)
        row[0].imshow(np.clip(ref / peak, 0, 1) ** (1 / 2.2))
        row[0].set_title(f"{name}: Mitsuba reference", fontsize=8)
        row[1].imshow(np.clip(test / peak, 0, 1) ** (1 / 2.2))
        row[1].set_title("jaxsss hierarchical (" + name.split(" ", 1)[-1] + ")", fontsize=8)
        for c in range(3):
            im = row[2 + c].imshow(emap[..., c], cmap="RdBu_r", vmin=-0.5, vmax=0.5)
            row[2 + c].set_title(f"(jaxsss - ref) / ref, {'RGB'[c]}", fontsize=8)
        fig.colorbar(im, ax=row[-1], fraction=0.046)
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    llvm_env()
    if argv is None:
        argv = sys.argv[1:]
    if "--references" in argv:
        for name in [a for a in argv if a in SCENES + FIT_VIEWS + CHECKS + tuple(FIRST_ORDER_REFERENCES)] or SCENES:
            meta = make_reference(name)
            print(f"{name}: {meta['spp']} spp, {meta['variant']}, {meta['seconds']:.1f} s, "
                  f"noise {np.round(meta['noise_mare_lit'], 4).tolist()}")
        return 0
    from benchmarks._harness import parse_args, write_results
    from jaxsss.export import mitsuba as xm
    from jaxsss.export.compare import BIN, error_by_cos, error_map, pixel_geometry
    from jaxsss.render import make_plan

    args = parse_args(argv, __doc__.splitlines()[0])
    cfg = CONFIG["quick" if args.quick else "full"]
    variant = xm.select_variant()
    rows, panels, summary = [], [], {"mitsuba_variant": variant}
    for name in SCENES:
        scene, ref, coverage, meta = load_reference(name)
        pixels = pixel_geometry(scene)
        jrows, images = jaxsss_rows(name, scene, ref, coverage, pixels, cfg["jaxsss"])
        rows += jrows + mitsuba_rows(name, scene, ref, coverage, pixels, cfg["mitsuba_spp"])
        for kernel in ("dipole", "white-oblique"):
            hier = images[next(k for k in images if k.startswith("hierarchical") and k.endswith(" " + kernel))]
            panels.append((f"{name} {kernel}", ref, hier, error_map(hier, ref, pixels, coverage=coverage)))
        # The plan's own kernel ("auto") at the plan's eps, against Mitsuba at equal error.
        auto = make_plan(scene, method="hierarchical", bssrdf="auto")
        row = next(r for r in jrows if r["setting"] == f"hierarchical eps={auto.eps:g} {auto.bssrdf}")
        summary[name] = {"reference_spp": meta["spp"], "reference_seconds": meta["seconds"],
                         "reference_noise_mare": meta["noise_mare_lit"],
                         "equal_error": {"setting": row["setting"], **equal_error(
                             row, [r for r in rows if r["scene"] == name and r["renderer"] == "mitsuba"],
                             meta["noise_mare_lit"])},
                         "jaxsss_error_by_cos": {label: error_by_cos(img, ref, pixels, coverage=coverage)
                                                 for label, img in images.items()}}
    for first_name, name in FIRST_ORDER_REFERENCES.items():
        scene, ref, coverage, _ = load_reference(name)
        first_ref = load_reference(first_name)[1]
        summary[name]["order_split"] = order_split(scene, ref, coverage, pixel_geometry(scene), first_ref)
    notes = [f"Mitsuba {variant}; references: tests/export/references/*.json",
             "seconds: both renderers after one warm-up render per scene: jaxsss the whole render (plan, pass 1, tree, "
             "pass 2; first_call_seconds: the warm-up without compilation), Mitsuba mi.render"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title="jaxsss vs Mitsuba volpathmis: error vs seconds")
    png_path = error_vs_seconds_plot(rows, png_path)
    maps = error_maps_plot(panels, Path(args.out) / f"{NAME}{args.tag}_maps.png")
    def rnd(v):  # null (no terminator band under an environment) prints as nan
        return np.round(np.asarray(v, dtype=float), 3).tolist()

    for r in rows:
        print(f"{r['method']:40s} {str(r['setting']):22s} mare_lit {rnd(r['mare_lit'])} "
              f"band {rnd(r['mare_band'])} sum {rnd(r['sum_ratio'])} {BIN}x{BIN} {rnd(r['mare_binned'])} "
              f"{r['seconds']:.2f} s (compile {r['compile_seconds'] or 0:.2f}"
              + (f", first call {r['first_call_seconds']:.2f} s)" if "first_call_seconds" in r else ")"))
    for name in SCENES:
        for label, bins in summary[name]["jaxsss_error_by_cos"].items():
            print(f"{name} jaxsss {label}: signed relative error by cos(normal, to light)")
            for b in bins:
                print(f"  cos [{b['cos'][0]:+.2f}, {b['cos'][1]:+.2f}] n={b['n']:4d} bias "
                      f"{rnd(b['bias'])} mare {rnd(b['mare'])}")
    for name in SCENES:
        print(format_equal_error(name, summary[name]["equal_error"]))
    for name in FIRST_ORDER_REFERENCES.values():
        split = summary[name]["order_split"]
        for part in ("first_order", "orders_2_up"):
            if split.get(part):
                print(f"{name} {part}: " + "; ".join(f"{k} {rnd(v)}" for k, v in split[part].items()))
    print(f"wrote {json_path}, {png_path}, {maps}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
