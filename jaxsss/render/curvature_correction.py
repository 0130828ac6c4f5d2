"""The curvature ratio, corrected by transport: a pencil beam's gain on a sphere over the half-space, orders >= 2.

The curvature ratio (:mod:`jaxsss.render.curvature`) is diffusion's: the dipole's exitance on a sphere with Kelvin's
image over the plane's. Measured against a walk (:func:`jaxsss.render.walk.pencil_beam_walk` in spheres and the
half-space, isotropic, index-matched, the orders >= 2 that the white kernels hold when the first order is marched,
:mod:`jaxsss.render.first_order`), it has the right size at normal incidence on spheres of 15 transport lengths and
more, and the wrong one on smaller spheres and at grazing incidence: on skin1's red (albedo 0.96) the whole beam's
gain on a sphere of 15 ``l_u`` is 1.119 in transport against the renderer's 1.103 at normal incidence, and 0.930
against 1.013 at ``mu_i = 0.1`` (``benchmarks/curvature_transport.py``); on spheres of 6-12 ``l_u`` the images were
4-6% too bright in red (docs/path_tracer.md, "Small spheres"). Diffusion's ratio was also capped at a radius of
``6.7 l_u`` (:data:`jaxsss.render.curvature.KAPPA_MAX_ZR`), a knob chosen on images.

The transport correction is

    Q(kappa l_u, d / l_u | mu_i, albedo) = C_MC(d) / (C_Kelvin(d, kappa; depth mu_i) K(d)),

``C_MC`` the walk's exitance at chord ``d`` from the entry on a sphere of radius ``1 / kappa`` over the half-space's
(orders >= 2, by chord bin), ``C_Kelvin`` the diffusion ratio at the bin's centre with the source at the node's depth
and no cap but the chord's (``kappa <= 2 / d``), and ``K`` the share of the light that the renderer's cut beam keeps
(:func:`jaxsss.render.passage.passage_loss`, the chord ``2 a mu_i`` of the refracted ray, azimuthal mean): ``Q`` is
what the renderer's own model of the pencil beam misses. It is 1 on the plane and tabulated on
:data:`CORRECTION_RADII` (3.3-25 ``l_u``), linear in the curvature between them and to the plane, per incidence node
and albedo. Near the entry it is 0.7-1 (least at grazing incidence on small spheres), far from it 1.5-9, and up to
18 at the antipode: light runs round a sphere of a few transport lengths and converges on the far side, which Kelvin's
image, shrinking with the chord, does not carry.

Where it is used: with every light behind the object (the scene plan's ``exit azimuth`` line, with the exit's current of
:mod:`jaxsss.render.exit_current`), the marched kernels multiply the ratio by ``max(Q, 1)``, the far part, and the cap
moves to the table's smallest sphere (:data:`KAPPA_MAX_MARCHED`). Its near part (``Q < 1``) is left out: without an
azimuth about the entry (the shifted profile has too little light ahead of it) it takes light from the terminator,
which is already short; with it the back-lit skin1 sphere was 0.227 / 0.239 / 0.219 per pixel against 0.211 / 0.214 /
0.208 (docs/path_tracer.md). From the light's side the near part is used (:func:`jaxsss.render.bssrdf.white_kernel`
with ``first_order`` and not ``curvature_transport``), with the cap at 5 ``l_u`` (:data:`KAPPA_MAX_NEAR`): on a small
sphere transport carries light from the lit side round to the far one, which the diffusion ratio keeps near the entry
(the 8 mm skin1 sphere, 6.2 / 8.4 / 11.9 ``l_u`` in radius, was 6.2 / 4.7 / 2.3% too bright in sum against Mitsuba
without it, 4.1 / 3.0 / 1.5% with it; docs/path_tracer.md, "Transport's near part from the light's side"). The far part
is left out there: the terminator's short exitance stands in for the exit's missing azimuth, and ``Q`` would undo it
(chicken1 0.034 -> 0.090 in red). The other kernels at
``eta = 1`` (``g > 0``, skies) keep the capped diffusion ratio; behind a dielectric boundary the near part of Fresnel
walks' ``Q`` is used (:mod:`jaxsss.render.dielectric_correction`).

``python -m jaxsss.render.curvature_correction --regenerate`` remakes ``data/curvature_correction.npz``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["CORRECTION_ALBEDO", "CORRECTION_D", "CORRECTION_D_EDGES", "CORRECTION_KAPPA", "CORRECTION_MUS",
           "CORRECTION_RADII", "KAPPA_MAX_MARCHED", "KAPPA_MAX_NEAR", "fit_curvature_correction",
           "generate_curvature_correction", "load_curvature_correction", "log_correction_table"]

CORRECTION_MUS = (1.0, 0.75, 0.5, 0.1)
"""Incidence cosines of the table: the white-oblique kernel's nodes (1 and :data:`jaxsss.render.bssrdf.KERNEL_MUS`)
and 0.75, the lights-behind kernel's (:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`); descending (the lookups take
the shipped table's own ``mus``)."""
CORRECTION_ALBEDO = (0.3, 0.6, 0.8, 0.9, 0.97, 0.995, 0.999)
"""Single-scattering albedos of the table, ascending (linear in ``sqrt(1 - albedo)`` between, held beyond the ends:
:func:`jaxsss.render.exit_distance.node_rows`; the lookups take the shipped table's own ``albedo``). 0.999 joined on
2026-12-02 (``--add-albedo``): the potato's red (0.9965) and apple's (0.9987), held at 0.995, took the far side of a
20 mm sphere lit from behind 23% bright against Mitsuba (``Q`` at 0.995 is 14% over a walk's at 0.9965 near the
antipode of a 7 ``l_u`` sphere)."""
CORRECTION_RADII = tuple(round(3.3 * 1.224**k, 2) for k in range(10, -1, -1))
"""Sphere radii of the walks, transport lengths (``g = 0``: mean free paths): 24.91 down to 3.3, a ratio of 1.224
between neighbours. ``Q`` is linear in the curvature between them at a fixed chord, and near a sphere's antipode it
changes several-fold within a transport length, where a neighbour's chord is still far from its own antipode: on six
radii (25, 16, 11, 7.5, 5, 3.3, until 2026-11-29) the 8 mm skin1 sphere's red (6.2 ``l_u``) was 35% short of a pencil
beam's walk at 11 ``l_u``, and 28% short of Mitsuba on its far dark side lit from behind (10% on these eleven)."""
CORRECTION_KAPPA = (0.0,) + tuple(1.0 / a for a in CORRECTION_RADII)
"""Curvature nodes ``kappa l_u`` (0: the plane, where ``Q = 1``; linear between, held beyond ``1 / 3.3``)."""
KAPPA_MAX_MARCHED = CORRECTION_KAPPA[-1]
"""The marched kernels' cap on the curvature lit from behind, in units of ``sigma_t'``: the table's smallest sphere."""
KAPPA_MAX_NEAR = 0.2
"""The marched kernels' cap on the curvature from the light's side, with ``Q``'s near part (units of ``sigma_t'``: a
sphere of 5 ``l_u``). A smaller sphere's pairs take the ratio and ``Q`` of one of 5 ``l_u``; its light runs round to
the far side, which the kernel without ``Q``'s far part does not carry, and holding the near part there keeps the lit
side's light. Chosen on the committed references' sums (red, the channel past it): chicken1 (3.3 ``l_u``) and ketchup
(4.9 ``l_u``) on the 20 mm sphere were 0.967 and 0.976 at the ratio's cap (6.7 ``l_u``,
:data:`jaxsss.render.curvature.KAPPA_MAX_ZR`), 1.026 and 1.001 at the table's smallest sphere (3.3 ``l_u``), and
0.987 and 0.998 here. Below the table's range the model has no transport in it: on held-out 8 and 12 mm spheres
chicken1's red (2 ``l_u``) was 5.6% short in sum, chicken2's green (2.7 ``l_u``) 1.4% bright (docs/path_tracer.md)."""
CORRECTION_D_EDGES = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0,
                               14.0, 17.0, 20.0, 24.0, 28.0, 33.0, 40.0, 50.0])
