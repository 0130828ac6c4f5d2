"""The exit direction on a curved surface: light that reaches a sphere's surface from inside leaves less grazing.

Along a direction that leaves a convex surface at a grazing angle the eye sees through only a thin shell of the
medium: on a sphere of radius ``a`` the ray inside is a chord of length ``2 a mu_o``, against an unbounded ray in a
half-space, and the light it gathers comes from near the surface. So a sphere's exit distribution is darker towards
grazing views and brighter along the normal than the half-space's (Chandrasekhar's, which the white kernels use),
the more so the smaller the sphere in transport lengths and the further the light travelled from its entry. A pencil
beam walk (:func:`jaxsss.render.walk.pencil_beam_walk` in a sphere and in a half-space, orders >= 2, isotropic,
index-matched), chicken1's red (albedo 0.91) on the 20 mm sphere (``a = 3.3 l_u``), at normal incidence: the
radiance leaving at ``mu_o`` 0.05 / 0.25 / 0.55 / 0.95 is 0.24 / 0.57 / 0.88 / 1.34 of the half-space's (same
exitance), and 0.17 / 0.34 / 0.65 / 1.78 for the light that exits 6-8 ``l_u`` from the entry; skin1's red (``a =
15 l_u``) 0.74 / 0.94 / 1.02 / 1.02. Against Mitsuba on chicken1's sphere the kernel's orders >= 2 were 19-26% too
bright at grazing views (``cos`` to the eye below 0.4) and 9-13% too dark in red near the normal (above 0.9)
(docs/path_tracer.md, "The exit on a curved surface").

Measured by the walk (:func:`generate_exit_curvature_table`), the ratio of the sphere's exit distribution to the
half-space's at chord ``d`` from the entry is close to one shape scaled by a function of the curvature and ``d``:

    X_2(mu_o | mu_i, d, kappa) = X_2(mu_o | mu_i) (1 + c(kappa l_u, d / l_u) phi(mu_o)),

the shape ``phi`` (a rank-1 fit over the spheres and distance bins, weighted by their light; ``int X_2 phi 2 mu dmu
= 0``, so the exitance is unchanged) and ``c`` (0 on a plane; tabulated per incidence node and albedo on
:data:`CURVED_KAPPA` x :data:`CURVED_D`). With the first order marched (:mod:`jaxsss.render.first_order`) the sums
carry a second exitance per node, ``sum F R C c`` (:attr:`jaxsss.render.bssrdf.WhiteKernel.exit_curved`), which
leaves by ``X_2 phi``; each pair's ``kappa`` is :func:`jaxsss.render.curvature.pair_curvature` (concave pairs: 0).
The near-field disc (within ``rho_0`` of the shaded point) keeps the plane's exit: ``c`` there is 0.02-0.14 within
half a transport length of the entry, but up to 0.26 at one on the smallest sphere (``a = 3.3 l_u``), which a
disc as wide as chicken1's red one (2.3 ``l_u``) leaves out.

``python -m jaxsss.render.exit_curvature --regenerate`` remakes ``data/exit_curvature.npz``.
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["CELL_D", "CELL_KAPPA", "CURVED_ALBEDO", "CURVED_D", "CURVED_KAPPA", "CURVED_MUS", "curved_amplitude",
           "curved_amplitude_at", "curved_amplitude_cells", "curved_exit_distribution", "fit_exit_curvature",
           "generate_exit_curvature_table", "load_exit_curvature_table"]

CURVED_MUS = (1.0, 0.75, 0.5, 0.1)
"""Incidence cosines of the table: the white-oblique kernel's nodes (1 and :data:`jaxsss.render.bssrdf.KERNEL_MUS`)
and 0.75, the lights-behind kernel's (:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`); descending (the lookups take
the shipped table's own ``mus``)."""
CURVED_ALBEDO = (0.3, 0.6, 0.8, 0.9, 0.97)
"""Single-scattering albedos of the table (linear between, held beyond the ends)."""
CURVED_RADII = (25.0, 16.0, 11.0, 7.5, 5.0, 3.3)
"""Sphere radii of the walks, transport lengths (``g = 0``: mean free paths)."""
CURVED_KAPPA = (0.0,) + tuple(1.0 / a for a in CURVED_RADII)
"""Curvature nodes ``kappa l_u`` (0: the plane, where ``c = 0``; linear between, held beyond ``1 / 3.3``)."""
CURVED_D_EDGES = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, np.inf])
CURVED_D = tuple(float(x) for x in np.append(0.5 * (CURVED_D_EDGES[1:-1] + CURVED_D_EDGES[:-2]), 16.0))
"""Distance nodes ``d / l_u`` of ``c``: the bins' centres (the last bin's at 16); linear between, held beyond."""
CURVED_MU_EDGES = np.linspace(0.0, 1.0, 21)
CURVED_PHOTONS = 1_000_000
CURVED_TABLE = Path(__file__).resolve().parent / "data" / "exit_curvature.npz"


