"""Photon diffusion in meshes (``--method photon``) against the mesh Monte Carlo: error against run time.

What is measured. Four validation scenes, all with ``sigma_a = 0.01``, ``sigma_s' = 0.99`` 1/mm (``alpha' = 0.99``,
``l_d = 5.8 mm``), ``eta = 1.3``, lit by a narrow spot (a beam of about 3.5 mm diameter) or a directional light:

- ``flat``: a 60 x 60 x 40 mm box lit in the middle of its top face: a half-space far from every edge, where the
  classic surface-sampled dipole is at home (the equal-error time comparison);
- ``edge``: a 30 x 30 x 20 mm box lit 3 mm from a top edge (the paper's Figure 5); points on the top face and down
  the side face;
- ``thin``: a 2 mm slab lit from below; points on the top face (transmission, the multipole);
- ``blocker``: an 8 mm slab with an absorbing 8 x 4 mm bar through its middle, lit from below by a directional light;
  points on the top face across the bar (volumetric shadow; disc radius 2 mm: the exitance is spread thin).

The reference is the same photon walk continued to the exits (:mod:`jaxsss.photon.reference`): multiply scattered
exitance (order >= 2, what diffusion models), disc kernel of radius 0.5 mm (2 mm for ``blocker``), 1e6 photons (quick: 1e5). ``error`` is
the relative L2 error over the points where the reference's relative standard error is below 10%; ``ref_noise`` is
the reference's own relative L2 standard error on those points (the floor no model can beat).

Rows: ``photon`` for photon counts 1e4 .. 3e5 at eps = 0.05 and for eps 0.02 .. 0.2 at 1e5 photons; ``hierarchical``
(the surface-sampled dipole of :mod:`jaxsss.render`) at the scene's sample density and at 4x. ``seconds`` is the whole
method at the points (photon tracing or irradiance samples, octree, interaction lists, the sum) without compilation
(``compile_seconds`` apart). ``equal_error`` rows: the fewest photons whose error is at most the hierarchical
method's, with the time ratio.
"""

from __future__ import annotations

import sys
import time

import equinox as eqx
import numpy as np

from benchmarks._harness import make_row, parse_args, write_results

NAME = "photon_render"
ERROR_METRIC = "relative L2 vs mesh Monte Carlo (order >= 2, disc kernel)"
MATERIAL = {"sigma_a": 0.01, "sigma_s_prime": 0.99, "eta": 1.3}
CONFIG = {
    "quick": {"mc": 100_000, "photons": (10_000, 30_000), "eps": (0.05, 0.2), "eps_photons": 30_000,
              "density": (1.0,)},
    "full": {"mc": 1_000_000, "photons": (10_000, 30_000, 100_000, 300_000), "eps": (0.02, 0.05, 0.1, 0.2),
             "eps_photons": 100_000, "density": (1.0, 4.0)},
}
RADIUS = {"flat": 0.5, "edge": 0.5, "thin": 0.5, "blocker": 2.0}


def _spot(x, y, z, direction):
    return {"type": "spot", "position": [x, y, z], "direction": direction, "cone_deg": 0.5, "intensity": 1.0e5}


