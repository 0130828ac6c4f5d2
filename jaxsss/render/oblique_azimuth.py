"""An oblique beam's light ahead of its entry on a curved surface: the first two azimuthal harmonics about the entry.

The white-oblique kernel (:mod:`jaxsss.render.bssrdf`) places an oblique beam's profile about a centre shifted forward
along the light's travel. The shift carries the beam's asymmetry near the entry; farther away the shifted profile
holds too little light ahead of the entry and too much behind it. Against a walk (index-matched, isotropic, orders >=
2, albedo 0.96, ``mu_i = 0.5``), the relative first harmonic of the exitance about the entry, ``L ~ 1 + H cos phi``
(``phi`` from the travel), is 0.75 in the walk and 0.48 in the kernel at 5.5 transport lengths, 0.70 against 0.36 at
9. On a sphere lit from behind, the camera sees the far side of the object, which is ahead of every oblique entry:
there the renderer's exitance was 0.6-0.8 of a walk on the whole sphere (``benchmarks/sphere_transport.py``).

The correction multiplies each oblique node's pair by

    f(phi) = G (1 + B cos phi + B_2 cos 2 phi),    G = 1 / (1 + (a_1 B + a_2 B_2) / 2),

with ``B, B_2`` chosen so that the product of ``f`` and the kernel's own azimuthal distribution ``1 + sum_n a_n cos n
phi`` has the walk's relative harmonics ``h_1, h_2`` (``h_n = 2 <L cos n phi> / <L>``): the cosine products give the
product's mean ``1 + (a_1 B + a_2 B_2) / 2`` and the linear system

    B (1 + a_2 / 2 - h_1 a_1 / 2) + B_2 (a_1 / 2 + a_3 / 2 - h_1 a_2 / 2) = h_1 - a_1,
    B (a_1 / 2 + a_3 / 2 - h_2 a_1 / 2) + B_2 (1 + a_4 / 2 - h_2 a_2 / 2) = h_2 - a_2.

``h_n`` is the pencil beam's in a sphere of curvature ``kappa`` at chord ``d`` (tallied by chord bin), ``a_n`` the
kernel's own at the same chord on the same sphere (its shifted profile times the curvature ratio and its transport
correction, :mod:`jaxsss.render.curvature_correction`, evaluated on a ring); ``G`` keeps the kernel's azimuthal mean
(which ``Q`` made the walk's). Where ``f`` would fall under :data:`AZIMUTH_FLOOR` at some azimuth, ``(B, B_2)`` are
scaled down together until it does not. Normal incidence has no azimuth (``B = B_2 = 0``, ``G = 1``).

Why two harmonics. A first harmonic alone cannot hold more than ``1 + H`` ahead against ``1 - H`` behind, and at low
albedo the walk's ``h_1`` exceeds 1 beyond two transport lengths (albedo 0.6, ``mu_i = 0.5``: 1.0-1.4); the factor
``1 + B cos phi`` was clipped at ``|B| <= 0.9`` in 12% of the table's cells. One irradiance sample of the back-lit
chicken1 sphere (``docs/path_tracer.md``, "The second azimuthal harmonic") against a pencil beam at its incidence
(``mu_i = 0.5``, 4-13 transport lengths) showed the light 16-21% short ahead of the entry and 9-68% too bright to its
sides in green and blue (albedo 0.73 and 0.67): the walk's light is more peaked along the travel than ``1 + H cos
phi`` can be. With both harmonics the back-lit chicken1 sphere went from mare_lit 0.162 / 0.228 / 0.238 to 0.156 /
0.184 / 0.217 against Mitsuba, skin1's from 0.138 / 0.077 / 0.060 to 0.114 / 0.049 / 0.054.

Tabulated per oblique node (:data:`AZIMUTH_MUS`), albedo (:data:`jaxsss.render.curvature_correction.CORRECTION_ALBEDO`)
and curvature node (the plane and the correction's spheres), on its chord bins; linear between them and held beyond.
Where it is used: the sums of the lights behind the object (the scene plan's ``exit azimuth`` line: the exit's
current, :mod:`jaxsss.render.exit_current`), with ``Q``: from the light's side the kernels' short exitance ahead of
the entry stands in for the exit's missing azimuth (docs/path_tracer.md, "Two errors that cancel at the terminator").
The near field (pairs within the sample spacing, :meth:`jaxsss.render.bssrdf.WhiteKernel.near_terms`) is left as it
is: a disc about the entry integrates ``cos phi`` to zero.

``python -m jaxsss.render.oblique_azimuth --regenerate`` remakes ``data/oblique_azimuth.npz``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["AZIMUTH_FLOOR", "AZIMUTH_MUS", "azimuth_factor", "azimuth_rows", "factor_harmonics", "fit_oblique_azimuth",
           "generate_oblique_azimuth", "kernel_harmonic", "load_oblique_azimuth"]

AZIMUTH_MUS = (0.5, 0.1)
"""The oblique nodes of the white-oblique kernel (:data:`jaxsss.render.bssrdf.KERNEL_MUS`)."""
AZIMUTH_FLOOR = 0.1
"""The factor ``1 + B cos phi + B_2 cos 2 phi`` is at least this at every azimuth (the first harmonic alone was held to
``|B| <= 0.9``, the same floor)."""
N_HARMONICS = 4
"""The kernel's own harmonics taken on the ring (:func:`kernel_harmonic`): the fit of ``(B, B_2)`` uses ``a_1..a_4``."""
AZIMUTH_PHOTONS = 1_000_000
AZIMUTH_MIN_COUNT = 2000
"""Photons a chord bin needs for its harmonic (a ratio of two noisy sums); beyond the last such bin ``B`` is held."""
N_PHI = 48
"""Azimuths of the ring on which the kernel's own harmonic is taken."""
AZIMUTH_TABLE = Path(__file__).resolve().parent / "data" / "oblique_azimuth.npz"


