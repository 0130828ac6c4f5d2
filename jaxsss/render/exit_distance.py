"""The exit direction by distance from the point of entry: light that has travelled far leaves less grazing.

Chandrasekhar's ``X(mu_o | mu_i)`` (:func:`jaxsss.render.bssrdf.exit_distribution`) is the angular distribution of
*all* the light a half-space reflects. Near the entry it is dominated by low orders of scattering, which leave
grazing (for a beam at ``mu_i = 0.1`` and albedo 0.91, 4.2x a Lambertian exit at ``mu_o = 0.05`` within half a mean
free path, against ``X`` = 3.0); light that has diffused further leaves closer to a Lambertian (2.3x at 1-2 mfp, 1.7x
at 2-4, 1.3x at 4-8). The dark side of a sphere is lit only by light from far away, and where the eye sees it at a
grazing angle (the limb) the whole-profile ``X`` made it too bright: the held-out chicken1 sphere's red was 35-62%
too bright at ``mu_o < 0.4`` on the dark side, 3-11% at ``mu_o`` 0.4-0.7 (docs/path_tracer.md, "Exit by distance").

Measured by the walk (:func:`generate_exit_distance_table`), the ratio of the light's exit distribution at distance
``d`` from the entry to the whole beam's is close to one shape scaled by a function of ``d``:

    X(mu_o | mu_i, d) = X(mu_o | mu_i) (1 + c(d) phi(mu_o)),

the shape ``phi`` (a rank-1 fit over the distance bins, weighted by their light; ``int X phi 2 mu dmu = 0``, so the
exitance is unchanged) and ``c`` (by ``d`` in mean free paths ``sigma_t' d``; negative near the entry, where light
leaves more grazing, and rising to 1 far out) tabulated per incidence node and albedo. Over a whole half-space the
light-weighted mean of ``c`` is 0, so the exit is ``X`` again. The sums carry a second exitance per node, ``sum F R
c(d)`` (:class:`jaxsss.render.bssrdf.WhiteKernel`, ``exit_split``), which leaves by ``X phi``.

``python -m jaxsss.render.exit_distance --regenerate`` remakes ``data/exit_distance.npz``.
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["SPLIT_ALBEDO", "SPLIT_D", "SPLIT_MUS", "amplitude_at", "distance_amplitude", "exit_split_distribution",
           "fit_exit_distance", "generate_exit_distance_table", "load_exit_distance_table", "node_rows"]

SPLIT_MUS = (1.0, 0.75, 0.5, 0.25, 0.1)
"""Incidence cosines of the table (the kernels' nodes are among them)."""
SPLIT_ALBEDO = (0.1, 0.3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995)
"""Single-scattering albedos of the table (linear between, held beyond the ends)."""
SPLIT_D_EDGES = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, np.inf])
SPLIT_D = tuple(float(x) for x in np.append(0.5 * (SPLIT_D_EDGES[1:-2] + SPLIT_D_EDGES[:-3]), 30.0))
"""Distances (mean free paths, ``sigma_t' d``) of the amplitude ``c`` nodes: the bins' centres (the last bin's at
30); linear between, held beyond."""
SPLIT_MU_EDGES = np.linspace(0.0, 1.0, 21)
SPLIT_PHOTONS = 1_000_000
SPLIT_TABLE = Path(__file__).resolve().parent / "data" / "exit_distance.npz"