"""Chord bins of the walks' tallies, transport lengths (a sphere's chords end at ``2 a``)."""
CORRECTION_D = tuple(float(x) for x in 0.5 * (CORRECTION_D_EDGES[1:] + CORRECTION_D_EDGES[:-1]))
"""Distance nodes ``d / l_u`` of ``Q``: the bins' centres (linear between, held beyond)."""
CORRECTION_PHOTONS = 1_000_000
CORRECTION_MIN_COUNT = 400
"""Photons a sphere's chord bin needs for its ``Q``; beyond the last such bin ``Q`` is held."""
CORRECTION_TABLE = Path(__file__).resolve().parent / "data" / "curvature_correction.npz"


def _tally(albedo: float, mu_i: float, radius: float | None, photons: int, seed: int, eta: float = 1.0,
           min_order: int = 2) -> np.ndarray:
    """``(2, D)``: the light per photon of the orders ``>= min_order`` by chord from the entry
    (:data:`CORRECTION_D_EDGES`, mean free paths), and the photons in each bin, in a sphere of ``radius`` or (None) the
    half-space, behind a boundary of relative index ``eta`` (1: index-matched)."""
    from jaxsss.render.walk import pencil_beam_walk

    out = np.zeros((2, len(CORRECTION_D_EDGES) - 1))

    def add(first, exit_point, direction, weight):
        chord = np.linalg.norm(exit_point, axis=1)
        out[0] += np.histogram(chord, CORRECTION_D_EDGES, weights=weight)[0]
        out[1] += np.histogram(chord, CORRECTION_D_EDGES)[0]

    pencil_beam_walk(albedo, mu_i, photons, seed, add, radius=radius, min_order=min_order, eta=eta)
    out[0] /= photons
    return out


