"""The exit's current: light leaves a translucent surface brighter along its flow, away from where it entered.

The white kernels' exit distributions (:func:`jaxsss.render.bssrdf.multiple_exit_distribution`, and its curved form
:mod:`jaxsss.render.exit_curvature`) depend on the exit cosine only: the radiance of a pencil beam's light at
distance ``d`` from the entry is taken to be the same in every azimuth. It is not. The light that reaches ``d`` is
moving away from the entry (Fick's law), so it leaves brighter in the directions that point away from the entry
along the surface than back towards it. An index-matched isotropic half-space (the walk of
:func:`jaxsss.render.walk.pencil_beam_walk`, orders >= 2), albedo 0.96 at normal incidence: the radiance is ``1 + A
cos phi`` (``phi``: the azimuth between the exit direction's tangential part and the direction away from the entry)
with ``A`` 0.7-1.1 at grazing exits (``mu_o`` 0.1) and 0.3-0.7 near the normal, from half a transport length on.

On a uniformly lit plane the pairs' currents cancel. At a point-lit sphere's terminator they do not: the light flows
from the lit side into the dark one (``benchmarks/sphere_transport.py``: the walk's azimuth factor at the camera is
0.72-0.87 seen from the light's side, 1.3-1.9 seen from behind).

The model: each pair adds ``v_k a(r_k / l_u) (t_k . t_o) Y_k(mu_o)`` to the radiance, ``v_k`` its node's exitance,
``r_k`` and ``t_k`` the distance from the node's (shifted) entry and the unit tangential direction away from it at
the shaded point, ``t_o`` the unit tangential part of the direction to the eye, ``a`` the normal-incidence
half-space's amplitude (the oblique nodes' light flows away from their shifted centres; their own rows of the table,
about the unshifted entry, over-counted the flow 2-4x on a plane under a point light), and ``Y_k = X_2(mu_o | mu_k)
psi_k(mu_o)`` (:func:`current_exit_distribution`): a rank-1 fit ``A ~ a(d) psi(mu_o)`` of the walks' first azimuthal
harmonic per incidence node and albedo (:func:`fit_exit_current`). The sums carry the current as three more rows per
node, ``sum v_k a t_k`` (:attr:`jaxsss.render.bssrdf.WhiteKernel.exit_current`); the exitance is unchanged (``cos
phi`` integrates to 0 over the azimuth). The near-field disc carries none (its light enters all around the shaded
point).

Only the current along the view is added (:func:`jaxsss.render.bssrdf.current_radiance`): where the view looks
against the flow the kernels' exitance is already short by about as much (the sphere's terminator seen from the
light's side: exitance 0.69-0.83 of the walk's, against an azimuth factor of 0.72-0.87; docs/path_tracer.md, "Two
errors that cancel at the terminator"), and the whole current would count that loss twice. The scene plan keeps the
current for the light of every light behind the object (:func:`jaxsss.render.plan.make_plan`, "exit azimuth"), the
views that look along its flow, together with the curvature ratio's far field corrected by transport
(:mod:`jaxsss.render.curvature_correction`); the light of lights on the camera's side is summed apart without them
(:meth:`jaxsss.render.renderer.Prepared.light_sides`). Forced on for lights on the camera's side, the clamped current
changed the committed images by 0 to 1.2% in sum; the image's sums take 1.7-1.9x as long with it.

Behind a dielectric boundary the white kernels hold every order and leave by the refracted exit; their current comes
from Fresnel walks (``eta`` as the last argument of :func:`current_amplitude` and :func:`current_exit_distribution`;
the table and why both signs are kept there: :mod:`jaxsss.render.dielectric_current`).

``python -m jaxsss.render.exit_current --regenerate`` remakes ``data/exit_current.npz``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["CURRENT_ALBEDO", "CURRENT_D", "CURRENT_D_EDGES", "CURRENT_MU_EDGES", "CURRENT_MUS", "current_amplitude",
           "current_amplitude_at", "current_exit_distribution", "fit_exit_current", "generate_exit_current_table",
           "load_exit_current_table", "tangential_unit"]

CURRENT_MUS = (1.0, 0.75, 0.5, 0.1)
"""Incidence cosines of the table: the white-oblique kernel's nodes (1 and :data:`jaxsss.render.bssrdf.KERNEL_MUS`)
and 0.75, the lights-behind kernel's (:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`); descending (the lookups take
the shipped table's own ``mus``)."""
CURRENT_ALBEDO = (0.3, 0.6, 0.8, 0.9, 0.97, 0.995)
"""Single-scattering albedos of the table (linear between, held beyond the ends)."""
CURRENT_D_EDGES = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 50.0])
"""Distance bins from the entry, transport lengths."""
CURRENT_D = tuple(float(x) for x in 0.5 * (CURRENT_D_EDGES[1:] + CURRENT_D_EDGES[:-1]))
"""Distance nodes ``d / l_u`` of ``a``: the bins' centres (linear between, held beyond)."""
CURRENT_MU_EDGES = np.linspace(0.0, 1.0, 21)
CURRENT_PHOTONS = 500_000
"""Photons per (incidence, albedo) walk of the shipped table (49 s for all 18)."""
CURRENT_TABLE = Path(__file__).resolve().parent / "data" / "exit_current.npz"