def _histogram(albedo: float, mu_i: float, radius: float | None, photons: int, seed: int) -> np.ndarray:
    """``(D, B)``: the orders >= 2's light per photon by chord from the entry (:data:`CURVED_D_EDGES`, mean free
    paths) and exit cosine to the outward normal (:data:`CURVED_MU_EDGES`), in a sphere of ``radius`` or (None) the
    half-space."""
    from jaxsss.render.walk import pencil_beam_walk

    h = np.zeros((len(CURVED_D_EDGES) - 1, len(CURVED_MU_EDGES) - 1))
    centre = np.zeros(3) if radius is None else np.array([0.0, 0.0, -float(radius)])

    def add(first, exit_point, direction, weight):
        normal = np.tile([0.0, 0.0, 1.0], (len(weight), 1)) if radius is None else (exit_point - centre) / radius
        mu = np.clip(np.einsum("ij,ij->i", normal, direction), 0.0, 1.0)
        h[:] += np.histogram2d(np.linalg.norm(exit_point, axis=1), mu, [CURVED_D_EDGES, CURVED_MU_EDGES],
                               weights=weight)[0]

    pencil_beam_walk(albedo, mu_i, photons, seed, add, radius=radius, min_order=2)
    return h / photons


def fit_exit_curvature(sphere: np.ndarray, plane: np.ndarray, mus=CURVED_MUS) -> tuple[np.ndarray, np.ndarray]:
    """``(c (U, A, R + 1, D), phi (U, A, B))`` from the walks' tallies at the incidence nodes ``mus``: ``sphere``
    ``(U, A, R, D, B)`` over :data:`CURVED_RADII` and ``plane`` ``(U, A, D, B)``. Per incidence and albedo, the
    light-weighted rank-1 fit of the bins' ratios ``q - 1 ~ c phi`` (``q``: a sphere's exit distribution in a distance
    bin over the plane's in the same bin); ``phi`` orthogonal to ``X_2 2 mu``
    (:func:`jaxsss.render.bssrdf.multiple_exit_distribution`), unit RMS, signed so that far light leaves less grazing
    (``c > 0``); ``c = 0`` at ``kappa = 0``, held beyond the last bin with light and clipped so that ``1 + c phi >=
    0.05`` in every bin."""
    from jaxsss.render.bssrdf import multiple_exit_distribution

    mu = 0.5 * (CURVED_MU_EDGES[1:] + CURVED_MU_EDGES[:-1])
    n_u, n_a, n_r, n_d, _ = sphere.shape
    amp = np.zeros((n_u, n_a, n_r + 1, n_d))
    shape = np.zeros((n_u, n_a, len(mu)))
    for k in range(n_u):
        for j in range(n_a):
            p = plane[k, j]
            p_dist = p / np.maximum(p.sum(axis=1, keepdims=True), 1e-300)
            rows, light, where = [], [], []
            for r in range(n_r):
                s = sphere[k, j, r]
                s_light = s.sum(axis=1)
                for b in range(n_d):
                    if s_light[b] > 1e-3 * s_light.sum() and np.all(p[b] > 0):
                        rows.append((s[b] / s_light[b]) / p_dist[b] - 1.0)
                        light.append(s_light[b])
                        where.append((r, b))
            q, light = np.array(rows), np.array(light)
            w = np.sqrt(light / light.sum())
            phi = np.linalg.svd(q * w[:, None], full_matrices=False)[2][0]
            # No change of the exitance: int X_2 phi 2 mu dmu = 0.
            x = np.asarray(multiple_exit_distribution(mu, np.array([float(mus[k])]),
                                                      np.array([CURVED_ALBEDO[j]])))[:, 0, 0]
            weight = x * 2.0 * mu
            phi = phi - weight @ phi / (weight @ weight) * weight
            phi = phi / np.sqrt(np.mean(phi * phi))
            c = q @ phi / (phi @ phi)
            # Far light leaves less grazing: the light-weighted c positive.
            if light @ c < 0.0:
                phi, c = -phi, -c
            c = np.clip(c, -0.95 / max(phi.max(), 1e-12), 0.95 / max(-phi.min(), 1e-12))
            table = np.full((n_r, n_d), np.nan)
            for (r, b), v in zip(where, c):
                table[r, b] = v
            for r in range(n_r):
                ok = np.flatnonzero(np.isfinite(table[r]))
                # Held beyond the last bin with light (and before the first, which has light in every walk).
                table[r] = np.interp(np.arange(n_d), ok, table[r, ok])
            # Radii from large to small, after the plane's row of zeros.
            amp[k, j, 1:] = table
            shape[k, j] = phi
    return amp, shape