def _rank_one(q: np.ndarray, light: np.ndarray, x: np.ndarray, mu: np.ndarray,
              far_bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(c (D,), phi (B,))``: the light-weighted rank-1 fit ``q - 1 ~ c phi`` of the distance bins' exit ratios
    ``q`` ``(D, B)`` (weights ``light`` ``(D,)``), ``phi`` made orthogonal to ``X 2 mu`` (no change of exitance),
    of unit RMS over the bins and signed so that ``c`` is positive over ``far_bins`` (far light leaves less
    grazing)."""
    w = np.sqrt(light / light.sum())
    u, sv, vt = np.linalg.svd((q - 1.0) * w[:, None], full_matrices=False)
    phi = vt[0]
    # No change of the exitance: int X phi 2 mu dmu = 0.
    weight = x * 2.0 * mu
    phi = phi - weight @ phi / (weight @ weight) * weight
    # The amplitude per distance bin: least squares of (q - 1) on phi.
    c = (q - 1.0) @ phi / (phi @ phi)
    # Unit RMS shape, signed so that the light beyond 2 mean free paths has c > 0.
    scale = np.sqrt(np.mean(phi * phi)) * (1.0 if (light * c)[far_bins].sum() >= 0.0 else -1.0)
    return c * scale, phi / scale


def fit_exit_distance(tallies: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(c (U, A, D), phi (U, A, B))`` from the walk's tallies ``(U, A, D, B)`` (light per photon by distance and
    exit-cosine bin): the rank-1 fit per incidence and albedo, ``c`` held beyond the last bin with light and clipped so
    that ``1 + c phi >= 0.05`` in every bin (the rank-1 form is poorest where little light is: strong absorption,
    normal incidence, a few mean free paths out; there it must not send negative light)."""
    from jaxsss.render.bssrdf import exit_distribution

    centres = 0.5 * (SPLIT_MU_EDGES[1:] + SPLIT_MU_EDGES[:-1])
    amp = np.zeros(tallies.shape[:3])
    shape = np.zeros(tallies.shape[:2] + tallies.shape[3:])
    for k in range(tallies.shape[0]):
        for j in range(tallies.shape[1]):
            h = tallies[k, j]
            light, total = h.sum(axis=1), h.sum(axis=0)
            ok = light > 1e-6 * light.sum()
            # Each distance bin's exit distribution over the whole beam's, bin by bin.
            q = np.where(ok[:, None] & (total > 0), (h / np.where(ok, light, 1.0)[:, None])
                         / np.where(total > 0, total / total.sum(), 1.0), 1.0)
            x = np.asarray(exit_distribution(centres, np.array([SPLIT_MUS[k]]), np.array([SPLIT_ALBEDO[j]])))[:, 0, 0]
            c, phi = _rank_one(q[ok], light[ok], x, centres, np.asarray(SPLIT_D)[ok] >= 2.0)
            # Positive exit in every bin: c phi >= -0.95.
            c = np.clip(c, -0.95 / max(phi.max(), 1e-12), 0.95 / max(-phi.min(), 1e-12))
            amp[k, j, ok] = c
            # Held beyond the last bin with light.
            amp[k, j, np.flatnonzero(ok)[-1] + 1:] = c[-1]
            shape[k, j] = phi
    return amp, shape


def generate_exit_distance_table(photons: int = SPLIT_PHOTONS, seed: int = 21, progress: bool = True) -> dict:
    """Run the walks and return the table: the amplitude ``c`` ``(U, A, D)`` and shape ``phi`` ``(U, A, B)`` over
    :data:`SPLIT_MUS`, :data:`SPLIT_ALBEDO`, :data:`SPLIT_D` and the exit-cosine bins, the tallies ``H`` ``(U, A, D,
    B)`` (light per photon), and metadata."""
    from tqdm.auto import tqdm

    from jaxsss.render.walk import pencil_beam_walk

    t0 = time.perf_counter()
    n_b, n_d = len(SPLIT_MU_EDGES) - 1, len(SPLIT_D)
    d_edges = np.append(SPLIT_D_EDGES[:-2], np.inf)
    tallies = np.zeros((len(SPLIT_MUS), len(SPLIT_ALBEDO), n_d, n_b))
    nodes = [(k, j) for k in range(len(SPLIT_MUS)) for j in range(len(SPLIT_ALBEDO))]
    for k, j in tqdm(nodes, desc="exit by distance", disable=not progress):
        h = tallies[k, j]

        def add(first, exit_point, direction, weight):
            h[:] += np.histogram2d(np.hypot(exit_point[:, 0], exit_point[:, 1]), direction[:, 2],
                                   [d_edges, SPLIT_MU_EDGES], weights=weight)[0]

        pencil_beam_walk(SPLIT_ALBEDO[j], SPLIT_MUS[k], photons, seed + 100 * k + j, add)
        h /= photons
    amp, shape = fit_exit_distance(tallies)
    return {"c": amp, "phi": shape, "H": tallies, "mus": np.asarray(SPLIT_MUS), "albedo": np.asarray(SPLIT_ALBEDO),
            "d": np.asarray(SPLIT_D), "mu_edges": SPLIT_MU_EDGES, "photons": photons, "seed": seed,
            "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk: index-matched isotropic half-space, pencil beam"}


@functools.lru_cache(maxsize=1)
def load_exit_distance_table() -> dict:
    """The shipped table (:data:`SPLIT_TABLE`) as NumPy arrays (cached)."""
    with np.load(SPLIT_TABLE) as f:
        return {k: f[k] for k in f.files}


def node_rows(table, table_mus, table_albedo, mus, albedo, what: str, coordinate: str = "albedo"):
    """``(K, C, ...)``: a ``(U, A, ...)`` ``table`` over incidence nodes ``table_mus`` and albedos ``table_albedo``
    (ascending), at the incidence nodes ``mus`` (each one of ``table_mus``; else a ValueError naming ``what``), linear
    between the albedo nodes in ``coordinate`` at the albedos ``(C,)`` (held beyond the ends; differentiable in
    ``albedo``):

    - ``"albedo"``: linear in the albedo itself;
    - ``"diffusion"``: linear in ``sqrt(1 - albedo)``, diffusion's ``sigma_tr / sigma_t'`` over ``sqrt 3``: the
      coordinate in which light's reach changes evenly near albedo 1 (the diffusion length ``l_d / l_u = 1 / sqrt(3 (1
      - albedo))`` is 3.3 at 0.97, 5.1 at 0.987 and 8.2 at 0.995). For the far part of the curvature correction
      (:mod:`jaxsss.render.curvature_correction`) at 0.987 on spheres of 7-7.4 ``l_u``, linear in the albedo took
      ``Q`` 8-16% under a walk's at 8-13 ``l_u`` from the entry; in this coordinate 0-8%."""
    from jaxsss.render.passage import node_interval

    table_mus = tuple(float(m) for m in table_mus)
    missing = [m for m in mus if float(m) not in table_mus]
    if missing:
        raise ValueError(f"{what}: mus {missing} have no table; it has {tuple(table_mus)}")
    if coordinate not in ("albedo", "diffusion"):
        raise ValueError(f"{what}: coordinate {coordinate!r}; allowed: 'albedo', 'diffusion'")
    tab = jnp.asarray(table[np.asarray([tuple(table_mus).index(float(m)) for m in mus])])  # (K, A, ...)
    nodes = np.asarray(table_albedo, dtype=np.float64)
    v = jnp.atleast_1d(albedo)
    if coordinate == "diffusion":
        # -sqrt(1 - a), ascending with a; a held at the end nodes first (the square root's slope is infinite at 1).
        v = -jnp.sqrt(1.0 - jnp.clip(v, nodes[0], nodes[-1]))
        nodes = -np.sqrt(1.0 - nodes)
    i, t = node_interval(v, nodes)
    t = t.reshape((1, -1) + (1,) * (tab.ndim - 2))
    # Linear in the coordinate.
    return tab[:, i] * (1.0 - t) + tab[:, i + 1] * t


def _node_rows(name: str, mus, albedo):
    """``(K, C, ...)``: table ``name`` at the incidence nodes ``mus``, linear in the albedos ``(C,)``."""
    return node_rows(load_exit_distance_table()[name], SPLIT_MUS, SPLIT_ALBEDO, mus, albedo,
                     "exit_distance (exit by distance)")


def distance_amplitude(mus, albedo) -> jnp.ndarray:
    """``(K, D, C)``: the amplitude ``c`` at the nodes :data:`SPLIT_D` for the incidence nodes ``mus`` and albedos
    ``(C,)`` (differentiable in ``albedo``); :func:`jaxsss.render.bssrdf.WhiteKernel` interpolates it per pair."""
    return jnp.moveaxis(_node_rows("c", mus, albedo), 1, 2)


def amplitude_at(table, d_mfp):
    """``(P, K, C)``: the amplitude ``c`` of :func:`distance_amplitude`'s ``table`` ``(K, D, C)`` at ``d_mfp``
    ``(P, 1 or K, C)`` mean free paths from the entry (linear between :data:`SPLIT_D`, held beyond)."""
    from jaxsss.render.passage import piecewise_linear

    # Linear in d between the nodes.
    return piecewise_linear(d_mfp, SPLIT_D, jnp.moveaxis(table, 1, 0)[:, None])


def exit_split_distribution(mu_o, mus, albedo):
    """``(Q, 2K, C)``: ``X`` then ``X phi`` for exit cosines ``mu_o`` ``(Q,)``, the incidence nodes ``mus`` (each one
    of :data:`SPLIT_MUS`) and albedos ``(C,)``: Chandrasekhar's ``X`` (:func:`jaxsss.render.bssrdf.exit_distribution`)
    and the tabulated shape, linear in the albedo and between the exit-cosine bins' centres (held beyond them).
    Differentiable in ``albedo``."""
    from jaxsss.render.bssrdf import exit_distribution

    phi = _node_rows("phi", mus, albedo)  # (K, C, B)
    centres = 0.5 * (SPLIT_MU_EDGES[1:] + SPLIT_MU_EDGES[:-1])
    u = (jnp.clip(mu_o, centres[0], centres[-1]) - centres[0]) / (centres[1] - centres[0])
    b = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, len(centres) - 2)
    f = (u - b.astype(u.dtype))[:, None, None]
    # Linear between the bins' centres: (Q, K, C).
    phi_q = jnp.moveaxis(phi[..., b], -1, 0) * (1.0 - f) + jnp.moveaxis(phi[..., b + 1], -1, 0) * f
    x = exit_distribution(mu_o, jnp.asarray(mus), albedo)  # (Q, K, C)
    return jnp.concatenate([x, x * phi_q], axis=1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m jaxsss.render.exit_distance",
                                description="The exit-by-distance table of the white kernels "
                                            "(jaxsss.render.exit_distance).")
    p.add_argument("--regenerate", action="store_true", help="run the walks and write the table")
    p.add_argument("--refit", action="store_true", help="refit c and phi from the shipped tallies (no walk)")
    p.add_argument("--photons", type=int, default=SPLIT_PHOTONS,
                   help=f"photons per (incidence, albedo) node (default {SPLIT_PHOTONS})")
    args = p.parse_args(argv)
    if args.refit:
        tab = dict(load_exit_distance_table())
        tab["c"], tab["phi"] = fit_exit_distance(tab["H"])
        np.savez_compressed(SPLIT_TABLE, **tab)
        print(f"refitted {SPLIT_TABLE}")
        return 0
    if not args.regenerate:
        tab = load_exit_distance_table()
        print(f"{SPLIT_TABLE}: c {tab['c'].shape} (mu_i, albedo, d), phi {tab['phi'].shape} (mu_i, albedo, mu_o "
              f"bin); {int(tab['photons'])} photons per node, {float(tab['seconds']):.0f} s")
        return 0
    tab = generate_exit_distance_table(args.photons)
    SPLIT_TABLE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(SPLIT_TABLE, **{k: np.asarray(v) for k, v in tab.items()})
    print(f"wrote {SPLIT_TABLE} in {tab['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
