"""The directional albedo of an index-matched half-space with Henyey-Greenstein scattering, from adding-doubling.

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

``python -m jaxsss.render.anisotropic_albedo --regenerate`` remakes ``data/anisotropic_albedo.npz`` (15 s;
needs iadpython, the ``test`` extra).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["G_NODES", "QUAD_POINTS", "TABLE", "X_NODES", "anisotropic_directional_albedo", "generate_anisotropic_albedo",
           "load_anisotropic_albedo"]

G_NODES = tuple(round(0.05 * k, 2) for k in range(20))
"""Anisotropies of the table: 0 to 0.95 in steps of 0.05 (the white Monte Carlo family's range)."""
X_NODES = tuple(round(k / 40, 4) for k in range(41))
"""``x = sqrt(1 - alpha')``: 0 (no absorption, ``A = 1``) to 1 (no scattering, ``A = 0``) in 40 steps."""
QUAD_POINTS = 24
"""Adding-doubling quadrature points (module docstring: iadpython is exact to 2e-5 at 24, and breaks above 32)."""
TABLE = Path(__file__).resolve().parent / "data" / "anisotropic_albedo.npz"


def generate_anisotropic_albedo(progress: bool = True) -> dict:
    """``{"A": (G, X, M), "mu": (M,), "g": (G,), "x": (X,), "seconds"}`` by adding-doubling (module docstring)."""
    import iadpython
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    mu = None
    table = np.zeros((len(G_NODES), len(X_NODES), QUAD_POINTS))
    for i, g in enumerate(tqdm(G_NODES, desc="adding-doubling by g", disable=not progress)):
        for j, x in enumerate(X_NODES):
            alpha_prime = 1.0 - x * x
            if x == 0.0:
                table[i, j] = 1.0  # no absorption: everything comes back
                continue
            # The single-scattering albedo of (sigma_a, sigma_s' / (1 - g)) for sigma_a / sigma_s' = (1 - a') / a'.
            a = 0.0 if alpha_prime == 0.0 else 1.0 / (1.0 + (1.0 - alpha_prime) / alpha_prime * (1.0 - g))
            sample = iadpython.Sample(a=a, b=1e4, g=g, n=1.0, quad_pts=QUAD_POINTS)
            R = sample.rt_matrices()[0]
            # Directional albedo at each quadrature cosine: the reflected flux of a unit beam incident along nu_j.
            table[i, j] = np.dot(sample.twonuw, R)
            mu = np.asarray(sample.nu)
    return {"A": table, "mu": mu, "g": np.asarray(G_NODES), "x": np.asarray(X_NODES),
            "seconds": time.perf_counter() - t0}


def load_anisotropic_albedo() -> dict:
    """The shipped table (:data:`TABLE`) as NumPy arrays (cached)."""
    from jaxsss.render.walk import load_table

    return load_table(TABLE)


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
    from jaxsss.render.passage import piecewise_linear

    g = float(g)
    if not G_NODES[0] <= g <= G_NODES[-1]:
        raise ValueError(f"anisotropic_directional_albedo(g={g}) must be in [{G_NODES[0]}, {G_NODES[-1]}]")
    mu = np.asarray(mu, dtype=np.float64).reshape(-1)
    if mu.size and (mu.min() < 0.0 or mu.max() > 1.0):
        raise ValueError(f"anisotropic_directional_albedo(mu in [{mu.min()}, {mu.max()}]) must be in [0, 1]")
    tab = load_anisotropic_albedo()
    # Linear in g (concrete): (X, M).
    by_g = np.apply_along_axis(lambda col: np.interp(g, tab["g"], col), 0, tab["A"])
    # Linear in mu on the quadrature's cosines (concrete): (X, M_out).
    by_mu = np.apply_along_axis(lambda row: np.interp(mu, tab["mu"], row), 1, by_g)
    # Linear in x = sqrt(1 - alpha') (traced; a zero-safe square root keeps the derivative finite at alpha' = 1).
    one_minus = jnp.clip(1.0 - jnp.asarray(alpha_prime), 0.0, 1.0)
    x = jnp.where(one_minus > 0.0, jnp.sqrt(jnp.where(one_minus > 0.0, one_minus, 1.0)), 0.0)
    out = piecewise_linear(x[:, None], tab["x"], jnp.asarray(by_mu, dtype=x.dtype))  # (C, M_out)
    return out.T


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m jaxsss.render.anisotropic_albedo",
                                description="The directional albedo of an index-matched HG half-space (adding-doubling).")
    p.add_argument("--regenerate", action="store_true", help="recompute the table with iadpython and write it")
    p.add_argument("--out", type=Path, default=TABLE, help=f"the table's path (default {TABLE})")
    args = p.parse_args(argv)
    if not args.regenerate:
        tab = load_anisotropic_albedo()
        print(f"{TABLE}: A (g, x, mu) {tab['A'].shape}, g {tab['g'][0]}-{tab['g'][-1]}, "
              f"mu {tab['mu'][0]:.4f}-{tab['mu'][-1]:.4f}")
        return 0
    tab = generate_anisotropic_albedo()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **{k: np.asarray(v) for k, v in tab.items()})
    print(f"wrote {args.out} in {tab['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