def generate_exit_curvature_table(photons: int = CURVED_PHOTONS, seed: int = 31, progress: bool = True,
                                  mus=CURVED_MUS) -> dict:
    """Run the walks (``mus``, default :data:`CURVED_MUS`, x :data:`CURVED_ALBEDO`, each on a half-space and the
    spheres of :data:`CURVED_RADII`; seeds ``seed + 1000 k + 100 j``, ``k`` the node's
    :func:`jaxsss.render.walk.seed_slot` among :data:`CURVED_MUS`) and return the table: ``c`` ``(U, A,
    len(CURVED_KAPPA), D)``, ``phi`` ``(U, A, B)``, the tallies and metadata."""
    from tqdm.auto import tqdm

    from jaxsss.render.walk import seed_slot

    t0 = time.perf_counter()
    n_d, n_b = len(CURVED_D_EDGES) - 1, len(CURVED_MU_EDGES) - 1
    mus = tuple(float(m) for m in mus)
    sphere = np.zeros((len(mus), len(CURVED_ALBEDO), len(CURVED_RADII), n_d, n_b))
    plane = np.zeros((len(mus), len(CURVED_ALBEDO), n_d, n_b))
    nodes = [(k, j) for k in range(len(mus)) for j in range(len(CURVED_ALBEDO))]
    for k, j in tqdm(nodes, desc="exit on a curved surface", disable=not progress):
        base = seed + 1000 * seed_slot(mus[k], CURVED_MUS) + 100 * j
        plane[k, j] = _histogram(CURVED_ALBEDO[j], mus[k], None, photons, base)
        for r, radius in enumerate(CURVED_RADII):
            sphere[k, j, r] = _histogram(CURVED_ALBEDO[j], mus[k], radius, photons, base + 1 + r)
    amp, shape = fit_exit_curvature(sphere, plane, mus)
    return {"c": amp, "phi": shape, "sphere": sphere, "plane": plane, "mus": np.asarray(mus),
            "albedo": np.asarray(CURVED_ALBEDO), "radii": np.asarray(CURVED_RADII), "kappa": np.asarray(CURVED_KAPPA),
            "d": np.asarray(CURVED_D), "d_edges": CURVED_D_EDGES, "mu_edges": CURVED_MU_EDGES, "photons": photons,
            "seed": seed, "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk: index-matched isotropic sphere and half-space, orders >= 2"}


@functools.lru_cache(maxsize=1)
def load_exit_curvature_table() -> dict:
    """The shipped table (:data:`CURVED_TABLE`) as NumPy arrays (cached)."""
    with np.load(CURVED_TABLE) as f:
        return {k: f[k] for k in f.files}


def _node_rows(name: str, mus, albedo):
    """``(K, C, ...)``: table ``name`` at the incidence nodes ``mus``, linear in the albedos ``(C,)``."""
    from jaxsss.render.exit_distance import node_rows

    table = load_exit_curvature_table()
    return node_rows(table[name], tuple(table["mus"]), CURVED_ALBEDO, mus, albedo,
                     "exit_curvature (curved exit)")


def curved_amplitude(mus, albedo) -> jnp.ndarray:
    """``(N_kappa, D, K, C)``: the amplitude ``c`` on :data:`CURVED_KAPPA` x :data:`CURVED_D` for the incidence
    nodes ``mus`` and albedos ``(C,)`` (differentiable in ``albedo``); the kernel interpolates it per pair
    (:func:`curved_amplitude_cells`, :func:`curved_amplitude_at`)."""
    return jnp.transpose(_node_rows("c", mus, albedo), (2, 3, 0, 1))


CELL_KAPPA, CELL_D = 0.005, 0.25
"""Spacing of the uniform grid the kernel resamples ``c`` on (``kappa l_u``, ``d / l_u``): every distance node lies on
it, and a pair's cell is then a multiplication, not a search (:func:`curved_amplitude_cells`)."""


