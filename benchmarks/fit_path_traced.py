"""Fits from path-traced images: ``fitting.fit_image`` on the committed Mitsuba references (issue 17, item 4).

The truth comes from outside: each target is a Mitsuba 3 volumetric path tracing committed with the tests
(``tests/export/references``), and ``fit_image`` sees only the image, the lights and the camera. Cases:

- ``skin1_sphere``: one point light on the 20 mm sphere (eta 1); red's blur spans 4.6 pixels, green's and blue's
  under two (flagged).
- ``skin1_sphere + zoom``: the same plus an 8-degree lens at the terminator on the camera's side
  (``skin1_sphere_zoom``): every channel's blur resolved.
- ``skin1_sphere_env``: the same sphere behind a dielectric boundary (eta 1.4) under a sky with a soft sun: red's blur
  resolved (4.6 pixels), and the sphere's brightness grows with ``l_d`` (light flows round it), which the start has
  to get right (:data:`fitting.image_fit.RD_START_FINE`).

Each case is fitted with the renderer's stated error against Mitsuba, ``model_error=fitting.RENDER_MODEL_ERROR``
(its brightness level and its error per band of the cosine to the light, :mod:`fitting.discrepancy`), and with the
level alone (what ``RENDER_MODEL_ERROR`` stated before the bands). Weights: the reference's per-pixel noise (the
mean |relative difference| of its two halves) on its lit, fully covered pixels. Rows: ``error`` is the largest
``|estimate / truth - 1|`` of ``sigma_a`` and ``sigma_s'`` over the identifiable channels (None if none is);
extra keys hold each channel's relative errors, relative standard errors and ``|error| / stderr`` (``z``).
Goal (issue 17): within 5% per channel, or standard errors that say honestly how far off they may be (every
``z`` of an identifiable channel below 2). ``seconds``: the whole fit after compilation; ``compile_seconds`` apart.
``--quick``: 256 pixels per view (full: 1500).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results

NAME = "fit_path_traced"
REFERENCES = Path(__file__).resolve().parents[1] / "tests" / "export" / "references"
CASES = {"skin1_sphere": ("skin1_sphere",), "skin1_sphere + zoom": ("skin1_sphere", "skin1_sphere_zoom"),
         "skin1_sphere_env": ("skin1_sphere_env",)}
PIXELS, QUICK_PIXELS = 1500, 256
METRIC = "max |estimate / truth - 1| of sigma_a, sigma_s' over identifiable channels"


def load_view(name: str):
    """``(scene, target, stderr)``: a committed reference on its lit, fully covered pixels, weighted by its noise."""
    from jaxsss.export.compare import LIT_FRACTION
    from jaxsss.render import load_scene

    scene = load_scene(REFERENCES / f"{name}.toml")
    meta = json.loads((REFERENCES / f"{name}.json").read_text())
    with np.load(REFERENCES / f"{name}.npz") as f:
        image, coverage = f["image"].astype(np.float64), f["coverage"]
    lit = (coverage >= 0.999)[..., None] & (image > LIT_FRACTION * image.max(axis=(0, 1)))
    target = np.where(lit.all(axis=-1, keepdims=True), image, 0.0)
    stderr = np.where(target > 0, np.asarray(meta["noise_mare_lit"]) * target, 1.0)
    return scene, target, stderr


def fit_case(views, max_pixels: int, model_error) -> dict:
    import fitting

    scenes, targets, stderrs = (list(x) for x in zip(*views))
    fit = fitting.fit_image(scenes, targets, target_stderr=stderrs, max_pixels=max_pixels, model_error=model_error)
    truth = scenes[0].material.medium
    rel = np.concatenate([np.asarray(fit.sigma_a) / np.asarray(truth.sigma_a),
                          np.asarray(fit.sigma_s_prime) / np.asarray(truth.sigma_s_prime)]) - 1.0
    rel_se = np.concatenate([np.asarray(fit.sigma_a_stderr) / np.asarray(fit.sigma_a),
                             np.asarray(fit.sigma_s_prime_stderr) / np.asarray(fit.sigma_s_prime)])
    ok = np.tile(np.asarray(fit.identifiable), 2)
    seconds = {k: float(v) for k, v in fit.seconds.items()}
    return {"fit": fit, "rel": rel, "rel_se": rel_se, "z": np.abs(rel) / rel_se, "ok": ok, "seconds": seconds}


Y_LIMIT = 0.3
"""The error plot's axis, +-30%: estimates beyond it are drawn as arrows at the edge with their value."""