def renderer_model(mu_i: float, albedo: float, radius: float, d=None, eta: float = 1.0) -> np.ndarray:
    """``(D,)``: the renderer's model of the pencil beam's gain at the chords ``d`` (transport lengths; default the
    nodes :data:`CORRECTION_D`) on a sphere of ``radius`` transport lengths: the diffusion ratio (source at the
    refracted depth of ``mu_i``, the boundary's ``A`` at ``eta``, the chord's cap only) times the share the cut beam
    keeps (the refracted chord ``2 radius mu_t``, azimuthal mean; ``sigma_t' = 1``)."""
    from jaxsss.fresnel import A_coefficient, snell_cosine
    from jaxsss.render.curvature import curvature_ratio
    from jaxsss.render.passage import passage_cells, passage_loss, passage_loss_table

    d = np.asarray(CORRECTION_D if d is None else d, dtype=np.float64)
    # Index-matched: A = 1 and the depth mu_i (as the shipped table was fitted); else Snell and the medium's A.
    mu_t, A = (mu_i, 1.0) if eta == 1.0 else (float(snell_cosine(np.asarray(mu_i), eta, xp=np)[0]),
                                              float(A_coefficient(eta)))
    ratio = np.asarray(curvature_ratio(d, 1.0 / radius, 1.0 - albedo, albedo, A, mu_t, kappa_max=np.inf))
    cells = passage_cells(passage_loss_table(jnp.asarray([albedo]), (mu_i,)))
    chord = 2.0 * radius * mu_t
    shape = (len(d), 1, 1)
    loss = passage_loss(cells, jnp.full(shape, chord), jnp.asarray(d / chord).reshape(shape), 0.5)
    return ratio * (1.0 - np.asarray(loss)[:, 0, 0])


