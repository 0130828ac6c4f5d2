"""The directional albedo of a half-space with Henyey-Greenstein scattering, index-matched or behind a dielectric
boundary, from adding-doubling.

``A(mu; alpha', g)`` is the fraction of light incident at cosine ``mu`` that a semi-infinite medium of reduced albedo
``alpha' = sigma_s' / (sigma_a + sigma_s')`` and anisotropy ``g`` sends back, every order, at ``eta = 1``. For
``g = 0`` it is Chandrasekhar's ``1 - H(mu) sqrt(1 - a)`` (:func:`jaxsss.render.bssrdf.directional_albedo`). For ``g >
0`` it is not the isotropic equivalent's at the same ``alpha'`` (similarity holds for the totals of diffuse light,
not for the incidence's dependence): forward scattering sends grazing light back sooner and normal light deeper. At
``g = 0.9``, ``alpha' = 0.83`` (the renderer's ``g = 0.9`` test material's blue) ``A(0.1) / A(1)`` is 2.32 against
1.66 for the isotropic equivalent.

The renderer's white-oblique kernel holds the exact profiles at three incidence nodes (1, 0.5, 0.1) and mixes them
linearly in the light's cosine; :func:`jaxsss.render.bssrdf.albedo_correction` scales each light so that the mix
reflects ``A(mu)``. With the isotropic curve for ``g = 0.9`` that factor was 1-2.7% too large at ``mu`` 0.2-0.8 and
2-6% too small at ``mu`` 0.02-0.05 (``alpha'`` 0.83-0.95; the kernel's node totals are within 0.4% of this table's).

Tabulated: :data:`TABLE` holds ``A`` on :data:`G_NODES` x :data:`X_NODES` (``x = sqrt(1 - alpha')``) x the
:data:`QUAD_POINTS` Radau cosines of the adding-doubling quadrature (``mu`` in the file); ``A = 1`` at ``x = 0``.
Computed by iadpython (S. Prahl's adding-doubling, ``Sample(a, b = 1e4, g, n = 1, quad_pts = 24)``: the reflection
matrix's column sums ``sum_i 2 nu_i w_i R_ij`` are the directional albedos at the quadrature cosines ``nu_j``; delta-M
for the phase function). The quadrature: at ``g = 0.9`` its 16- and 24-point runs agree within 2e-5 at normal
incidence and 0.1% at ``mu = 0.1``; iadpython 0.5.3 breaks down above that (32 points 0.75-1.4% low at normal
incidence, 40-64 points meaningless). Interpolation: linear in each axis, held beyond the ends; within 0.4% of fresh
adding-doubling between the nodes at ``mu >= 0.05`` (``tests/render/test_anisotropic_albedo.py``).

Behind a smooth dielectric boundary (``eta = n_inside / n_outside > 1``) the share of the light incident at ``mu``
(outside) that comes back diffusely is ``A(mu; alpha', g, eta) = (1 - F(mu)) B``: ``F`` the exact Fresnel reflectance
(the specular part, left out), ``B`` the share of the transmitted light that the half-space and its internal
reflection send back out. ``A`` is concave in ``mu``: it falls to 0 at grazing incidence with the transmittance. At
``eta = 1.4`` and ``alpha' = 0.99`` (isotropic) it is 0.27 / 0.54 / 0.61 / 0.60 at ``mu`` 0.09 / 0.33 / 0.75 / 1, so
the white-oblique kernel's linear mix of its nodes (1, 0.5, 0.1) under-reflects cos 0.25 by about 30%
(:func:`jaxsss.render.bssrdf.albedo_correction` takes ``eta``). :data:`DIELECTRIC_TABLE` holds ``B`` on
:data:`G_NODES` x :data:`ETA_NODES` x :data:`X_NODES` x 24 cosines ``nu`` inside above the critical angle, at the
relative places ``t = (nu - nu_c) / (1 - nu_c)`` that are the index-matched table's ``mu`` (iadpython,
``Sample(a, b = 1e4, g, n = eta, quad_pts = 48)``: half the points below the critical angle; the column sums of the
reflection matrix, boundary included, less those of a run without scattering, which are ``F`` to 4 digits). ``B`` is
smooth in ``nu``; it is interpolated linearly in the outside cosine on each ``eta`` node's own cosines, then linearly
in ``eta`` (the nodes are dense near 1, where the critical angle opens and ``B`` changes fastest): against fresh
32-point runs off every node within 0.3% at ``alpha' >= 0.95`` and 0.75% at 0.5-0.83, at every cosine. Checked
against the renderer's white Monte Carlo tables at ``(g = 0, n = 1.33, 1.4)`` and a Fresnel walk under diffuse light
(``tests/render/test_anisotropic_albedo.py``).

``python -m jaxsss.render.anisotropic_albedo --regenerate`` remakes ``data/anisotropic_albedo.npz`` (15 s) and
``data/dielectric_albedo.npz`` (about 10 minutes); it needs iadpython, the ``test`` extra.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["DIELECTRIC_QUAD_POINTS", "DIELECTRIC_TABLE", "ETA_NODES", "G_NODES", "QUAD_POINTS", "TABLE", "X_NODES",
           "albedo_cosines", "anisotropic_directional_albedo", "dielectric_directional_albedo",
           "generate_anisotropic_albedo", "generate_dielectric_albedo", "load_anisotropic_albedo",
           "load_dielectric_albedo"]

G_NODES = tuple(round(0.05 * k, 2) for k in range(20))
"""Anisotropies of the table: 0 to 0.95 in steps of 0.05 (the white Monte Carlo family's range)."""
X_NODES = tuple(round(k / 40, 4) for k in range(41))
"""``x = sqrt(1 - alpha')``: 0 (no absorption, ``A = 1``) to 1 (no scattering, ``A = 0``) in 40 steps."""
QUAD_POINTS = 24
"""Adding-doubling quadrature points (module docstring: iadpython is exact to 2e-5 at 24, and breaks above 32)."""
TABLE = Path(__file__).resolve().parent / "data" / "anisotropic_albedo.npz"
ETA_NODES = (1.01, 1.02, 1.05, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6)
"""Relative indices ``eta`` of the dielectric table (linear in ``eta`` between them and the index-matched table at 1;
dense near 1, where the critical angle opens and ``B`` changes fastest)."""
DIELECTRIC_QUAD_POINTS = 48
"""Adding-doubling quadrature points with a boundary: half of them (24) are Radau cosines between the critical angle
and normal incidence, at the same relative places ``t`` as :data:`QUAD_POINTS` at ``eta = 1``."""
DIELECTRIC_TABLE = Path(__file__).resolve().parent / "data" / "dielectric_albedo.npz"


def _single_scattering_albedo(alpha_prime: float, g: float) -> float:
    """The single-scattering albedo of ``(sigma_a, sigma_s' / (1 - g))`` for ``sigma_a / sigma_s' = (1 - a') / a'``."""
    return 0.0 if alpha_prime == 0.0 else 1.0 / (1.0 + (1.0 - alpha_prime) / alpha_prime * (1.0 - g))


def _column_sums(a: float, g: float, n: float, quad_pts: int) -> tuple[np.ndarray, np.ndarray]:
    """``(nu, R)``: adding-doubling's quadrature cosines inside that light leaves by (above the critical angle) and the
    total reflection of a unit beam incident along each, boundary included (iadpython, a thick slab ``b = 1e4``;
    ``rt_matrices`` before ``twonuw``, which it sets)."""
    import iadpython

    sample = iadpython.Sample(a=a, b=1e4, g=g, n=n, quad_pts=quad_pts)
    R = sample.rt_matrices()[0]
    nu, two_nu_w = np.asarray(sample.nu), np.asarray(sample.twonuw)
    k = np.flatnonzero(nu > (sample.nu_c() if n != 1.0 else 0.0))
    # Directional albedo at each quadrature cosine: the reflected flux of a unit beam incident along nu_j.
    return nu[k], two_nu_w[k] @ R[np.ix_(k, k)]


def generate_anisotropic_albedo(progress: bool = True) -> dict:
    """``{"A": (G, X, M), "mu": (M,), "g": (G,), "x": (X,), "seconds"}`` by adding-doubling (module docstring)."""
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    mu = None
    table = np.zeros((len(G_NODES), len(X_NODES), QUAD_POINTS))
    for i, g in enumerate(tqdm(G_NODES, desc="adding-doubling by g", disable=not progress)):
        for j, x in enumerate(X_NODES):
            if x == 0.0:
                table[i, j] = 1.0  # no absorption: everything comes back
                continue
            mu, table[i, j] = _column_sums(_single_scattering_albedo(1.0 - x * x, g), g, 1.0, QUAD_POINTS)
    return {"A": table, "mu": mu, "g": np.asarray(G_NODES), "x": np.asarray(X_NODES),
            "seconds": time.perf_counter() - t0}


def generate_dielectric_albedo(progress: bool = True) -> dict:
    """``{"B": (G, E, X, M), "t": (M,), "g", "eta", "x", "seconds"}``: the share ``B = A / (1 - F)`` of the light
    transmitted at each escaping quadrature cosine that comes back out, by adding-doubling with the boundary at
    every :data:`ETA_NODES` (module docstring); ``t = (nu - nu_c) / (1 - nu_c)``, the same for every ``eta``."""
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    table = np.zeros((len(G_NODES), len(ETA_NODES), len(X_NODES), DIELECTRIC_QUAD_POINTS // 2))
    t = None
    for i, g in enumerate(tqdm(G_NODES, desc="adding-doubling with a boundary, by g", disable=not progress)):
        for e, eta in enumerate(ETA_NODES):
            # No scattering: the boundary's own (specular) reflection, F at each cosine.
            nu, specular = _column_sums(0.0, g, eta, DIELECTRIC_QUAD_POINTS)
            nu_c = np.sqrt(1.0 - 1.0 / eta**2)
            t = (nu - nu_c) / (1.0 - nu_c)
            for j, x in enumerate(X_NODES):
                if x == 0.0:
                    table[i, e, j] = 1.0  # no absorption: all the transmitted light comes back
                    continue
                total = _column_sums(_single_scattering_albedo(1.0 - x * x, g), g, eta, DIELECTRIC_QUAD_POINTS)[1]
                table[i, e, j] = (total - specular) / (1.0 - specular)
    # float32: 1e-7 relative, far below the interpolation's error, and half the file (0.6 MB).
    return {"B": table.astype(np.float32), "t": t, "g": np.asarray(G_NODES), "eta": np.asarray(ETA_NODES),
            "x": np.asarray(X_NODES), "seconds": time.perf_counter() - t0}


def load_anisotropic_albedo() -> dict:
    """The shipped table (:data:`TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(TABLE)


def _checked(owner: str, mu, g: float) -> tuple[np.ndarray, float]:
    """``(mu (M,), g)`` as floats, or a ValueError naming ``owner``, the value and the range."""
    g = float(g)
    if not G_NODES[0] <= g <= G_NODES[-1]:
        raise ValueError(f"{owner}(g={g}) must be in [{G_NODES[0]}, {G_NODES[-1]}]")
    mu = np.asarray(mu, dtype=np.float64).reshape(-1)
    if mu.size and (mu.min() < 0.0 or mu.max() > 1.0):
        raise ValueError(f"{owner}(mu in [{mu.min()}, {mu.max()}]) must be in [0, 1]")
    return mu, g


def _linear_in_x(alpha_prime, x_nodes, rows):
    """``(M, C)``: ``rows`` ``(X, M)`` linear in ``x = sqrt(1 - alpha')`` at ``alpha_prime`` ``(C,)`` (traced; a
    zero-safe square root keeps the derivative finite at ``alpha' = 1``)."""
    from jaxsss.render.passage import piecewise_linear

    one_minus = jnp.clip(1.0 - jnp.asarray(alpha_prime), 0.0, 1.0)
    x = jnp.where(one_minus > 0.0, jnp.sqrt(jnp.where(one_minus > 0.0, one_minus, 1.0)), 0.0)
    return piecewise_linear(x[:, None], x_nodes, jnp.asarray(rows, dtype=x.dtype)).T


def anisotropic_directional_albedo(mu, alpha_prime, g: float):
    """``(M, C)``: the directional albedo ``A(mu; alpha', g)`` of an index-matched half-space (module docstring).

    Args:
        mu: ``(M,)`` incidence cosines, concrete (host values: the renderer's grid), in ``[0, 1]``.
        alpha_prime: ``(C,)`` reduced albedo ``sigma_s' / (sigma_a + sigma_s')`` in ``[0, 1]``; traced and
            differentiable.
        g: the Henyey-Greenstein anisotropy, a concrete float in ``[0, 0.95]``.

    Returns:
        ``A`` ``(M, C)``, linear in ``mu``, ``x = sqrt(1 - alpha')`` and ``g`` on the table's nodes.

    Raises:
        ValueError: ``g`` outside ``[0, 0.95]`` or ``mu`` outside ``[0, 1]``.
    """
    mu, g = _checked("anisotropic_directional_albedo", mu, g)
    tab = load_anisotropic_albedo()
    # Linear in g (concrete): (X, M).
    by_g = np.apply_along_axis(lambda col: np.interp(g, tab["g"], col), 0, tab["A"])
    # Linear in mu on the quadrature's cosines (concrete): (X, M_out).
    by_mu = np.apply_along_axis(lambda row: np.interp(mu, tab["mu"], row), 1, by_g)
    return _linear_in_x(alpha_prime, tab["x"], by_mu)


def load_dielectric_albedo() -> dict:
    """The shipped dielectric table (:data:`DIELECTRIC_TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(DIELECTRIC_TABLE)


def _eta_bracket(eta: float) -> list[tuple[float, float]]:
    """``[(node, weight)]``: linear interpolation at ``eta`` (in ``(1, 1.6]``) between 1 and :data:`ETA_NODES`."""
    nodes = (1.0,) + ETA_NODES
    k = min(max(int(np.searchsorted(nodes, eta)), 1), len(nodes) - 1)
    w = (eta - nodes[k - 1]) / (nodes[k] - nodes[k - 1])
    return [(node, weight) for node, weight in ((nodes[k - 1], 1.0 - w), (nodes[k], w)) if weight > 0.0]


def albedo_cosines(eta: float = 1.0) -> np.ndarray:
    """The outside cosines at which :func:`dielectric_directional_albedo` at ``eta`` (or
    :func:`anisotropic_directional_albedo` at 1) has kinks: the escaping quadrature cosines of the ``eta`` nodes it
    mixes, sorted. A caller that samples the curve and interpolates it keeps them."""
    eta = float(eta)
    if eta == 1.0:
        return _node_cosines(1.0)
    return np.unique(np.concatenate([_node_cosines(node) for node, _ in _eta_bracket(eta)]))


def _node_cosines(eta: float) -> np.ndarray:
    """The outside cosines of a table's escaping quadrature cosines at the node ``eta`` (1 or one of
    :data:`ETA_NODES`)."""
    if eta == 1.0:
        return np.asarray(load_anisotropic_albedo()["mu"])
    nu_c = np.sqrt(1.0 - 1.0 / eta**2)
    nu = nu_c + load_dielectric_albedo()["t"] * (1.0 - nu_c)
    # Snell: the cosine outside of light that leaves along nu.
    return np.sqrt(np.maximum(1.0 - eta**2 * (1.0 - nu**2), 0.0))


def _escaping_share(g: float, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """``(mu, B)``: :func:`_node_cosines` at the node ``eta`` and ``B`` ``(X, M)`` there (``A`` at 1), linear in ``g``
    (concrete)."""
    tab = load_anisotropic_albedo() if eta == 1.0 else load_dielectric_albedo()
    rows = tab["A"] if eta == 1.0 else tab["B"][:, ETA_NODES.index(eta)]
    return _node_cosines(eta), np.apply_along_axis(lambda col: np.interp(g, tab["g"], col), 0, rows)


def dielectric_directional_albedo(mu, alpha_prime, g: float, eta: float):
    """``(M, C)``: the directional albedo ``A(mu; alpha', g, eta)`` of a half-space behind a smooth boundary of relative
    index ``eta`` (module docstring): the diffusely reflected share of the light incident at ``mu`` (outside),
    specular reflection excluded, ``A = (1 - F(mu)) B``.

    Args:
        mu: ``(M,)`` incidence cosines outside, concrete, in ``[0, 1]``.
        alpha_prime: ``(C,)`` reduced albedo in ``[0, 1]``; traced and differentiable.
        g: the Henyey-Greenstein anisotropy, a concrete float in ``[0, 0.95]``.
        eta: ``n_inside / n_outside``, a concrete float in ``[1, 1.6]``; 1 is
            :func:`anisotropic_directional_albedo`.

    Returns:
        ``A`` ``(M, C)``: ``B`` linear in the outside cosine on each ``eta`` node's escaping cosines, in ``eta``
        between the nodes, in ``g`` and in ``x = sqrt(1 - alpha')``; times the exact Fresnel transmittance at ``mu``.

    Raises:
        ValueError: ``eta`` outside ``[1, 1.6]``, ``g`` outside ``[0, 0.95]`` or ``mu`` outside ``[0, 1]``.
    """
    from jaxsss.fresnel import fresnel_unpolarised

    eta = float(eta)
    nodes = (1.0,) + ETA_NODES
    if not nodes[0] <= eta <= nodes[-1]:
        raise ValueError(f"dielectric_directional_albedo(eta={eta}) must be in [{nodes[0]}, {nodes[-1]}]")
    if eta == 1.0:
        return anisotropic_directional_albedo(mu, alpha_prime, g)
    mu, g = _checked("dielectric_directional_albedo", mu, g)
    # Linear in eta between the two nodes around it (concrete), each linear in mu on its own escaping cosines.
    share = 0.0
    for node, weight in _eta_bracket(eta):
        cos, rows = _escaping_share(g, node)
        share = share + weight * np.apply_along_axis(lambda row, cos=cos: np.interp(mu, cos, row), 1, rows)
    B = _linear_in_x(alpha_prime, load_dielectric_albedo()["x"], share)
    # A = (1 - F(mu)) B: the exact Fresnel transmittance into the medium.
    return (1.0 - fresnel_unpolarised(mu, eta, xp=np))[:, None].astype(B.dtype) * B


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m jaxsss.render.anisotropic_albedo",
                                description="The directional albedo of an HG half-space, index-matched and behind a "
                                            "dielectric boundary (adding-doubling).")
    p.add_argument("--regenerate", action="store_true", help="recompute the tables with iadpython and write them")
    p.add_argument("--out", type=Path, default=TABLE.parent,
                   help=f"the directory to write them to (default {TABLE.parent})")
    args = p.parse_args(argv)
    if not args.regenerate:
        tab, die = load_anisotropic_albedo(), load_dielectric_albedo()
        print(f"{TABLE}: A (g, x, mu) {tab['A'].shape}, g {tab['g'][0]}-{tab['g'][-1]}, "
              f"mu {tab['mu'][0]:.4f}-{tab['mu'][-1]:.4f}")
        print(f"{DIELECTRIC_TABLE}: B (g, eta, x, t) {die['B'].shape}, eta {die['eta'][0]}-{die['eta'][-1]}")
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    for path, generate in ((TABLE, generate_anisotropic_albedo), (DIELECTRIC_TABLE, generate_dielectric_albedo)):
        tab = generate()
        np.savez_compressed(args.out / path.name, **{k: np.asarray(v) for k, v in tab.items()})
        print(f"wrote {args.out / path.name} in {tab['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