def _tally(albedo: float, mu_i: float, radius: float | None, photons: int, seed: int) -> np.ndarray:
    """``(4, D)``: the orders >= 2's light per photon by chord bin (:data:`CORRECTION_D_EDGES`), the same weighted by
    ``cos phi`` and by ``cos 2 phi`` about the entry (``phi`` from the beam's travel), and the photons per bin; in a
    sphere of ``radius`` mean free paths or (None) the half-space."""
    from jaxsss.render.curvature_correction import CORRECTION_D_EDGES
    from jaxsss.render.walk import pencil_beam_walk

    out = np.zeros((4, len(CORRECTION_D_EDGES) - 1))

    def add(first, exit_point, direction, weight):
        chord = np.linalg.norm(exit_point, axis=1)
        along = np.linalg.norm(exit_point[:, :2], axis=1)
        cos_phi = np.where(along > 0, exit_point[:, 0] / np.maximum(along, 1e-300), 0.0)
        out[0] += np.histogram(chord, CORRECTION_D_EDGES, weights=weight)[0]
        out[1] += np.histogram(chord, CORRECTION_D_EDGES, weights=weight * cos_phi)[0]
        out[2] += np.histogram(chord, CORRECTION_D_EDGES, weights=weight * (2.0 * cos_phi * cos_phi - 1.0))[0]
        out[3] += np.histogram(chord, CORRECTION_D_EDGES)[0]

    pencil_beam_walk(albedo, mu_i, photons, seed, add, radius=radius, min_order=2)
    out[:3] /= photons
    return out