def _tally(albedo: float, mu_i: float, photons: int, seed: int, eta: float = 1.0) -> np.ndarray:
    """``(4, D, B)``: the light per photon by distance from the entry (:data:`CURRENT_D_EDGES`) and exit cosine
    (:data:`CURRENT_MU_EDGES`; outside the boundary) in the half-space, and the same weighted by ``e . u`` (``e``: the
    unit tangential exit direction, ``u``: the unit direction away from the entry), by ``e . t`` (``t = +x``: the
    light's travel) and by ``u . t``. Index-matched (``eta = 1``): the orders >= 2 (the renderer marches the first).
    Behind a dielectric boundary: every order (:func:`jaxsss.render.walk.pencil_beam_walk` with ``eta``), binned by
    the cosine outside (Snell keeps the azimuth)."""
    from jaxsss.fresnel import snell_cosine
    from jaxsss.render.walk import pencil_beam_walk

    h = np.zeros((4, len(CURRENT_D_EDGES) - 1, len(CURRENT_MU_EDGES) - 1))

    def add(first, exit_point, direction, weight):
        radial = exit_point[:, :2] / np.maximum(np.linalg.norm(exit_point[:, :2], axis=1, keepdims=True), 1e-300)
        along = direction[:, :2] / np.maximum(np.linalg.norm(direction[:, :2], axis=1, keepdims=True), 1e-300)
        bins = [CURRENT_D_EDGES, CURRENT_MU_EDGES]
        mu = np.clip(direction[:, 2], 0.0, 1.0)
        # Snell: the cosine outside (0 past the critical angle, where nothing leaves).
        mu_o = mu if eta == 1.0 else snell_cosine(mu, 1.0 / eta, xp=np)[0]
        at = (np.linalg.norm(exit_point, axis=1), mu_o)
        for i, f in enumerate((1.0, np.sum(radial * along, axis=1), along[:, 0], radial[:, 0])):
            h[i] += np.histogram2d(*at, bins, weights=weight * f)[0]

    pencil_beam_walk(albedo, mu_i, photons, seed, add, min_order=2 if eta == 1.0 else 1, eta=eta)
    return h / photons


