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

The kernel as rendered. A render's light column on a curved object ends where its refracted ray leaves it, after
the chord ``t = 2 a mu_i`` on a sphere; the kernel then shortens the profile's shift to the travel that chord allows
and, where the cut beam matters (:mod:`jaxsss.render.passage`), takes the light lost at ``d / t`` chords from the
entry, more of it ahead of the entry than behind. The walk's harmonics hold that loss already, so the kernel's own
``a_n`` are taken with the beam as a render has it (:func:`kernel_harmonic`, chord and cut included). Until 2026-12-01
they were taken without the chord: the factor put back only the light the uncut kernel lacked ahead, and the render
then cut it again. At ``mu_i = 0.1`` on a sphere of 11.1 transport lengths (albedo 0.67) the rendered kernel's ``h_1``
at 2.5-5 transport lengths was 0.20 / 0.04 / -0.12 against the walk's 0.98 / 0.90 / 0.77 (1.00 / 0.90 / 0.78 now), and
the back-lit chicken1 sphere was 0.156 / 0.184 / 0.217 per pixel against Mitsuba (0.150 / 0.122 / 0.171 now).

The kernel's mean. ``G`` keeps the rendered kernel's azimuthal mean, which ``Q`` was meant to make the walk's. It does
not quite: ``Q`` is fitted with the cut's azimuthal mean about an unshifted entry and only its far part (``Q > 1``) is
used, and against the walk's mean by chord bin (``M`` in the table, :func:`kernel_ring_mean`) the rendered oblique
nodes are 10-25% too bright at 0.5-2 transport lengths (``mu_i = 0.5``) and 10-60% at 0.5-7 (``mu_i = 0.1``, most on
small spheres at low albedo). Taking ``G`` to the walk's mean (``M`` times it) was measured and not kept: it darkened
the back-lit images that other parts of the model leave short (the hat mix between incidence nodes on a sphere,
docs/path_tracer.md), chicken1 0.150 / 0.122 / 0.171 -> 0.149 / 0.142 / 0.188 and four held-out spheres likewise, and
helped only the red terminator bands (ketchup lit from the side and behind 0.142 -> 0.077).

Tabulated per oblique node (:data:`AZIMUTH_MUS`), albedo (:data:`jaxsss.render.curvature_correction.CORRECTION_ALBEDO`;
linear in ``sqrt(1 - albedo)`` between, as ``Q``) and curvature node (the plane and the correction's spheres), on its
chord bins; linear between them and held beyond.
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
           "generate_oblique_azimuth", "kernel_harmonic", "kernel_ring_mean", "load_oblique_azimuth"]

AZIMUTH_MUS = (0.75, 0.5, 0.1)
"""The oblique nodes of the white-oblique kernel (:data:`jaxsss.render.bssrdf.KERNEL_MUS`) and 0.75, the lights-behind
kernel's (:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`)."""
AZIMUTH_FLOOR = 0.1
"""The factor ``1 + B cos phi + B_2 cos 2 phi`` is at least this at every azimuth (the first harmonic alone was held to
``|B| <= 0.9``, the same floor)."""
N_HARMONICS = 4
"""The kernel's own harmonics taken on the ring (:func:`kernel_harmonic`): the fit of ``(B, B_2)`` uses ``a_1..a_4``."""
AZIMUTH_PHOTONS = 1_000_000
AZIMUTH_MIN_COUNT = 2000
"""Photons a chord bin needs for its harmonic (a ratio of two noisy sums); beyond the last such bin ``B`` is held."""
MEAN_FROM = 0.5
"""Transport lengths from the entry from which the table's ``M`` (the walk's mean over the kernel's) is taken, held
nearer: within half a transport length the shifted profile's peak sits off the entry (the far kernel's ring there is
0.35-0.9 of the walk's), and the near field (a disc of ``rho_0``, :meth:`jaxsss.render.bssrdf.WhiteKernel.near_terms`)
holds such pairs."""
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