def kernel_harmonic(kernel, mus: tuple, mu_i: float, radius: float | None, d) -> np.ndarray:
    """``(N_HARMONICS, D)``: the relative harmonics ``a_n = 2 <v cos n phi> / <v>`` (``n = 1..4``) of ``kernel``'s node
    ``mu_i`` (one of ``mus``) about a pencil beam's entry, at chords ``d`` on a sphere of ``radius`` (None: the plane),
    in the kernel's units (a medium with ``sigma_t' = 1`` gives transport lengths); NaN beyond the sphere's chord.
    The beam enters at the origin (normal ``+z``) travelling towards ``+x``; the ring's points carry the sphere's
    normals, so the kernel applies its curvature ratio as in a render."""
    from jaxsss.render.bssrdf import incident_flux

    phi = (np.arange(N_PHI) + 0.5) * 2.0 * np.pi / N_PHI
    sin_t = np.sqrt(1.0 - mu_i * mu_i)
    flux = incident_flux(mus, jnp.ones(1), jnp.array([[mu_i]]), jnp.ones((1, 1, 1)),
                         tangent=jnp.array([[[sin_t, 0.0, 0.0]]]))
    sources = kernel.sources(flux)
    out = np.full((N_HARMONICS, len(d)), np.nan)
    cos_n = np.cos(np.arange(1, N_HARMONICS + 1)[:, None] * phi[None, :])  # (N_HARMONICS, N_PHI)
    for i, chord in enumerate(np.asarray(d, dtype=np.float64)):
        if radius is None:
            points = np.stack([chord * np.cos(phi), chord * np.sin(phi), np.zeros(N_PHI)], axis=1)
            normals = np.tile([0.0, 0.0, 1.0], (N_PHI, 1))
        elif chord < 2.0 * radius:
            theta = 2.0 * np.arcsin(chord / (2.0 * radius))
            points = radius * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                        np.full(N_PHI, np.cos(theta) - 1.0)], axis=1)
            normals = points / radius + np.array([0.0, 0.0, 1.0])
        else:
            continue
        v = np.asarray(kernel.pair(jnp.asarray(points), jnp.broadcast_to(sources, (N_PHI,) + sources.shape[1:]),
                                   (jnp.asarray(normals), jnp.tile(jnp.array([0.0, 0.0, 1.0]), (N_PHI, 1)))))
        v = v[:, mus.index(mu_i), 0]
        out[:, i] = 2.0 * np.mean(v * cos_n, axis=1) / np.mean(v)
    return out


