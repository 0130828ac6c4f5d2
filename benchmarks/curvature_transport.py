"""The curvature ratio against transport: a pencil beam into an index-matched sphere and into a half-space.

The renderer multiplies each (shaded point, sample) pair's half-space profile by the sphere-to-plane ratio of the
diffusion dipole with a Kelvin image (:func:`jaxsss.render.curvature.curvature_ratio`, its source at depth ``mu_i
l_u`` for light incident at cosine ``mu_i``), and a light column's flux by the chance of an interaction along the
chord its refracted ray cuts, ``1 - exp(-sigma_t t)`` (:mod:`jaxsss.render.passage`). Here the same ratio is
measured by transport itself: an analogue Monte Carlo walk (isotropic scattering, ``g = 0``, ``eta = 1``, absorption
by weight, roulette below a weight of 1e-3) of a pencil beam entering a sphere of radius ``R`` at its pole at
incidence cosine ``mu_i``, and the same beam into a half-space. Light that leaves before its first interaction is
not tallied (the renderer's passage lets it through). The exitance per unit area at chord distance ``d`` from the
entry point, azimuth-averaged (on the sphere the area within chord ``d`` is ``pi d^2``, as on the plane), gives
``C_MC(d) = M_sphere(d) / M_plane(d)``; the renderer's counterpart is ``C_model(d) = (1 - exp(-sigma_t 2 R mu_i))
C_Kelvin(d; depth mu_i)``. The renderer also shifts an oblique profile's centre forward, by at most its truncated
mean travel (a few mm, :func:`jaxsss.render.passage.truncated_travel`); that is left out here, so compare beyond it.
The walk is independent of the renderer and of ``jaxsss.mc`` (whose layered geometry has no sphere).

Rows: one per medium and incidence; ``error`` is the largest ``|C_model / C_MC - 1|`` over the chord bins with at
least 100 photons in both tallies; extra keys hold ``d``, ``C_MC`` with its standard error (from 8 batches), and
``C_model``, and ``half_space_cut``: :func:`truncated_ratio`, the half-space's own exitance when its beam's first
flight is cut at the chord (what a chord does to a grazing beam, without the curvature). ``seconds``: the walks
(NumPy; no compilation). ``--quick``: 4e4 photons per walk (full: 4e5).
"""

from __future__ import annotations

import itertools
import sys
import time

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results
from jaxsss.render.walk import isotropic_directions, roulette

NAME = "curvature_transport"
RADIUS = 20.0
"""mm: the reference spheres' radius (tests/export/references)."""
MEDIA = {"skin1 R": (0.032, 0.74), "potato R": (0.0024, 0.68), "ketchup R": (0.061, 0.18),
         "chicken1 R": (0.015, 0.15)}
"""``(sigma_a, sigma_s')`` per mm, Jensen et al. 2001 (red channels: l_u 1.3, 1.5, 4.2 and 6.1 mm)."""
EDGES = np.array([0.5, 1.0, 2.0, 3.0, 5.0, 7.5, 10.0, 14.0, 18.0, 22.0, 26.0, 30.0, 34.0, 38.0, 40.0])
PHOTONS, QUICK_PHOTONS = 400_000, 40_000
BATCHES = 8
MIN_ORDERS = (1, 2)
"""All the collided light, and the orders >= 2 alone (the kernel's share with the first order marched)."""
MUS = (1.0, 0.3, 0.1)
"""Incidence cosines: normal, and two grazing ones (the light near a sphere's terminator)."""
METRIC = "max |C_model / C_MC - 1| over chord bins (pencil beam)"