def _beam_sources(kernel, mus: tuple, mu_i: float, radius: float | None):
    """``kernel.sources`` of a unit pencil beam at incidence cosine ``mu_i`` (one of ``mus``) entering at the origin
    (normal ``+z``) towards ``+x``, as a render's light column: on a sphere of ``radius`` its refracted ray runs along
    the chord ``t = 2 radius mu_i`` (index-matched), so its forward shift is the travel that chord allows
    (:func:`jaxsss.render.passage.truncated_travel`) and, when the kernel carries the cut beam (``kernel.passage``),
    the flux carries the chord's rows (:meth:`jaxsss.render.renderer.Prepared.sample_flux`)."""
    from jaxsss.render.bssrdf import incident_flux
    from jaxsss.render.passage import truncated_travel

    sin_t = np.sqrt(1.0 - mu_i * mu_i)
    args = (mus, jnp.ones(1), jnp.array([[mu_i]]))
    chord = np.inf if radius is None else 2.0 * radius * mu_i
    travel = truncated_travel(jnp.array([[chord]]), jnp.ones(1))  # (1, 1, 1)
    flux = incident_flux(*args, jnp.ones((1, 1, 1)), tangent=jnp.array([[[sin_t, 0.0, 0.0]]]), tangent_weight=travel)
    if kernel.passage is not None:
        # The flux of a column with a finite chord and times that chord (none on the plane).
        rows = [incident_flux(*args, jnp.full((1, 1, 1), chord**p if np.isfinite(chord) else 0.0)) for p in (0, 1)]
        flux = jnp.concatenate([flux] + [row[:, None] for row in rows], axis=1)
    return kernel.sources(flux)


def _rings(kernel, mus: tuple, mu_i: float, radius: float | None, chords) -> np.ndarray:
    """``(len(chords), N_PHI)``: ``kernel``'s node ``mu_i`` on rings at ``chords`` from the beam's entry
    (:func:`_beam_sources`) on the plane or a sphere of ``radius`` (each chord below ``2 radius``); the points carry
    the sphere's normals, so the kernel applies its curvature ratio as in a render."""
    chords = np.asarray(chords, dtype=np.float64)
    phi = (np.arange(N_PHI) + 0.5) * 2.0 * np.pi / N_PHI
    c, p = np.repeat(chords, N_PHI), np.tile(phi, len(chords))
    if radius is None:
        points = np.stack([c * np.cos(p), c * np.sin(p), np.zeros_like(c)], axis=1)
        normals = np.tile([0.0, 0.0, 1.0], (len(c), 1))
    else:
        theta = 2.0 * np.arcsin(c / (2.0 * radius))
        points = radius * np.stack([np.sin(theta) * np.cos(p), np.sin(theta) * np.sin(p), np.cos(theta) - 1.0], axis=1)
        normals = points / radius + np.array([0.0, 0.0, 1.0])
    sources = _beam_sources(kernel, mus, mu_i, radius)
    v = kernel.pair(jnp.asarray(points), jnp.broadcast_to(sources, (len(c),) + sources.shape[1:]),
                    (jnp.asarray(normals), jnp.tile(jnp.array([0.0, 0.0, 1.0]), (len(c), 1))))
    return np.asarray(v)[:, mus.index(mu_i), 0].reshape(len(chords), N_PHI)


def kernel_harmonic(kernel, mus: tuple, mu_i: float, radius: float | None, d) -> np.ndarray:
    """``(N_HARMONICS, D)``: the relative harmonics ``a_n = 2 <v cos n phi> / <v>`` (``n = 1..4``) of ``kernel``'s node
    ``mu_i`` (one of ``mus``) about a pencil beam's entry, at chords ``d`` on a sphere of ``radius`` (None: the plane),
    in the kernel's units (a medium with ``sigma_t' = 1`` gives transport lengths); NaN beyond the sphere's chord.
    The beam is a render's light column (:func:`_beam_sources`: its chord's shortened shift and, with the cut beam,
    the cut's loss ahead of the entry are in ``a_n``)."""
    d = np.asarray(d, dtype=np.float64)
    out = np.full((N_HARMONICS, len(d)), np.nan)
    inside = np.ones(len(d), bool) if radius is None else d < 2.0 * radius
    if inside.any():
        phi = (np.arange(N_PHI) + 0.5) * 2.0 * np.pi / N_PHI
        v = _rings(kernel, mus, mu_i, radius, d[inside])  # (D', N_PHI)
        cos_n = np.cos(np.arange(1, N_HARMONICS + 1)[:, None] * phi[None, :])  # (N_HARMONICS, N_PHI)
        out[:, inside] = 2.0 * (v @ cos_n.T).T / N_PHI / v.mean(axis=1)
    return out