def fit_curvature_correction(sphere: np.ndarray, plane: np.ndarray, eta: float = 1.0,
                             radii: tuple = CORRECTION_RADII, mus=CORRECTION_MUS,
                             albedos=CORRECTION_ALBEDO) -> np.ndarray:
    """``log Q`` ``(U, A, 1 + R, D)`` from the walks' tallies at the incidence nodes ``mus`` and ``albedos``, ``sphere``
    ``(U, A, R, 2, D)`` over ``radii`` (default :data:`CORRECTION_RADII`) and ``plane`` ``(U, A, 2, D)`` (light,
    photons): the walk's
    gain over the renderer's model (:func:`renderer_model`) per chord bin, 0 on the plane; held beyond the last bin
    with :data:`CORRECTION_MIN_COUNT` photons in both walks.

    The bin that holds the antipode (``d0 < 2 a < d1``) is kept: on the sphere it covers the area ``pi (4 a^2 -
    d0^2)`` (Archimedes), on the plane ``pi (d1^2 - d0^2)``, and the model is taken at its mean chord ``(d0 + 2 a) /
    2``. Light converges there (Q at the antipode of the 7.5 ``l_u`` sphere is 3x its value at 13 ``l_u``), and it is
    what the far dark side of an object lit from behind shows; until 2026-11-29 that bin was dropped and ``Q`` held
    from the one before it (chicken1's red lit from behind, cos -1 to -0.5 to the light: -28% against Mitsuba with
    it dropped, -12% with it kept)."""
    n_u, n_a, n_r, _, n_d = sphere.shape
    e0, e1 = CORRECTION_D_EDGES[:-1], CORRECTION_D_EDGES[1:]
    log_q = np.zeros((n_u, n_a, n_r + 1, n_d))
    for k, mu in enumerate(float(m) for m in mus):
        for j, albedo in enumerate(float(a) for a in albedos):
            p = plane[k, j]
            for r, radius in enumerate(radii):
                s = sphere[k, j, r]
                antipode = (e0 < 2.0 * radius) & (e1 > 2.0 * radius)
                ok = (s[1] >= CORRECTION_MIN_COUNT) & (p[1] >= CORRECTION_MIN_COUNT) & ((e1 <= 2.0 * radius) | antipode)
                # The sphere's area in each bin over the plane's (1 but in the antipode's bin).
                area = np.where(antipode, (e1**2 - e0**2) / np.maximum(4.0 * radius**2 - e0**2, 1e-300), 1.0)
                chord = np.where(antipode, 0.5 * (e0 + 2.0 * radius), np.asarray(CORRECTION_D))
                # Transport's gain over the renderer's model of it, per chord bin.
                q = np.log(np.maximum(s[0] * area, 1e-300) / np.maximum(p[0], 1e-300)) \
                    - np.log(np.maximum(renderer_model(mu, albedo, radius, chord, eta), 1e-300))
                good = np.flatnonzero(ok)
                # Held beyond the last bin with light (before the first: every walk has light there).
                log_q[k, j, 1 + r] = np.interp(np.arange(n_d), good, q[good])
    return log_q


def generate_curvature_correction(photons: int = CORRECTION_PHOTONS, seed: int = 47, progress: bool = True,
                                  mus=CORRECTION_MUS, albedos=CORRECTION_ALBEDO) -> dict:
    """Run the walks (``mus``, default :data:`CORRECTION_MUS`, x ``albedos``, default :data:`CORRECTION_ALBEDO`, each
    on a half-space and the spheres of :data:`CORRECTION_RADII`; seeds by each node's slot among
    :data:`CORRECTION_MUS` and each albedo's among :data:`CORRECTION_ALBEDO`) and return the table: ``log_q``, the
    tallies and metadata."""
    from jaxsss.render.walk import sphere_and_plane_tallies

    t0 = time.perf_counter()
    mus = tuple(float(m) for m in mus)
    albedos = tuple(float(a) for a in albedos)
    sphere, plane = sphere_and_plane_tallies(_tally, mus, albedos, CORRECTION_RADII, photons, seed,
                                             "curvature correction", progress, table_mus=CORRECTION_MUS,
                                             table_albedo=CORRECTION_ALBEDO)
    return {"log_q": fit_curvature_correction(sphere, plane, mus=mus, albedos=albedos), "sphere": sphere,
            "plane": plane, "mus": np.asarray(mus), "albedo": np.asarray(albedos),
            "radii": np.asarray(CORRECTION_RADII), "kappa": np.asarray(CORRECTION_KAPPA),
            "d": np.asarray(CORRECTION_D), "d_edges": CORRECTION_D_EDGES, "photons": photons, "seed": seed,
            "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.walk.pencil_beam_walk: index-matched isotropic sphere and half-space, orders >= 2"}