def pencil_beam_exitance(geometry: str, sigma_a: float, sigma_s: float, n: int, seed: int,
                         radius: float = RADIUS, edges: np.ndarray = EDGES, mu_i: float = 1.0,
                         first_flight_max: float = np.inf, min_order: int = 1):
    """``(exitance (B,) per unit area per photon, photons (B,))`` at chord distances ``edges`` from the entry point of
    a pencil beam at incidence cosine ``mu_i`` into ``geometry`` ("sphere" of ``radius``, or "plane": the half-space
    ``z < 0``), the light that leaves before its first interaction left out. ``first_flight_max`` (mm): photons whose
    first flight is longer leave (a beam truncated as a chord of that length truncates it). ``min_order``: tally only
    the light scattered at least that many times (2: what the renderer's kernel holds when the first order is marched,
    :mod:`jaxsss.render.first_order`)."""
    rng = np.random.default_rng(seed)
    sigma_t = sigma_a + sigma_s
    albedo = sigma_s / sigma_t
    entry = np.array([0.0, 0.0, radius if geometry == "sphere" else 0.0])
    pos = np.tile(entry, (n, 1))
    d = np.tile([np.sqrt(1.0 - mu_i * mu_i), 0.0, -mu_i], (n, 1))
    w = np.ones(n)
    order = 0  # interactions so far: every photon still inside has had the same number
    tally, count = np.zeros(len(edges) - 1), np.zeros(len(edges) - 1)
    collided = False
    while len(w):
        step = -np.log(rng.random(len(w))) / sigma_t
        new = pos + step[:, None] * d
        out = (np.einsum("ij,ij->i", new, new) > radius**2) if geometry == "sphere" else new[:, 2] > 0.0
        if not collided:
            out |= step > first_flight_max
        if out.any() and order >= max(min_order, 1):
            p, v = pos[out], d[out]
            if geometry == "sphere":  # where the step leaves the sphere
                b = np.einsum("ij,ij->i", p, v)
                t = -b + np.sqrt(np.maximum(b * b - (np.einsum("ij,ij->i", p, p) - radius**2), 0.0))
            else:
                t = -p[:, 2] / v[:, 2]
            chord = np.linalg.norm(p + t[:, None] * v - entry, axis=1)
            tally += np.histogram(chord, edges, weights=w[out])[0]
            count += np.histogram(chord, edges)[0]
        collided = True
        order += 1
        keep = ~out
        pos, w = new[keep], w[keep] * albedo
        d = isotropic_directions(rng, len(w))
        alive = roulette(rng, w)
        pos, d, w = pos[alive], d[alive], w[alive]
    return tally / n / (np.pi * (edges[1:] ** 2 - edges[:-1] ** 2)), count


def measured_ratio(sigma_a: float, sigma_s: float, photons: int, seed: int = 0, mu_i: float = 1.0,
                   min_order: int = 1):
    """``(C_MC, stderr, min photons per bin, plane exitance per bin)`` from :data:`BATCHES` independent batches of each
    walk (the light scattered at least ``min_order`` times)."""
    runs = []
    counts = np.zeros((2, len(EDGES) - 1))
    for b in range(BATCHES):
        sphere, cs = pencil_beam_exitance("sphere", sigma_a, sigma_s, photons // BATCHES, seed + 2 * b, mu_i=mu_i,
                                          min_order=min_order)
        plane, cp = pencil_beam_exitance("plane", sigma_a, sigma_s, photons // BATCHES, seed + 2 * b + 1, mu_i=mu_i,
                                         min_order=min_order)
        runs.append((sphere, plane))
        counts += np.stack([cs, cp])
    sphere, plane = (np.array(x) for x in zip(*runs))
    ratio = sphere.mean(0) / np.maximum(plane.mean(0), 1e-300)
    # Delta method over the batch means.
    rel = np.hypot(sphere.std(0, ddof=1) / np.maximum(sphere.mean(0), 1e-300),
                   plane.std(0, ddof=1) / np.maximum(plane.mean(0), 1e-300)) / np.sqrt(BATCHES)
    return ratio, ratio * rel, counts.min(axis=0), plane.mean(0)