def kernel_ring_mean(kernel, mus: tuple, mu_i: float, radius: float | None, edges=None, n_sub: int = 4) -> np.ndarray:
    """``(D,)``: the azimuthal mean of ``kernel``'s node ``mu_i`` (per unit incident flux, 1/area in the kernel's
    units) averaged over each chord bin of ``edges`` (default :data:`CORRECTION_D_EDGES`) by area: ``n_sub`` rings
    evenly spaced in ``d^2`` (on a sphere the area within chord ``d`` is ``pi d^2``, as on the plane); NaN for bins
    that reach past a sphere's antipode. The walk's counterpart is its light per photon in the bin over ``pi (d_1^2 -
    d_0^2)``."""
    from jaxsss.render.curvature_correction import CORRECTION_D_EDGES

    edges = np.asarray(CORRECTION_D_EDGES if edges is None else edges, dtype=np.float64)
    e0, e1 = edges[:-1], edges[1:]
    out = np.full(len(e0), np.nan)
    inside = np.ones(len(e0), bool) if radius is None else e1 <= 2.0 * radius
    if inside.any():
        q = (np.arange(n_sub) + 0.5) / n_sub
        chords = np.sqrt(e0[inside, None] ** 2 + q[None, :] * (e1[inside, None] ** 2 - e0[inside, None] ** 2))
        v = _rings(kernel, mus, mu_i, radius, chords.ravel())  # (D' n_sub, N_PHI)
        out[inside] = v.reshape(-1, n_sub * N_PHI).mean(axis=1)
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


def fit_oblique_azimuth(sphere: np.ndarray, plane: np.ndarray, mus=AZIMUTH_MUS, albedos=None) -> dict:
    """``B``, ``B2`` and ``G`` ``(U, A, len(CORRECTION_KAPPA), D)`` at the albedos ``albedos`` (default
    :data:`jaxsss.render.curvature_correction.CORRECTION_ALBEDO`) from the walks' tallies (``sphere`` ``(U, A, R, 4,
    D)`` over :data:`jaxsss.render.curvature_correction.CORRECTION_RADII`, ``plane`` ``(U, A, 4, D)``) and the kernel's
    own harmonics (:func:`kernel_harmonic`: the white-oblique kernel with the curvature ratio, ``Q`` and the cut beam,
    the beam a render's light column) on the same spheres (:func:`factor_harmonics`); with the walk's two harmonics
    ``H_walk`` ``(..., 2, D)`` and the kernel's ``H_kernel`` ``(..., N_HARMONICS, D)`` (NaN where a bin has too few
    photons), and ``M``, the walk's azimuthal mean over the kernel's (:func:`kernel_ring_mean`; held within
    :data:`MEAN_FROM` and beyond the last bin with light). ``M`` is a record, not used: ``G`` keeps the kernel's own
    mean (module docstring, "The kernel's mean")."""
    import jaxsss
    from jaxsss.render.bssrdf import white_kernel, white_tables
    from jaxsss.render.curvature_correction import CORRECTION_ALBEDO, CORRECTION_D, CORRECTION_D_EDGES, CORRECTION_RADII

    albedos = tuple(float(a) for a in (CORRECTION_ALBEDO if albedos is None else albedos))
    d = np.asarray(CORRECTION_D)
    area = np.pi * (CORRECTION_D_EDGES[1:] ** 2 - CORRECTION_D_EDGES[:-1] ** 2)
    oblique = tuple(float(m) for m in mus)
    mus, sources = white_tables(0.0, 1.0, True, mus=oblique)
    shape = (len(oblique), len(albedos), len(CORRECTION_RADII) + 1)
    b_all, b2_all, g_all = np.zeros(shape + (len(d),)), np.zeros(shape + (len(d),)), np.ones(shape + (len(d),))
    m_all = np.ones(shape + (len(d),))
    h_walk, h_kernel = np.full(shape + (2, len(d)), np.nan), np.full(shape + (N_HARMONICS, len(d)), np.nan)
    index = np.arange(len(d))
    for j, albedo in enumerate(albedos):
        medium = jaxsss.Medium(jnp.array([1.0 - albedo]), jnp.array([albedo]), 1.0)
        # The back-lit render's kernel: the cut beam on (a render cuts the light columns that end in the object).
        kernel = white_kernel(medium, sources, mus, shift=True, curvature=True, first_order=True,
                              curvature_transport=True, passage=0.0)
        for u, mu in enumerate(oblique):
            for r in range(len(CORRECTION_RADII) + 1):
                radius = None if r == 0 else CORRECTION_RADII[r - 1]
                tally = plane[u, j] if r == 0 else sphere[u, j, r - 1]
                ok = tally[3] >= AZIMUTH_MIN_COUNT
                if radius is not None:
                    ok &= CORRECTION_D_EDGES[1:] <= 2.0 * radius
                hw = np.where(ok, 2.0 * tally[1:3] / np.where(tally[0] > 0, tally[0], 1.0), np.nan)  # (2, D)
                hk = kernel_harmonic(kernel, mus, mu, radius, d)  # (N_HARMONICS, D)
                # The walk's mean over the kernel's, bin by bin.
                mean = np.where(ok, tally[0] / area, np.nan) / kernel_ring_mean(kernel, mus, mu, radius)
                b1, b2, _ = factor_harmonics(hk, hw)
                good = np.flatnonzero(np.isfinite(b1) & np.isfinite(b2))
                known = np.flatnonzero(np.all(np.isfinite(hk), axis=0))
                fine = np.flatnonzero(np.isfinite(mean) & (mean > 0) & (CORRECTION_D_EDGES[:-1] >= MEAN_FROM))
                if len(fine):
                    m_all[u, j, r] = np.exp(np.interp(index, fine, np.log(mean[fine])))
                if len(good) == 0 or len(known) == 0:
                    continue
                # Held beyond the last bin with light; G from the kernel's harmonics there.
                b1, b2 = np.interp(index, good, b1[good]), np.interp(index, good, b2[good])
                hk_all = np.stack([np.interp(index, known, row[known]) for row in hk])
                b_all[u, j, r], b2_all[u, j, r] = b1, b2
                g_all[u, j, r] = 1.0 / (1.0 + (hk_all[0] * b1 + hk_all[1] * b2) / 2.0)
                h_walk[u, j, r], h_kernel[u, j, r] = hw, hk
    return {"B": b_all, "B2": b2_all, "G": g_all, "M": m_all, "H_walk": h_walk, "H_kernel": h_kernel}