def plot_errors(rows: list[dict], path: Path) -> Path:
    """Each coefficient's relative error with +-2 standard error bars, one panel per case, the statements side by
    side: the bars cross 0 where the standard errors are honest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(dict.fromkeys(r["setting"] for r in rows))
    labels = [f"{k} {c}" for k in ("sigma_a", "sigma_s'") for c in "RGB"]
    fig, axes = plt.subplots(1, len(cases), figsize=(5.5 * len(cases), 4.0), sharey=True, layout="constrained")
    for ax, case in zip(np.atleast_1d(axes), cases):
        for j, r in enumerate(x for x in rows if x["setting"] == case):
            rel = np.array(r["rel_sigma_a"] + r["rel_sigma_s_prime"])
            se = rel / np.where(rel != 0, np.array(r["z_sigma_a"] + r["z_sigma_s_prime"]) * np.sign(rel), 1.0)
            ok = np.tile(r["identifiable"], 2)
            x = np.arange(6) + (j - 0.5) * 0.3
            for flag, face in ((True, f"C{j}"), (False, "none")):
                m = ok == flag
                ax.errorbar(x[m], rel[m], yerr=2 * np.abs(se[m]), fmt="o", color=f"C{j}", mfc=face, capsize=3,
                            label=f"{r['method']}" + ("" if flag else " (not identifiable)") if m.any() else None)
            # Estimates off the axis (a flagged channel on a plateau): an arrow at the edge with the value.
            for xi, v in zip(x, rel):
                if abs(v) > Y_LIMIT:
                    edge = np.sign(v) * 0.93 * Y_LIMIT
                    ax.annotate(f"{v:+.0%}", (xi, edge), xytext=(xi, edge - np.sign(v) * 0.12 * Y_LIMIT),
                                fontsize=7, color=f"C{j}", ha="center",
                                arrowprops={"arrowstyle": "->", "color": f"C{j}"})
        ax.set_ylim(-Y_LIMIT, Y_LIMIT)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.axhspan(-0.05, 0.05, color="0.9", zorder=0)
        ax.set_xticks(range(6), labels, rotation=30, fontsize=8)
        ax.set_title(case, fontsize=9)
        ax.legend(fontsize=7)
    np.atleast_1d(axes)[0].set_ylabel("estimate / truth - 1, bars +-2 standard errors")
    fig.suptitle("fit_image from Mitsuba references (grey: the 5% goal)", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    from fitting import RENDER_MODEL_ERROR

    pixels = QUICK_PIXELS if args.quick else PIXELS
    statements = {"bands": RENDER_MODEL_ERROR, "level only": RENDER_MODEL_ERROR.level}
    rows = []
    for case, names in CASES.items():
        views = [load_view(n) for n in names]
        for label, error in statements.items():
            r = fit_case(views, pixels, error)
            s = r["seconds"]
            err = float(np.max(np.abs(r["rel"][r["ok"]]))) if r["ok"].any() else None
            rows.append(make_row(
                NAME, label, f"{case}, {pixels} px/view", err, METRIC,
                sum(v for k, v in s.items() if k != "compile"), s["compile"],
                rel_sigma_a=r["rel"][:3].tolist(), rel_sigma_s_prime=r["rel"][3:].tolist(),
                rel_stderr_sigma_a=r["rel_se"][:3].tolist(), rel_stderr_sigma_s_prime=r["rel_se"][3:].tolist(),
                z_sigma_a=r["z"][:3].tolist(), z_sigma_s_prime=r["z"][3:].tolist(),
                identifiable=np.asarray(r["fit"].identifiable).tolist(), converged=bool(r["fit"].converged),
                max_z_identifiable=float(np.max(r["z"][r["ok"]])) if r["ok"].any() else None))
            print(f"{case:<22}{label:<12} err {err if err is None else round(err, 3)!s:<7} "
                  f"rel sigma_a {np.round(r['rel'][:3], 3)} sigma_s' {np.round(r['rel'][3:], 3)} "
                  f"z {np.round(r['z'], 1)} identifiable {np.asarray(r['fit'].identifiable)} "
                  f"{rows[-1]['seconds']:.0f} s (+{s['compile']:.0f} s compile)", flush=True)
    notes = ["targets: Mitsuba references committed in tests/export/references; weights: their per-pixel noise",
             "bands = fitting.RENDER_MODEL_ERROR (level + terminator bands); level only = its level"]
    write_results(NAME, rows, args.out, quick=args.quick, notes=notes, connect=False,
                  title="fit_image from path-traced images: largest error of an identifiable channel")
    plot_errors(rows, Path(args.out) / f"{NAME}{args.tag}_errors.png")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