def load_curvature_correction() -> dict:
    """The shipped table (:data:`CORRECTION_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(CORRECTION_TABLE)


def log_correction_table(r_lu, kappa_lu, mus, albedo, log_q=None, kappa=CORRECTION_KAPPA, table_mus=None,
                         table_albedo=None):
    """``(K, G, N, C)``: ``log Q`` at the distances ``r_lu`` ``(G, C)`` and curvatures ``kappa_lu`` ``(G, N, C)``
    (both in units of ``l_u``), for the incidence nodes ``mus`` (each one of :data:`CORRECTION_MUS`) and albedos
    ``(C,)``: linear in ``sqrt(1 - albedo)`` (:func:`jaxsss.render.exit_distance.node_rows`), bilinear in (``kappa
    l_u``, ``d / l_u``) on the table's nodes, held beyond them. Differentiable in ``albedo`` and the coordinates.
    ``log_q``: another table (default the shipped index-matched one; :mod:`jaxsss.render.dielectric_correction`) on
    the curvature nodes ``kappa``, incidence nodes ``table_mus`` and albedos ``table_albedo``, the same elsewhere."""
    from jaxsss.render.exit_distance import node_rows
    from jaxsss.render.passage import piecewise_linear

    if log_q is None:
        shipped = load_curvature_correction()
        log_q, table_mus, table_albedo = shipped["log_q"], tuple(shipped["mus"]), tuple(shipped["albedo"])
    elif table_albedo is None:
        raise ValueError("log_correction_table: a log_q of its own needs its table_albedo (its albedo nodes)")
    rows = node_rows(log_q, table_mus, table_albedo, mus, albedo,  # (K, C, Nk, D)
                     "curvature_correction (transport-corrected curvature ratio)", coordinate="diffusion")
    # Linear in d / l_u at every curvature node: (G, K, C, Nk) -> (Nk, G, 1, K, C).
    by_d = piecewise_linear(r_lu[:, None, :, None], CORRECTION_D, jnp.moveaxis(rows, 3, 0))
    by_d = jnp.moveaxis(by_d, 3, 0)[:, :, None]
    # Then in kappa l_u: (G, N, K, C) -> (K, G, N, C).
    q = piecewise_linear(kappa_lu[:, :, None, :], kappa, by_d)
    return jnp.moveaxis(q, 2, 0)


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.curvature_correction", path=CORRECTION_TABLE, photons=CORRECTION_PHOTONS,
        description="The transport correction of the curvature ratio of the white kernels' orders >= 2 "
                    "(jaxsss.render.curvature_correction).",
        photons_help="photons per walk (6 spheres and a half-space per node)", load=load_curvature_correction,
        refit=lambda tab: {"log_q": fit_curvature_correction(tab["sphere"], tab["plane"], mus=tuple(tab["mus"]),
                                                             albedos=tuple(tab["albedo"]))},
        generate=generate_curvature_correction, node_keys=("log_q", "sphere", "plane"),
        albedo_keys=("log_q", "sphere", "plane"),
        describe=lambda tab: (f"log Q {tab['log_q'].shape} (mu_i, albedo, kappa l_u, d / l_u); "
                              f"{int(tab['photons'])} photons per walk, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