def truncated_ratio(sigma_a: float, sigma_s: float, photons: int, mu_i: float, chord: float, seed: int = 0):
    """``T(d)``: the exitance of a half-space's beam whose first flight is cut at ``chord`` over the uncut one's (two
    walks from the same seed: the same first flights, the cut ones leave). On the sphere a chord cuts the beam the
    same way, so ``C_MC ~ T x`` the curvature gain."""
    cut, _ = pencil_beam_exitance("plane", sigma_a, sigma_s, photons, seed, mu_i=mu_i, first_flight_max=chord)
    full, _ = pencil_beam_exitance("plane", sigma_a, sigma_s, photons, seed, mu_i=mu_i)
    return cut / np.maximum(full, 1e-300)


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    from jaxsss.render.curvature import curvature_ratio

    photons = QUICK_PHOTONS if args.quick else PHOTONS
    mid = 0.5 * (EDGES[1:] + EDGES[:-1])
    rows = []
    area = np.pi * (EDGES[1:] ** 2 - EDGES[:-1] ** 2)
    for min_order, (name, (sa, ss)), mu in itertools.product(MIN_ORDERS, MEDIA.items(), MUS):
        t0 = time.perf_counter()
        c_mc, se, n_min, plane = measured_ratio(sa, ss, photons, mu_i=mu, min_order=min_order)
        seconds = time.perf_counter() - t0
        passage = 1.0 - np.exp(-(sa + ss) * 2.0 * RADIUS * mu)
        c_model = passage * np.asarray(curvature_ratio(mid, 1.0 / RADIUS, sa, ss, 1.0, mu))
        cut = truncated_ratio(sa, ss, photons // 2, mu, 2.0 * RADIUS * mu) if mu < 1.0 else np.ones_like(mid)
        ok = n_min >= 100
        err = float(np.max(np.abs(c_model[ok] / c_mc[ok] - 1.0))) if ok.any() else None
        # The whole beam's gain over the half-space (within the last edge): transport's and the model's.
        w = plane * area / np.sum(plane * area)
        total_mc, total_model = float(np.sum(w * c_mc)), float(np.sum(w * c_model))
        rows.append(make_row(NAME, f"{name}, orders >= {min_order}", f"mu_i {mu:g}", err, METRIC, seconds, None,
                             mu_i=mu, min_order=min_order, chord_mm=mid.tolist(), c_mc=c_mc.tolist(),
                             c_mc_stderr=se.tolist(), c_model=c_model.tolist(), half_space_cut=cut.tolist(),
                             photons_min=n_min.tolist(), total_mc=total_mc, total_model=total_model,
                             l_u_mm=1.0 / (sa + ss), photons=photons))
        print(f"{name:<11} orders >= {min_order}, l_u {1 / (sa + ss):4.2f} mm, mu_i {mu:g} ({seconds:.0f} s): "
              f"whole beam {total_mc:.3f} (model {total_model:.3f})\n  d (mm)  "
              + " ".join(f"{x:6.1f}" for x in mid) + "\n  C_MC    " + " ".join(f"{x:6.2f}" for x in c_mc)
              + "\n  +-      " + " ".join(f"{x:6.2f}" for x in se)
              + "\n  model   " + " ".join(f"{x:6.2f}" for x in c_model)
              + "\n  cut     " + " ".join(f"{x:6.2f}" for x in cut), flush=True)
    write_results(NAME, rows, args.out, quick=args.quick, connect=False,
                  notes=[f"sphere radius {RADIUS} mm, eta 1, g 0, pencil beams at mu_i {MUS}; {BATCHES} batches"],
                  title="curvature ratio x passage: the renderer against a transport walk")
    _plot_ratios(rows, args.out, args.tag)
    return 0


def _plot_ratios(rows, out, tag: str = "") -> None:
    """``C_MC`` (points with 2 standard errors), ``C_model`` (lines) and the half-space with its beam cut at the
    chord (dotted) against the chord distance, one panel per incidence cosine and one colour per medium (circles: all
    the collided light; squares and a dashed line: the orders >= 2)."""
    import matplotlib

    matplotlib.use("Agg")
    from pathlib import Path

    import matplotlib.pyplot as plt

    mus = list(dict.fromkeys(r["mu_i"] for r in rows))
    fig, axes = plt.subplots(1, len(mus), figsize=(5.0 * len(mus), 4.5), layout="constrained", sharey=True)
    for ax, mu in zip(np.atleast_1d(axes), mus):
        for r in (x for x in rows if x["mu_i"] == mu):
            d = np.asarray(r["chord_mm"])
            k = list(MEDIA).index(r["method"].split(",")[0])
            first = r["min_order"] == 1
            ax.errorbar(d, r["c_mc"], yerr=2 * np.asarray(r["c_mc_stderr"]), fmt="o" if first else "s", ms=4,
                        color=f"C{k}", capsize=2, label=f"{r['method']} (l_u {r['l_u_mm']:.1f} mm): transport")
            ax.plot(d, r["c_model"], "-" if first else "--", color=f"C{k}", label=f"{r['method']}: renderer")
            if mu < 1.0 and first:
                ax.plot(d, r["half_space_cut"], ":", color=f"C{k}",
                        label=f"{r['method']}: half-space, beam cut at the chord")
        ax.set(yscale="log", xlabel="chord distance from the entry point, mm", title=f"pencil beam, mu_i = {mu:g}")
        ax.grid(True, which="both", alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel(f"exitance on the sphere (radius {RADIUS:g} mm) / on the plane")
    np.atleast_1d(axes)[0].legend(fontsize=6, ncol=2)
    fig.savefig(Path(out) / f"{NAME}{tag}_ratios.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