def fit_exit_current(tallies: np.ndarray, mus=CURRENT_MUS) -> tuple[np.ndarray, np.ndarray]:
    """``(ab (U, A, D, 2), psi (U, A, B))`` from the walks' ``tallies`` ``(U, A, 4, D, B)`` at the incidence nodes
    ``mus``. Per bin, the radiance's
    first harmonic as a vector ``c = a u + b t`` (``L ~ 1 + c . e``, so ``<e> = c / 2``), ``(a, b)`` by least squares
    over the bin's photons: ``[[W, W_ut], [W_ut, W]] (a, b) = 2 (W_eu, W_et)``. Then ``(a, b)(d, mu_o) ~ (a(d),
    b(d)) psi(mu_o)`` (rank 1 over both, each bin weighted by its light); ``psi`` scaled to 1 at its largest, ``a``
    and ``b`` held beyond the last distance bin with light. ``b = 0`` at normal incidence (by symmetry)."""
    n_u, n_a, _, n_d, n_b = tallies.shape
    amp, shape = np.zeros((n_u, n_a, n_d, 2)), np.zeros((n_u, n_a, n_b))
    for k in range(n_u):
        for j in range(n_a):
            light, eu, et, ut = tallies[k, j]
            det = np.maximum(light * light - ut * ut, 1e-300)
            a = 2.0 * (light * eu - ut * et) / det
            b = 2.0 * (light * et - ut * eu) / det
            if float(mus[k]) == 1.0:
                b = np.zeros_like(b)
            w = np.sqrt(light / light.sum())
            stacked = np.concatenate([a * w, b * w])  # (2D, B)
            psi = np.linalg.svd(stacked, full_matrices=False)[2][0]
            psi = psi * np.sign(psi.sum())
            psi = psi / np.max(np.abs(psi))
            # a(d) and b(d) by weighted least squares against psi, bin by bin.
            norm = np.maximum(np.sum(light * psi * psi, axis=1), 1e-300)
            ok = np.flatnonzero(light.sum(axis=1) > 1e-4 * light.sum())
            for i, x in enumerate((a, b)):
                fit = np.sum(light * x * psi, axis=1) / norm
                amp[k, j, :, i] = np.interp(np.arange(n_d), ok, fit[ok])
            shape[k, j] = psi
    return amp, shape


def generate_exit_current_table(photons: int = CURRENT_PHOTONS, seed: int = 53, progress: bool = True,
                                eta: float = 1.0, mus=None, table_mus=CURRENT_MUS) -> dict:
    """Run the half-space walks (``mus``, default ``table_mus``, x :data:`CURRENT_ALBEDO`) at relative index ``eta``
    and return the table: ``a``, ``psi``, the tallies and metadata. Seeds ``seed + 100 k + j``, ``k`` the node's
    :func:`jaxsss.render.walk.seed_slot` among ``table_mus``."""
    from jaxsss.render.walk import seed_slot

    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    mus = tuple(table_mus if mus is None else mus)
    tallies = np.zeros((len(mus), len(CURRENT_ALBEDO), 4, len(CURRENT_D_EDGES) - 1, len(CURRENT_MU_EDGES) - 1))
    nodes = [(k, j) for k in range(len(mus)) for j in range(len(CURRENT_ALBEDO))]
    for k, j in tqdm(nodes, desc=f"exit current, eta {eta:g}", disable=not progress):
        tallies[k, j] = _tally(CURRENT_ALBEDO[j], mus[k], photons, seed + 100 * seed_slot(mus[k], table_mus) + j, eta)
    amp, shape = fit_exit_current(tallies, mus)
    orders = "orders >= 2" if eta == 1.0 else f"smooth dielectric boundary eta {eta:g}, orders >= 1"
    return {"ab": amp, "psi": shape, "tallies": tallies, "mus": np.asarray(mus),
            "albedo": np.asarray(CURRENT_ALBEDO), "d": np.asarray(CURRENT_D), "d_edges": CURRENT_D_EDGES,
            "mu_edges": CURRENT_MU_EDGES, "photons": photons, "seed": seed, "seconds": time.perf_counter() - t0,
            "source": f"jaxsss.render.walk.pencil_beam_walk: isotropic half-space, {orders}"}