def generate_oblique_azimuth(photons: int = AZIMUTH_PHOTONS, seed: int = 71, progress: bool = True,
                             mus=AZIMUTH_MUS, albedos=None) -> dict:
    """Run the walks (``mus``, default :data:`AZIMUTH_MUS`, x ``albedos``, default the correction's, each on a
    half-space and the correction's spheres; seeds by each node's slot among :data:`AZIMUTH_MUS` and each albedo's
    among the correction's) and return the table: ``B``, ``G``, the harmonics, the tallies and metadata. A node's fit
    needs the correction's and the cut beam's tables at that node (and the correction's at that albedo)."""
    from jaxsss.render.curvature_correction import CORRECTION_ALBEDO, CORRECTION_RADII
    from jaxsss.render.walk import sphere_and_plane_tallies

    t0 = time.perf_counter()
    mus = tuple(float(m) for m in mus)
    albedos = tuple(float(a) for a in (CORRECTION_ALBEDO if albedos is None else albedos))
    sphere, plane = sphere_and_plane_tallies(_tally, mus, albedos, CORRECTION_RADII, photons, seed,
                                             "oblique azimuth", progress, table_mus=AZIMUTH_MUS,
                                             table_albedo=CORRECTION_ALBEDO)
    return {**fit_oblique_azimuth(sphere, plane, mus, albedos), "sphere": sphere, "plane": plane,
            "mus": np.asarray(mus), "albedo": np.asarray(albedos), "radii": np.asarray(CORRECTION_RADII),
            "photons": photons, "seed": seed, "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk: index-matched isotropic sphere and half-space, orders "
                      ">= 2, the first two azimuthal harmonics about the entry"}


def load_oblique_azimuth() -> dict:
    """The shipped table (:data:`AZIMUTH_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(AZIMUTH_TABLE)


def azimuth_rows(mus: tuple, albedo):
    """``(K, C, len(CORRECTION_KAPPA), D, 3)``: the factor's ``(G, B, B_2)`` for the kernel's nodes ``mus`` and albedos
    ``(C,)``, linear in ``sqrt(1 - albedo)`` between the table's (as ``Q``'s,
    :func:`jaxsss.render.curvature_correction.log_correction_table`); the normal node (1) has ``G = 1`` and ``B = B_2 =
    0``."""
    from jaxsss.render.exit_distance import node_rows

    table = load_oblique_azimuth()
    oblique = tuple(m for m in mus if m != 1.0)
    rows = [node_rows(table[name], tuple(table["mus"]), tuple(table["albedo"]), oblique, albedo,
                      "oblique_azimuth (an oblique beam's light ahead of its entry)", coordinate="diffusion")
            for name in ("G", "B", "B2")]
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
        refit=lambda tab: fit_oblique_azimuth(tab["sphere"], tab["plane"], tuple(tab["mus"]), tuple(tab["albedo"])),
        generate=generate_oblique_azimuth, node_keys=("B", "B2", "G", "M", "H_walk", "H_kernel", "sphere", "plane"),
        albedo_keys=("B", "B2", "G", "M", "H_walk", "H_kernel", "sphere", "plane"),
        describe=lambda tab: (f"B {tab['B'].shape} (mu_i, albedo, kappa l_u, d / l_u); "
                              f"{int(tab['photons'])} photons per walk, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