def cases():
    """``{name: (scene dict, points (Q, 3), normals (Q, 3))}`` of the four validation scenes."""
    cam = {"position": [100.0, -100.0, 100.0], "look_at": [0.0, 0.0, 0.0]}
    out = {}
    line = np.linspace(-12.0, 12.0, 49)
    pts = np.stack([line, np.zeros_like(line), np.full_like(line, 20.0)], 1)
    out["flat"] = ({"mesh": {"builtin": "box", "extents": [60.0, 60.0, 40.0]}, "material": MATERIAL,
                    "light": [_spot(0.0, 0.0, 220.0, [0, 0, -1.0])], "camera": cam},
                   pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    top = np.stack([np.linspace(3.0, 14.8, 40), np.zeros(40), np.full(40, 10.0)], 1)
    side = np.stack([np.full(40, 15.0), np.zeros(40), np.linspace(9.8, 0.0, 40)], 1)
    out["edge"] = ({"mesh": {"builtin": "box", "extents": [30.0, 30.0, 20.0]}, "material": MATERIAL,
                    "light": [_spot(12.0, 0.0, 210.0, [0, 0, -1.0])], "camera": cam},
                   np.concatenate([top, side]),
                   np.concatenate([np.tile([0.0, 0.0, 1.0], (40, 1)), np.tile([1.0, 0.0, 0.0], (40, 1))]))
    pts = np.stack([line, np.zeros_like(line), np.full_like(line, 1.0)], 1)
    out["thin"] = ({"mesh": {"builtin": "slab", "width": 60.0, "depth": 60.0, "thickness": 2.0},
                    "material": MATERIAL, "light": [_spot(0.0, 0.0, -201.0, [0, 0, 1.0])], "camera": cam},
                   pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    line = np.linspace(-20.0, 20.0, 41)
    pts = np.stack([line, np.zeros_like(line), np.full_like(line, 4.0)], 1)
    out["blocker"] = ({"mesh": {"builtin": "slab", "width": 60.0, "depth": 40.0, "thickness": 8.0},
                       "material": MATERIAL, "blocker": [{"builtin": "box", "extents": [8.0, 36.0, 4.0]}],
                       "light": [{"type": "directional", "direction": [0.0, 0.0, 1.0], "intensity": 1.0}],
                       "camera": cam},
                      pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    return out


def _error(model, ref, mask):
    return float(np.linalg.norm((model - ref)[mask]) / np.linalg.norm(ref[mask]))


@eqx.filter_jit
def _exitance(prepared, medium):
    return prepared.exitance(medium)


def _timed(prepare_points, exitance, medium):
    """``(exitance (Q,) of channel 0, seconds without compilation, compile seconds, info)`` of one method: its
    geometry (``prepare_points() -> (prepared, _, info)``), then its jitted ``exitance`` compiled apart."""
    t0 = time.perf_counter()
    prep, _, info = prepare_points()
    t_geo = time.perf_counter() - t0
    t0 = time.perf_counter()
    fn = exitance.lower(prep, medium).compile()
    t_comp = time.perf_counter() - t0
    t0 = time.perf_counter()
    m = np.asarray(fn(prep, medium))[:, 0]
    return m, t_geo + time.perf_counter() - t0, t_comp, info


def _photon(scene, pts, nrm, n, eps):
    from jaxsss.photon.render import prepare_photon

    return _timed(lambda: prepare_photon(scene, n_photons=n, eps=eps, points=(pts, nrm)), _exitance,
                  scene.material.medium)


def _hierarchical(scene, pts, nrm, density):
    from jaxsss.render.renderer import prepare
    from jaxsss.render.scene import RenderSettings, scene_with

    scene = scene_with(scene, render=RenderSettings(density=density))
    return _timed(lambda: prepare(scene, points=(pts, nrm)), _exitance, scene.material.medium)


def main(argv=None) -> int:
    from jaxsss.photon.reference import mesh_monte_carlo, surface_exitance
    from jaxsss.render.scene import parse_scene

    args = parse_args(argv, __doc__.splitlines()[0])
    cfg = CONFIG["quick" if args.quick else "full"]
    rows, summary, profiles = [], {}, {}
    for case, (data, pts, nrm) in cases().items():
        scene = parse_scene(data)
        t0 = time.perf_counter()
        mc = mesh_monte_carlo(scene, cfg["mc"])
        t_mc = time.perf_counter() - t0
        ref = surface_exitance(mc.exits, scene.mesh, pts, nrm, RADIUS[case], min_order=2)
        val, se = ref.value[:, 0], ref.stderr[:, 0]
        mask = np.isfinite(val) & (val > 0) & (se < 0.1 * np.where(val > 0, val, np.inf))
        if not mask.any():  # too few reference photons for any point (the blocker case in --quick)
            print(f"{case}: reference {t_mc:.1f} s, no point with stderr < 10%: case left out", file=sys.stderr)
            summary[case] = {"left_out": f"no point with reference stderr < 10% at {cfg['mc']:.0e} photons"}
            continue
        noise = float(np.linalg.norm(se[mask]) / np.linalg.norm(val[mask]))
        rows.append(make_row(NAME, "mesh Monte Carlo", f"{case} N={cfg['mc']:.0e}", noise, "relative L2 stderr",
                             t_mc, None, case=case, points=int(mask.sum())))
        print(f"{case}: reference {t_mc:.1f} s, {int(mask.sum())} points, noise {noise:.3f}", file=sys.stderr)
        prof = {"points": pts.tolist(), "mc": val.tolist(), "mask": mask.tolist()}
        runs = [(n, 0.05) for n in cfg["photons"]] + [(cfg["eps_photons"], e) for e in cfg["eps"] if e != 0.05]
        photon_rows = []
        for n, eps in runs:
            m, sec, comp, info = _photon(scene, pts, nrm, n, eps)
            err = _error(m, val, mask)
            photon_rows.append((n, eps, err, sec))
            rows.append(make_row(NAME, "photon", f"{case} N={n:.0e} eps={eps:g}", err, ERROR_METRIC, sec, comp,
                                 case=case, photons=n, eps=eps, ref_noise=noise, sources=info["n_sources"],
                                 pairs=info["n_interactions"], multipole_pairs=info["n_interactions_multipole"],
                                 blocked_pairs=info["n_pairs_blocked"]))
            prof[f"photon N={n:.0e} eps={eps:g}"] = m.tolist()
            print(f"  photon N={n} eps={eps}: error {err:.3f}, {sec:.2f} s", file=sys.stderr)
        hier = []
        for dens in cfg["density"]:
            m, sec, comp, info = _hierarchical(scene, pts, nrm, dens)
            err = _error(m, val, mask)
            hier.append((err, sec))
            rows.append(make_row(NAME, "hierarchical", f"{case} density={dens:g}", err, ERROR_METRIC, sec, comp,
                                 case=case, density=dens, ref_noise=noise, samples=info["n_samples"]))
            prof[f"hierarchical density={dens:g}"] = m.tolist()
            print(f"  hierarchical density={dens}: error {err:.3f}, {sec:.2f} s", file=sys.stderr)
        h_err, h_sec = min(hier)
        at_eps = [r for r in photon_rows if r[1] == 0.05]
        good = [r for r in at_eps if r[2] <= h_err]
        summary[case] = {"reference_noise": noise, "hierarchical_error": h_err, "hierarchical_seconds": h_sec,
                         "photon_error_most_photons": at_eps[-1][2], "photon_seconds_most_photons": at_eps[-1][3]}
        if good:
            n, _, err, sec = good[0]
            summary[case].update(photon_photons_at_equal_error=n, photon_seconds_at_equal_error=sec,
                                 time_ratio_photon_over_hierarchical=sec / h_sec)
            rows.append(make_row(NAME, "equal error", f"{case}: photon N={n:.0e} vs hierarchical", err, ERROR_METRIC,
                                 sec, None, case=case, hierarchical_error=h_err, hierarchical_seconds=h_sec,
                                 time_ratio=sec / h_sec))
        profiles[case] = prof
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=[__doc__.split("\n\n")[1]], connect=False,
                                        title="photon diffusion vs mesh Monte Carlo")
    _plot_profiles(profiles, png_path.with_name(png_path.stem + "_profiles.png"))
    print(json_path)
    return 0


def _plot_profiles(profiles, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(profiles), figsize=(4.2 * len(profiles), 3.6))
    for ax, (case, prof) in zip(axes, profiles.items(), strict=True):
        k = np.arange(len(prof["mc"]))
        mask = np.asarray(prof["mask"])
        ax.semilogy(k[mask], np.asarray(prof["mc"])[mask], "k.", label="mesh MC (order >= 2)")
        photon = [key for key in prof if key.startswith("photon") and key.endswith("eps=0.05")]
        hier = [key for key in prof if key.startswith("hierarchical")]
        for key in (photon[-1], hier[-1]):
            ax.semilogy(k, np.maximum(prof[key], 1e-12), "-", label=key)
        ax.set_title(case)
        ax.set_xlabel("point index along the line" + (" (top, then side)" if case == "edge" else ""))
        ax.set_ylabel("exitance, W/mm^2")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