def curved_amplitude_cells(table):
    """``(N_k - 1, N_d - 1, K, C, 4)`` bilinear coefficients (``f00, f10 - f00, f01 - f00, f11 - f10 - f01 + f00``)
    of :func:`curved_amplitude`'s ``table`` resampled on the uniform grid of :data:`CELL_KAPPA` x :data:`CELL_D` up to
    the last nodes (linear between the table's nodes, so the same function); differentiable in the table."""
    from jaxsss.render.passage import piecewise_linear

    kappa = np.arange(0.0, CURVED_KAPPA[-1] + CELL_KAPPA, CELL_KAPPA)
    d = np.arange(0.0, CURVED_D[-1] + CELL_D, CELL_D)
    # Linear in d at each curvature node, (N_kappa, N_d, K, C); then in kappa, (N_k, N_d, K, C).
    by_d = piecewise_linear(jnp.asarray(d)[:, None, None], CURVED_D, jnp.moveaxis(table, 1, 0)[:, :, None])
    f = piecewise_linear(jnp.asarray(kappa)[:, None, None, None], CURVED_KAPPA, by_d[:, None])
    f00, f10, f01, f11 = f[:-1, :-1], f[1:, :-1], f[:-1, 1:], f[1:, 1:]
    return jnp.stack([f00, f10 - f00, f01 - f00, f11 - f10 - f01 + f00], axis=-1)


def curved_amplitude_at(cells, kappa_lu, d_lu):
    """``(P, K, C)``: the amplitude ``c`` at the pairs' curvature ``kappa l_u`` and distance ``d / l_u`` (each ``(P, 1,
    C)``) from :func:`curved_amplitude_cells`' ``cells``: bilinear, held beyond the last nodes (one gather of a cell's
    four coefficients per element: the resampled grid needs no search)."""
    n_k, n_d, n_nodes, n_c = cells.shape[:4]
    x = jnp.clip(kappa_lu / CELL_KAPPA, 0.0, float(n_k))
    y = jnp.clip(d_lu / CELL_D, 0.0, float(n_d))
    i = jnp.minimum(jnp.floor(x), n_k - 1.0)
    j = jnp.minimum(jnp.floor(y), n_d - 1.0)
    u, v = x - i, y - j  # (P, 1, C)
    k = jnp.arange(n_nodes, dtype=jnp.int32)[None, :, None]
    c = jnp.arange(n_c, dtype=jnp.int32)[None, None, :]
    row = ((i.astype(jnp.int32) * n_d + j.astype(jnp.int32)) * n_nodes + k) * n_c + c  # (P, K, C)
    q = cells.reshape(-1, 4)[row]
    # Bilinear in (kappa l_u, d / l_u).
    return q[..., 0] + u * q[..., 1] + v * (q[..., 2] + u * q[..., 3])


def curved_exit_distribution(mu_o, mus, albedo):
    """``(Q, 2K, C)``: ``X_2`` then ``X_2 phi`` for exit cosines ``mu_o`` ``(Q,)``, the incidence nodes ``mus`` (each
    one of :data:`CURVED_MUS`) and albedos ``(C,)``: :func:`jaxsss.render.bssrdf.multiple_exit_distribution` and the
    tabulated shape, linear in the albedo and between the exit-cosine bins' centres (held beyond them).
    Differentiable in ``albedo``."""
    from jaxsss.render.bssrdf import multiple_exit_distribution
    from jaxsss.render.passage import piecewise_linear

    phi = jnp.moveaxis(_node_rows("phi", mus, albedo), -1, 0)  # (B, K, C)
    centres = 0.5 * (CURVED_MU_EDGES[1:] + CURVED_MU_EDGES[:-1])
    # Linear between the bins' centres: (Q, K, C).
    phi_q = piecewise_linear(jnp.asarray(mu_o)[:, None, None], centres, phi[:, None])
    x = multiple_exit_distribution(mu_o, jnp.asarray(mus), albedo)  # (Q, K, C)
    return jnp.concatenate([x, x * phi_q], axis=1)


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.exit_curvature", path=CURVED_TABLE, photons=CURVED_PHOTONS,
        description="The curved-exit table of the white kernels' orders >= 2 (jaxsss.render.exit_curvature).",
        photons_help="photons per walk (6 spheres and a half-space per node)", load=load_exit_curvature_table,
        refit=lambda tab: dict(zip(("c", "phi"), fit_exit_curvature(tab["sphere"], tab["plane"], tuple(tab["mus"])))),
        generate=generate_exit_curvature_table, node_keys=("c", "phi", "sphere", "plane"),
        describe=lambda tab: (f"c {tab['c'].shape} (mu_i, albedo, kappa l_u, d / l_u), phi {tab['phi'].shape} "
                              f"(mu_i, albedo, mu_o bin); {int(tab['photons'])} photons per walk, "
                              f"{float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