def factor_harmonics(a, h) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(B, B_2, G)`` of the factor ``G (1 + B cos phi + B_2 cos 2 phi)`` (module docstring) that gives a kernel with
    relative harmonics ``a`` ``(4, ...)`` the walk's ``h`` ``(2, ...)`` and keeps its mean; scaled down where the factor
    would fall under :data:`AZIMUTH_FLOOR`. NaN where ``a`` or ``h`` is."""
    a1, a2, a3, a4 = a
    h1, h2 = h
    # The product's first two harmonics, linear in (B, B_2): [[m11, m12], [m21, m22]] (B, B_2) = (r1, r2).
    m11, m12, r1 = 1.0 + a2 / 2.0 - h1 * a1 / 2.0, (a1 + a3) / 2.0 - h1 * a2 / 2.0, h1 - a1
    m21, m22, r2 = (a1 + a3) / 2.0 - h2 * a1 / 2.0, 1.0 + a4 / 2.0 - h2 * a2 / 2.0, h2 - a2
    det = m11 * m22 - m12 * m21
    b1, b2 = (r1 * m22 - r2 * m12) / det, (m11 * r2 - m21 * r1) / det
    # The lowest of b1 c + b2 (2 c^2 - 1) over c = cos phi in [-1, 1]: at c = +-1, or where its derivative vanishes.
    c_star = np.clip(-b1 / np.where(b2 != 0.0, 4.0 * b2, np.inf), -1.0, 1.0)
    low = np.minimum(np.minimum(-b1 + b2, b1 + b2), b1 * c_star + b2 * (2.0 * c_star * c_star - 1.0))
    scale = np.where(low < AZIMUTH_FLOOR - 1.0, (1.0 - AZIMUTH_FLOOR) / np.where(low < 0.0, -low, 1.0), 1.0)
    b1, b2 = b1 * scale, b2 * scale
    return b1, b2, 1.0 / (1.0 + (a1 * b1 + a2 * b2) / 2.0)


def fit_oblique_azimuth(sphere: np.ndarray, plane: np.ndarray) -> dict:
    """``B``, ``B2`` and ``G`` ``(U, A, len(CORRECTION_KAPPA), D)`` from the walks' tallies (``sphere`` ``(U, A, R, 4,
    D)`` over :data:`jaxsss.render.curvature_correction.CORRECTION_RADII`, ``plane`` ``(U, A, 4, D)``) and the kernel's
    own harmonics (:func:`kernel_harmonic`, the white-oblique kernel with the curvature ratio and ``Q``) on the same
    spheres (:func:`factor_harmonics`); with the walk's two harmonics ``H_walk`` ``(..., 2, D)`` and the kernel's
    ``H_kernel`` ``(..., N_HARMONICS, D)`` (NaN where a bin has too few photons)."""
    import jaxsss
    from jaxsss.render.bssrdf import white_kernel, white_tables
    from jaxsss.render.curvature_correction import CORRECTION_ALBEDO, CORRECTION_D, CORRECTION_D_EDGES, CORRECTION_RADII

    d = np.asarray(CORRECTION_D)
    mus, sources = white_tables(0.0, 1.0, True)
    shape = (len(AZIMUTH_MUS), len(CORRECTION_ALBEDO), len(CORRECTION_RADII) + 1)
    b_all, b2_all, g_all = np.zeros(shape + (len(d),)), np.zeros(shape + (len(d),)), np.ones(shape + (len(d),))
    h_walk, h_kernel = np.full(shape + (2, len(d)), np.nan), np.full(shape + (N_HARMONICS, len(d)), np.nan)
    index = np.arange(len(d))
    for j, albedo in enumerate(CORRECTION_ALBEDO):
        medium = jaxsss.Medium(jnp.array([1.0 - albedo]), jnp.array([albedo]), 1.0)
        kernel = white_kernel(medium, sources, mus, shift=True, curvature=True, first_order=True,
                              curvature_transport=True)
        for u, mu in enumerate(AZIMUTH_MUS):
            for r in range(len(CORRECTION_RADII) + 1):
                radius = None if r == 0 else CORRECTION_RADII[r - 1]
                tally = plane[u, j] if r == 0 else sphere[u, j, r - 1]
                ok = tally[3] >= AZIMUTH_MIN_COUNT
                if radius is not None:
                    ok &= CORRECTION_D_EDGES[1:] <= 2.0 * radius
                hw = np.where(ok, 2.0 * tally[1:3] / np.where(tally[0] > 0, tally[0], 1.0), np.nan)  # (2, D)
                hk = kernel_harmonic(kernel, mus, mu, radius, d)  # (N_HARMONICS, D)
                b1, b2, _ = factor_harmonics(hk, hw)
                good = np.flatnonzero(np.isfinite(b1) & np.isfinite(b2))
                known = np.flatnonzero(np.all(np.isfinite(hk), axis=0))
                if len(good) == 0 or len(known) == 0:
                    continue
                # Held beyond the last bin with light; G from the kernel's harmonics there.
                b1, b2 = np.interp(index, good, b1[good]), np.interp(index, good, b2[good])
                hk_all = np.stack([np.interp(index, known, row[known]) for row in hk])
                b_all[u, j, r], b2_all[u, j, r] = b1, b2
                g_all[u, j, r] = 1.0 / (1.0 + (hk_all[0] * b1 + hk_all[1] * b2) / 2.0)
                h_walk[u, j, r], h_kernel[u, j, r] = hw, hk
    return {"B": b_all, "B2": b2_all, "G": g_all, "H_walk": h_walk, "H_kernel": h_kernel}


def generate_oblique_azimuth(photons: int = AZIMUTH_PHOTONS, seed: int = 71, progress: bool = True) -> dict:
    """Run the walks (:data:`AZIMUTH_MUS` x the correction's albedos, each on a half-space and the correction's
    spheres) and return the table: ``B``, ``G``, the harmonics, the tallies and metadata."""
    from jaxsss.render.curvature_correction import CORRECTION_ALBEDO, CORRECTION_RADII
    from jaxsss.render.walk import sphere_and_plane_tallies

    t0 = time.perf_counter()
    sphere, plane = sphere_and_plane_tallies(_tally, AZIMUTH_MUS, CORRECTION_ALBEDO, CORRECTION_RADII, photons, seed,
                                             "oblique azimuth", progress)
    return {**fit_oblique_azimuth(sphere, plane), "sphere": sphere, "plane": plane, "mus": np.asarray(AZIMUTH_MUS),
            "albedo": np.asarray(CORRECTION_ALBEDO), "radii": np.asarray(CORRECTION_RADII), "photons": photons,
            "seed": seed, "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk: index-matched isotropic sphere and half-space, orders "
                      ">= 2, the first two azimuthal harmonics about the entry"}


def load_oblique_azimuth() -> dict:
    """The shipped table (:data:`AZIMUTH_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(AZIMUTH_TABLE)


def azimuth_rows(mus: tuple, albedo):
    """``(K, C, len(CORRECTION_KAPPA), D, 3)``: the factor's ``(G, B, B_2)`` for the kernel's nodes ``mus`` and albedos
    ``(C,)``, linear in the albedo between the table's; the normal node (1) has ``G = 1`` and ``B = B_2 = 0``."""
    from jaxsss.render.curvature_correction import CORRECTION_ALBEDO
    from jaxsss.render.exit_distance import node_rows

    table = load_oblique_azimuth()
    oblique = tuple(m for m in mus if m != 1.0)
    rows = [node_rows(table[name], AZIMUTH_MUS, CORRECTION_ALBEDO, oblique, albedo,
                      "oblique_azimuth (an oblique beam's light ahead of its entry)") for name in ("G", "B", "B2")]
    out = []
    for value, row in zip((1.0, 0.0, 0.0), rows):
        full = [jnp.full(row.shape[1:], value, row.dtype) if m == 1.0 else row[oblique.index(m)] for m in mus]
        out.append(jnp.stack(full))
    return jnp.stack(out, axis=-1)


def azimuth_factor(rows, kappa_lu, d_lu, cos_phi):
    """``(P, K, C)``: ``G (1 + B cos phi + B_2 cos 2 phi)`` at the pairs' curvature ``kappa_lu`` and chord ``d_lu``
    (``(P, 1, 1)`` or ``(P, 1, C)``, in transport lengths) and azimuth ``cos_phi`` ``(P, K, C)`` from each node's
    travel; ``rows`` ``(K, C, Nk, D, 3)`` from :func:`azimuth_rows`. Bilinear in (``kappa l_u``, ``d / l_u``) on the
    table's nodes, held beyond them (one gather of the cell's corners per pair: interpolating every curvature node
    along the chord first took as long as the rest of the pair); differentiable in every argument."""
    from jaxsss.render.curvature_correction import CORRECTION_D, CORRECTION_KAPPA
    from jaxsss.render.passage import node_interval

    n_k, n_c, n_kappa, n_d, n_f = rows.shape
    shape = cos_phi.shape
    i, t = node_interval(jnp.broadcast_to(d_lu, shape), CORRECTION_D)
    j, w = node_interval(jnp.broadcast_to(kappa_lu, shape), CORRECTION_KAPPA)
    k = jnp.arange(n_k, dtype=jnp.int32)[None, :, None]
    c = jnp.arange(n_c, dtype=jnp.int32)[None, None, :]
    # (G, B, B_2) at the cell's four corners, from the flattened (K, C, Nk, D, 3) table.
    table = rows.reshape(-1, n_f)
    base = ((k * n_c + c) * n_kappa + j) * n_d + i
    f00, f01 = table[base], table[base + 1]
    f10, f11 = table[base + n_d], table[base + n_d + 1]
    t, w = t[..., None], w[..., None]
    gb = (1.0 - w) * ((1.0 - t) * f00 + t * f01) + w * ((1.0 - t) * f10 + t * f11)
    return gb[..., 0] * (1.0 + gb[..., 1] * cos_phi + gb[..., 2] * (2.0 * cos_phi * cos_phi - 1.0))


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.oblique_azimuth", path=AZIMUTH_TABLE, photons=AZIMUTH_PHOTONS,
        description="The first two azimuthal harmonics of an oblique beam's orders >= 2 about its entry, walk over the "
                    "white-oblique kernel (jaxsss.render.oblique_azimuth).",
        photons_help="photons per walk (the correction's spheres and a half-space per node)", load=load_oblique_azimuth,
        refit=lambda tab: fit_oblique_azimuth(tab["sphere"], tab["plane"]),
        generate=generate_oblique_azimuth,
        describe=lambda tab: (f"B {tab['B'].shape} (mu_i, albedo, kappa l_u, d / l_u); "
                              f"{int(tab['photons'])} photons per walk, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
