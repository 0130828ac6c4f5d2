"""The direction of the light a forward-scattering half-space reflects: the white kernels' exit model for ``g > 0``.

At an index-matched boundary the white kernels send each incidence node's exitance towards the eye with
Chandrasekhar's exit distribution ``X(mu_o | mu_i)`` (:func:`jaxsss.render.bssrdf.exit_distribution`). That is exact
for isotropic scattering, where the reflected radiance has no azimuthal dependence at all. A forward-scattering medium
(Henyey-Greenstein ``g > 0``) sends the light of an oblique beam on forwards: it leaves at grazing exit cosines and
along the beam's own azimuth. For ``g = 0.9``, albedo 0.95, light entering at ``mu_i = 0.1`` (Monte Carlo, below):
two thirds of the reflectance leaves in the forward third of azimuths and one seventh in the backward third, and the
azimuth-averaged radiance at ``mu_o = 0.7`` is 0.65 of the isotropic ``X``. The total reflectance differs from the
isotropic equivalent's by only -4 to +8% (``sigma_s' = sigma_s (1 - g)`` holds for the totals, not for the directions).

**The table.** The radiance leaving a half-space lit at ``mu_i``, relative to a Lambertian exit of the same total,

    X(mu_o, phi | mu_i, alpha', g) = X_0(mu_o) + 2 sum_{m >= 1} X_m(mu_o) cos(m phi),

with ``phi`` the azimuth between the exit direction and the incident beam's direction of travel (both projected on
the surface), is tabulated from :func:`jaxsss.mc.simulate`'s direction tally (``exit_mu_edges``; index-matched
half-space, ``sigma_s' = 1/mm``) at the nodes :data:`EXIT_G` x :data:`EXIT_ALBEDO` x :data:`EXIT_MUS` x the exit-cosine
bins of :data:`EXIT_MU_EDGES`, for ``m = 0 .. EXIT_HARMONICS - 1``. At ``g = 0`` the node is exact instead:
Chandrasekhar's ``X`` and no harmonics (isotropic scattering has no azimuthal dependence); at normal incidence the
harmonics are zero by symmetry and are set so. Interpolated linearly in ``g``, ``alpha'`` (held beyond the ends) and
``mu_o`` (between bin centres); the incidence cosine must be a node (the kernel's nodes are).
``python -m jaxsss.render.exit_direction --regenerate`` remakes ``data/exit_direction.npz``.

**The azimuth at a shaded point** (:func:`azimuth_harmonics`): each delta light's direction of travel at the point,
projected on its tangent plane, against the view's projection, gives ``cos(m phi)``; lights are weighted by their
unshadowed, unclamped irradiance there (so that a point past the terminator, lit only by light diffused from the lit
side, still knows where that light came from). Extended lights (sky, sphere and rectangle lights) count in the weight
but add no harmonics: their columns keep only a mean direction, so their light is taken as spread evenly in azimuth
(the azimuth-averaged ``X_0``). This is material-free and computed once per image.

Measured against Mitsuba's g09_sphere reference (g = 0.9, eta 1, point light; docs/path_tracer.md, "Forward
scattering's exit direction").
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

__all__ = ["EXIT_ALBEDO", "EXIT_G", "EXIT_HARMONICS", "EXIT_MUS", "EXIT_MU_EDGES", "EXIT_TABLE",
           "anisotropic_exit_distribution", "azimuth_harmonics", "generate_exit_table", "load_exit_table"]

EXIT_G = (0.0, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95)
"""Anisotropy nodes of the exit table (``g = 0``: Chandrasekhar's exact ``X``)."""
EXIT_ALBEDO = (0.1, 0.3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.995)
"""Similarity-albedo nodes ``alpha' = sigma_s' / (sigma_a + sigma_s')``."""
EXIT_MUS = (1.0, 0.75, 0.5, 0.25, 0.1)
"""Incidence cosines (the white kernels' nodes are among them)."""
EXIT_MU_EDGES = np.linspace(0.0, 1.0, 21)
"""Exit-cosine bins of the Monte Carlo tally; the table holds their averages, read at the bin centres."""
EXIT_HARMONICS = 9
"""Azimuthal harmonics ``cos(m phi)``, ``m = 0 .. 8``: enough for the forward peak of ``g = 0.9`` at ``mu_o >= 0.1``
(the truncated series is within the table's noise there; nearer grazing the series rings, and the eye rarely sees
a surface at ``mu_o < 0.1``)."""
EXIT_PHOTONS = 200_000
"""Photons per node of the table (the harmonics' noise is about 1% of ``X_0`` per bin at moderate ``mu_o``)."""
EXIT_TABLE = Path(__file__).resolve().parent / "data" / "exit_direction.npz"


def generate_exit_table(photons: int = EXIT_PHOTONS, seed: int = 11, progress: bool = True) -> dict:
    """Run the Monte Carlo nodes and return the table: ``X`` ``(G, A, U, B, H)`` over :data:`EXIT_G`,
    :data:`EXIT_ALBEDO`, :data:`EXIT_MUS`, the exit-cosine bins and the harmonics, plus its metadata."""
    from tqdm.auto import tqdm

    from jaxsss.mc import Stack, simulate
    from jaxsss.render.bssrdf import exit_distribution

    edges = EXIT_MU_EDGES
    centres, width = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    x = np.zeros((len(EXIT_G), len(EXIT_ALBEDO), len(EXIT_MUS), len(centres), EXIT_HARMONICS))
    totals = np.zeros(x.shape[:3])
    t0 = time.perf_counter()
    nodes = [(i, j, k) for i in range(len(EXIT_G)) for j in range(len(EXIT_ALBEDO)) for k in range(len(EXIT_MUS))]
    for i, j, k in tqdm(nodes, desc="exit table", disable=not progress):
        g, a, mu = EXIT_G[i], EXIT_ALBEDO[j], EXIT_MUS[k]
        if g == 0.0:
            # Isotropic scattering: Chandrasekhar's exact X, no azimuthal dependence.
            x[i, j, k, :, 0] = np.asarray(exit_distribution(centres, np.array([mu]), np.array([a])))[:, 0, 0]
            continue
        res = simulate(Stack.half_space((1.0 - a) / a, 1.0 / (1.0 - g), g, 1.0), photons,
                       seed=seed + 1000 * i + 100 * j + k, angle_deg=math.degrees(math.acos(mu)),
                       exit_mu_edges=edges, exit_harmonics=EXIT_HARMONICS, progress=False)
        totals[i, j, k] = res.R_diffuse
        # X = (R_mu_phi[u, m] per bin) / (2 R mu_o d mu_o): radiance relative to a Lambertian exit of the total R.
        x[i, j, k] = res.R_mu_phi / (2.0 * res.R_diffuse * centres * width)[:, None]
        if mu == 1.0:
            x[i, j, k, :, 1:] = 0.0  # normal incidence: no azimuth to depend on
    return {"X": x, "R_diffuse": totals, "g": np.asarray(EXIT_G), "albedo": np.asarray(EXIT_ALBEDO),
            "mus": np.asarray(EXIT_MUS), "mu_edges": edges, "photons": photons, "seed": seed,
            "seconds": time.perf_counter() - t0,
            "source": "jaxsss.mc.simulate, index-matched half-space, sigma_s' = 1/mm, exit_mu_edges tally; "
                      "g = 0: Chandrasekhar's X (jaxsss.render.bssrdf.exit_distribution)"}


@functools.lru_cache(maxsize=1)
def load_exit_table() -> dict:
    """The shipped table (:data:`EXIT_TABLE`) as NumPy arrays (cached)."""
    with np.load(EXIT_TABLE) as f:
        return {k: f[k] for k in f.files}


def _hat(x, nodes):
    """``(..., N)`` linear-interpolation weights of ``x`` over the ascending ``nodes`` (held beyond the ends):
    :func:`jaxsss.render.bssrdf.hat_weights`, which takes descending nodes, over the reversed ones."""
    from jaxsss.render.bssrdf import hat_weights  # bssrdf imports this module

    return hat_weights(x, np.asarray(nodes)[::-1])[..., ::-1]


def anisotropic_exit_distribution(mu_o, harmonics, mu_i, albedo, g):
    """``X(mu_o, phi | mu_i)`` of a forward-scattering half-space (module docstring), relative to a Lambertian exit.

    Args:
        mu_o: ``(Q,)`` exit (view) cosines.
        harmonics: ``(Q, EXIT_HARMONICS - 1)`` the light's azimuth at each point, ``cos(m phi)`` for ``m >= 1``
            (:func:`azimuth_harmonics`; zeros: the azimuth average).
        mu_i: ``(K,)`` incidence cosines, each one of :data:`EXIT_MUS` (static).
        albedo: ``(C,)`` similarity albedo ``sigma_s' / (sigma_a + sigma_s')``.
        g: the anisotropy, a scalar in ``[0, 0.95]`` (held at the last node beyond).

    Returns:
        ``(Q, K, C)``, ``>= 0``; ``int_0^1 int X 2 mu_o dmu_o dphi / (2 pi) = 1`` (the harmonics integrate to zero
        over ``phi``), to within the floor at 0 where the truncated series rings negative (grazing incidence and
        exit behind a narrow forward peak).
    """
    tab = load_exit_table()
    idx = []
    for m in np.atleast_1d(np.asarray(mu_i, dtype=float)):
        hit = np.flatnonzero(np.isclose(tab["mus"], m))
        if hit.size != 1:
            raise ValueError(f"anisotropic_exit_distribution(mu_i={m:g}) is not a node of the exit table "
                             f"{tuple(float(v) for v in tab['mus'])}")
        idx.append(int(hit[0]))
    x = jnp.asarray(tab["X"][:, :, idx])  # (G, A, K, U, H)
    # Linear in g, then in alpha' per channel: (K, C, U, H).
    x = jnp.einsum("g,gakuh->akuh", _hat(jnp.asarray(g, dtype=x.dtype), tab["g"]), x)
    x = jnp.einsum("ca,akuh->kcuh", _hat(jnp.asarray(albedo), tab["albedo"]), x)
    edges = tab["mu_edges"]
    centres = 0.5 * (edges[1:] + edges[:-1])
    w_mu = _hat(jnp.clip(mu_o, 0.0, 1.0), centres)  # (Q, U)
    x = jnp.einsum("qu,kcuh->qkch", w_mu, x)
    # X_0 + 2 sum_m X_m cos(m phi), floored at 0: nine harmonics ring below zero behind a narrow forward peak (grazing
    # incidence and exit, g >= 0.7: down to -0.36 X_0 at g = 0.9, alpha' 0.995, and below -X_0 at g = 0.95, alpha' 0.1),
    # where the radiance is about 0. Unfloored, such points rendered negative (docs/path_tracer.md, stop 56).
    return jnp.maximum(x[..., 0] + 2.0 * jnp.einsum("qkch,qh->qkc", x[..., 1:], harmonics), 0.0)


def azimuth_harmonics(lights, points, normals, to_eye, n: int = EXIT_HARMONICS - 1) -> np.ndarray:
    """``(Q, n)``: the light-weighted ``cos(m phi)``, ``m = 1 .. n``, between the light's direction of travel and the
    view, both projected on each point's tangent plane (NumPy; module docstring for the weights).

    Args:
        lights: the scene's lights.
        points, normals, to_eye: ``(Q, 3)`` shaded points (mm), unit outward normals and unit directions to the eye.
    """
    from jaxsss.render.lights import EXTENDED_KINDS, _extended, _one_light, light_channels

    points, normals, to_eye = (np.asarray(a, dtype=np.float64) for a in (points, normals, to_eye))
    out = np.zeros((len(points), n))
    total = np.zeros(len(points))
    if not len(points):
        return out
    view = to_eye - np.einsum("qj,qj->q", to_eye, normals)[:, None] * normals
    view_len = np.linalg.norm(view, axis=1)
    for light in lights:
        if light.kind in EXTENDED_KINDS:
            # Spread in azimuth: weight only.
            _, irr, _ = _extended(light, points, normals, None, 0, light_channels(lights))
            total += irr.sum(axis=1).mean(axis=-1)
            continue
        to_light, _, factor = _one_light(light, points)
        w = np.asarray(factor).mean(axis=-1)
        travel = -to_light
        tang = travel - np.einsum("qj,qj->q", travel, normals)[:, None] * normals
        tang_len = np.linalg.norm(tang, axis=1)
        ok = (tang_len > 1e-9) & (view_len > 1e-9)
        c = np.where(ok, np.einsum("qj,qj->q", tang, view) / np.maximum(tang_len * view_len, 1e-300), 0.0)
        c = np.clip(c, -1.0, 1.0)
        # cos(m phi) by the Chebyshev recurrence; no azimuth (normal incidence or view) adds none.
        prev, cur = np.ones_like(c), c
        for m in range(n):
            out[:, m] += np.where(ok, w * cur, 0.0)
            prev, cur = cur, 2.0 * c * cur - prev
        total += w
    return np.where(total[:, None] > 0, out / np.where(total > 0, total, 1.0)[:, None], 0.0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m jaxsss.render.exit_direction",
                                description="The exit-direction table of forward-scattering half-spaces "
                                            "(jaxsss.render.exit_direction).")
    p.add_argument("--regenerate", action="store_true", help="run the Monte Carlo nodes and write the table")
    p.add_argument("--photons", type=int, default=EXIT_PHOTONS, help=f"photons per node (default {EXIT_PHOTONS})")
    args = p.parse_args(argv)
    if not args.regenerate:
        tab = load_exit_table()
        print(f"{EXIT_TABLE}: X {tab['X'].shape} (g, albedo, mu_i, mu_o bin, harmonic); {int(tab['photons'])} "
              f"photons per node, {float(tab['seconds']):.0f} s")
        return 0
    from jaxsss.mc import use_cpu_devices

    use_cpu_devices()
    tab = generate_exit_table(args.photons)
    EXIT_TABLE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(EXIT_TABLE, **{k: np.asarray(v) for k, v in tab.items()})
    print(f"wrote {EXIT_TABLE} in {tab['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