def load_exit_current_table() -> dict:
    """The shipped table (:data:`CURRENT_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(CURRENT_TABLE)


def _table(name: str, eta=None, dtype=None):
    """``((U, A, ...), mus)``: table ``name`` and its incidence nodes: the index-matched table's orders >= 2 (``eta``
    None), or every order behind a dielectric boundary of relative index ``eta`` (a scalar, may be traced), linear in
    ``eta`` between the dielectric table's nodes and held beyond; in ``dtype`` (None: the table's)."""
    from jaxsss.render.dielectric_current import load_dielectric_current_table
    from jaxsss.render.passage import node_interval

    if eta is None:
        tab = load_exit_current_table()
        return jnp.asarray(tab[name], dtype), tuple(tab["mus"])
    tab = load_dielectric_current_table()
    nodes = jnp.asarray(tab[name], dtype)
    i, t = node_interval(jnp.asarray(eta, nodes.dtype), tab["eta"])
    # Linear in eta between the nodes.
    return (1.0 - t) * nodes[i] + t * nodes[i + 1], tuple(tab["mus"])


def _node_rows(name: str, mus, albedo, eta=None):
    """``(K, C, ...)``: table ``name`` (:func:`_table`, in the albedos' dtype) at the incidence nodes ``mus``, linear
    in the albedos ``(C,)``."""
    from jaxsss.render.exit_distance import node_rows

    table, nodes = _table(name, eta, jnp.result_type(albedo, 0.0))
    return node_rows(table, nodes, CURRENT_ALBEDO, mus, albedo, "exit_current (the exit's current)")


def current_amplitude(albedo, eta=None) -> jnp.ndarray:
    """``(D, C)``: the amplitude ``a`` (away from the entry) of the normal-incidence half-space at :data:`CURRENT_D`
    for albedos ``(C,)`` (linear between the table's, held beyond; differentiable in ``albedo``): the index-matched
    orders >= 2 (``eta`` None) or every order behind a boundary of relative index ``eta`` (:func:`_table`)."""
    return _node_rows("ab", (1.0,), albedo, eta)[0, :, :, 0].T


def current_amplitude_at(table, d_lu):
    """``(P, K, C)``: :func:`current_amplitude`'s ``table`` ``(D, C)`` at ``d_lu`` ``(P, K, C)`` transport lengths
    from the entry (linear between :data:`CURRENT_D`, held beyond)."""
    from jaxsss.render.passage import piecewise_linear

    # Linear in d between the nodes.
    return piecewise_linear(d_lu, CURRENT_D, table[:, None])


def current_exit_distribution(mu_o, mus, albedo, eta=None):
    """``(Q, K, C)``: ``Y_k = X(mu_o | mu_k) psi_k(mu_o)`` for exit cosines ``mu_o`` ``(Q,)`` (outside), the
    incidence nodes ``mus`` and albedos ``(C,)``: the tabulated shape (linear between the exit-cosine bins' centres,
    held beyond them) times the kernels' own exit distribution, the orders >= 2's
    (:func:`jaxsss.render.bssrdf.multiple_exit_distribution`) without ``eta``, else the refracted one behind a boundary
    of relative index ``eta`` (:func:`jaxsss.render.bssrdf.refracted_exit_distribution`, the dielectric table).
    Differentiable in ``albedo``."""
    from jaxsss.render.bssrdf import (
        multiple_exit_distribution,
        refracted_exit_distribution,
    )
    from jaxsss.render.passage import piecewise_linear

    psi = jnp.moveaxis(_node_rows("psi", mus, albedo, eta), -1, 0)  # (B, K, C)
    centres = 0.5 * (CURRENT_MU_EDGES[1:] + CURRENT_MU_EDGES[:-1])
    # Linear between the bins' centres: (Q, K, C).
    psi_q = piecewise_linear(jnp.asarray(mu_o)[:, None, None], centres, psi[:, None])
    nodes = jnp.asarray(mus, psi.dtype)
    if eta is None:
        return multiple_exit_distribution(mu_o, nodes, albedo) * psi_q
    return refracted_exit_distribution(mu_o, nodes, albedo, eta) * psi_q


def tangential_unit(v, normal):
    """``(..., 3)``: the unit tangential part of ``v`` at a surface of unit ``normal`` (both ``(..., 3)``); 0 where
    ``v`` is along the normal."""
    t = v - jnp.sum(v * normal, axis=-1, keepdims=True) * normal
    n2 = jnp.sum(t * t, axis=-1, keepdims=True)
    return jnp.where(n2 > 1e-24, t / jnp.sqrt(jnp.where(n2 > 1e-24, n2, 1.0)), 0.0)


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.exit_current", path=CURRENT_TABLE, photons=CURRENT_PHOTONS,
        description="The azimuthal (current) term of the white kernels' exit, orders >= 2 "
                    "(jaxsss.render.exit_current).",
        photons_help="photons per (incidence, albedo) node", load=load_exit_current_table,
        refit=lambda tab: dict(zip(("ab", "psi"), fit_exit_current(tab["tallies"], tuple(tab["mus"])))),
        generate=generate_exit_current_table, node_keys=("ab", "psi", "tallies"),
        describe=lambda tab: (f"a, b {tab['ab'].shape} (mu_i, albedo, d / l_u, a|b), psi {tab['psi'].shape} "
                              f"(mu_i, albedo, mu_o bin); {int(tab['photons'])} photons per walk, "
                              f"{float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
