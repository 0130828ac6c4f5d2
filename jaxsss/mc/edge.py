"""Monte Carlo transport in a quarter-space: the reference for diffusion at a right-angled edge (quadpole).

Geometry: the medium fills ``{x > 0, z > 0}`` (``z`` is depth below the *top* face ``z = 0``; ``x`` the distance
from the *side* face ``x = 0``); ``y`` runs along the edge. A collimated pencil beam hits the top face at
``(edge_distance, 0, 0)`` along ``+z`` (normal incidence). Both faces are smooth, index-mismatched boundaries with
the same outside index ``n_outside``; the medium has index ``n``.

Physics and conventions are those of :mod:`jaxsss.mc._kernel` (MCML; its helpers are reused): specular reflection
``F(n / n_outside, 1)`` removed deterministically, all-or-none Fresnel reflection at both faces, absorption by
weight, Henyey-Greenstein scattering, Russian roulette, a step cap, SplitMix64 lanes with regeneration. Exits are
tallied per face and per scattering order (0, 1, >= 2) as totals and as histograms: the top face over ``(x, y)``,
the side face over ``(z, y)``, per incident photon per mm^2. Every packet's weight ends in exactly one tally, so
``R_specular + R_top + R_side + A + roulette_balance + step_cap_weight = 1`` to rounding (tested).

One compiled program per (lanes, grid sizes, step cap, roulette settings); coefficients, indices, edges, the edge
distance and the photon budget are run-time values.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc._kernel import N_ORDER, _bin, _fresnel, _hg_cos, _spin, _uniform
from jaxsss.mc.result import stderr_of_mean

__all__ = ["EdgeResult", "simulate_edge"]


class _EdgeConfig(NamedTuple):
    lanes: int
    n_u: tuple  # bins along (top: x, side: z)
    n_y: tuple  # bins along y, per face
    max_steps: int
    weight_threshold: float
    roulette_chance: float


def _edge_kernel(cfg: _EdgeConfig, p: dict, key, budget):
    """One batch of ``budget`` photons; returns the batch's tallies (sums of weights and of squared weights)."""
    lanes, f64 = cfg.lanes, jnp.float64
    mu_a, mu_s, g = p["sigma_a"], p["sigma_s"], p["g"]
    mu_t = mu_a + mu_s
    rel = p["n_outside"] / p["n"]
    zeros = jnp.zeros((lanes,), f64)
    st = {"x": zeros, "y": zeros, "z": zeros, "ux": zeros, "uy": zeros, "uz": zeros + 1.0, "w": zeros,
          "s": zeros, "absorbed": zeros, "order": jnp.zeros((lanes,), jnp.int32),
          "steps": jnp.zeros((lanes,), jnp.int32), "alive": jnp.zeros((lanes,), bool),
          "rng": jax.random.bits(key, (lanes,), jnp.uint64)}
    n_hist = [cfg.n_u[k] * cfg.n_y[k] for k in range(2)]
    tal = {"exit": jnp.zeros((2, N_ORDER, 2), f64), "absorbed": jnp.zeros((2,), f64),
           "roulette": jnp.zeros((), f64), "cap": jnp.zeros((2,), f64),
           "hist0": jnp.zeros((N_ORDER * n_hist[0], 2), f64), "hist1": jnp.zeros((N_ORDER * n_hist[1], 2), f64)}

    def cond(carry):
        s, _, launched = carry
        return jnp.any(s["alive"]) | (launched < budget)

    def body(carry):
        s, t, launched = carry
        s, t = dict(s), dict(t)
        # Regeneration: dead lanes take new photons while the budget lasts (MCML manual 3.2).
        dead = ~s["alive"]
        launch = dead & (jnp.cumsum(dead.astype(jnp.int64)) <= budget - launched)
        launched = launched + jnp.sum(launch.astype(jnp.int64))
        start = {"x": p["edge_distance"], "y": 0.0, "z": 0.0, "ux": 0.0, "uy": 0.0, "uz": 1.0, "w": p["w0"],
                 "s": 0.0, "absorbed": 0.0}
        for k, v in start.items():
            s[k] = jnp.where(launch, v, s[k])
        for k in ("order", "steps"):
            s[k] = jnp.where(launch, 0, s[k])
        alive = s["alive"] | launch
        rng, u_step = _uniform(s["rng"])
        rng, u_a = _uniform(rng)
        rng, u_b = _uniform(rng)
        rng, u_c = _uniform(rng)
        x, y, z, ux, uy, uz, w = (s[k] for k in ("x", "y", "z", "ux", "uy", "uz", "w"))
        # Step (MCML 3.3): a fresh dimensionless step when the last one is used up.
        step = jnp.where(s["s"] <= 0.0, -jnp.log1p(-u_step), s["s"])
        # Distances to the two faces along the direction of flight.
        d_top = jnp.where(uz < 0.0, -z / jnp.where(uz < 0.0, uz, -1.0), jnp.inf)
        d_side = jnp.where(ux < 0.0, -x / jnp.where(ux < 0.0, ux, -1.0), jnp.inf)
        side = d_side < d_top
        d_b = jnp.minimum(d_top, d_side)
        s_geo = step / mu_t
        hit = d_b <= s_geo
        dist = jnp.where(hit, d_b, s_geo)
        x = jnp.where(hit & side, 0.0, x + dist * ux)
        z = jnp.where(hit & ~side, 0.0, z + dist * uz)
        y = y + dist * uy
        step = jnp.where(hit, jnp.maximum(step - d_b * mu_t, 0.0), 0.0)
        # Interface (MCML 3.7.1): reflect with probability F(theta_i), else leave the medium.
        cos_i = jnp.where(side, -ux, -uz)
        F, _ = _fresnel(cos_i, rel)
        reflect = hit & (u_a < F)
        exited = alive & hit & ~reflect
        ux_b = jnp.where(reflect & side, -ux, ux)
        uz_b = jnp.where(reflect & ~side, -uz, uz)
        # Interaction: absorb by weight (MCML 3.5), scatter (3.6).
        interact = alive & ~hit
        dw = jnp.where(interact, w * mu_a / mu_t, 0.0)
        w = w - dw
        absorbed = s["absorbed"] + dw
        sx, sy, sz = _spin(ux, uy, uz, _hg_cos(g, u_a), u_b)
        ux, uy, uz = (jnp.where(interact, a, b) for a, b in ((sx, ux_b), (sy, uy), (sz, uz_b)))
        order = s["order"] + interact.astype(jnp.int32)
        # Russian roulette (MCML 3.8).
        low = interact & (w < cfg.weight_threshold)
        w_new = jnp.where(low, jnp.where(u_c < cfg.roulette_chance, w / cfg.roulette_chance, 0.0), w)
        t["roulette"] = t["roulette"] + jnp.sum(jnp.where(low, w - w_new, 0.0))
        roulette_dead = low & (w_new == 0.0)
        w = w_new
        steps = s["steps"] + 1
        capped = alive & ~exited & ~roulette_dead & (steps >= cfg.max_steps)
        died = alive & (exited | roulette_dead | capped)

        # Tallies: per face and order, with squares (each photon exits at most once).
        cls = jnp.minimum(order, N_ORDER - 1)
        face = side.astype(jnp.int32)
        w_exit = jnp.where(exited, w, 0.0)
        moments = jnp.stack([w_exit, w_exit * w_exit], axis=1)
        combo = jnp.where(exited, face * N_ORDER + cls, 2 * N_ORDER)
        t["exit"] = t["exit"].reshape(2 * N_ORDER, 2).at[combo].add(moments, mode="drop").reshape(2, N_ORDER, 2)
        a_done = jnp.where(died, absorbed, 0.0)
        t["absorbed"] = t["absorbed"] + jnp.stack([jnp.sum(a_done), jnp.sum(a_done * a_done)])
        t["cap"] = t["cap"] + jnp.stack([jnp.sum(jnp.where(capped, w, 0.0)), jnp.sum(capped.astype(f64))])
        for k, coord in ((0, x), (1, z)):
            iu, in_u = _bin(p[f"u_edges{k}"], coord)
            iy, in_y = _bin(p[f"y_edges{k}"], y)
            ok = exited & (face == k) & in_u & in_y
            idx = jnp.where(ok, cls * n_hist[k] + iu * cfg.n_y[k] + iy, N_ORDER * n_hist[k])
            t[f"hist{k}"] = t[f"hist{k}"].at[idx].add(moments, mode="drop")
        new = {"x": x, "y": y, "z": z, "ux": ux, "uy": uy, "uz": uz, "w": w, "s": step, "absorbed": absorbed,
               "order": order, "steps": steps, "alive": alive & ~died, "rng": rng}
        return new, t, launched

    _, tallies, _ = lax.while_loop(cond, body, (st, tal, jnp.zeros((), jnp.int64)))
    return tallies


_jitted = jax.jit(_edge_kernel, static_argnums=0)
_COMPILED: dict = {}  # one executable per configuration and argument shapes (runs reuse it)


@dataclasses.dataclass(frozen=True, eq=False)
class EdgeResult:
    """Tallies of :func:`simulate_edge`, per incident photon (NumPy float64).

    ``R_top``, ``R_side`` (+ ``_stderr``): light leaving each face; ``R_top_order``, ``R_side_order`` ``(3,)`` by
    scattering order 0, 1, >= 2 (+ ``_stderr``). ``top_hist`` ``(3, X, Y)`` over ``(top_x_edges, top_y_edges)`` and
    ``side_hist`` ``(3, Z, Y)`` over ``(side_z_edges, side_y_edges)``: exitance per mm^2 by order (+ ``_stderr``).
    ``A`` absorbed, ``roulette_balance``, ``step_cap_weight``, ``step_cap_hits``, ``R_specular``; metadata
    ``photons``, ``seconds``, ``compile_seconds``.
    """

    photons: int
    seconds: float
    compile_seconds: float
    R_specular: float
    R_top: float
    R_top_stderr: float
    R_side: float
    R_side_stderr: float
    R_top_order: np.ndarray
    R_top_order_stderr: np.ndarray
    R_side_order: np.ndarray
    R_side_order_stderr: np.ndarray
    A: float
    A_stderr: float
    roulette_balance: float
    step_cap_weight: float
    step_cap_hits: int
    top_x_edges: np.ndarray
    top_y_edges: np.ndarray
    side_z_edges: np.ndarray
    side_y_edges: np.ndarray
    top_hist: np.ndarray
    top_hist_stderr: np.ndarray
    side_hist: np.ndarray
    side_hist_stderr: np.ndarray

    @property
    def weight_balance(self) -> float:
        """``R_specular + R_top + R_side + A + roulette_balance + step_cap_weight``: 1 to rounding."""
        return self.R_specular + self.R_top + self.R_side + self.A + self.roulette_balance + self.step_cap_weight


def _grid(edges, name):
    arr = np.asarray(check_range(edges, name, None, None, owner="simulate_edge"), dtype=np.float64)
    if arr.ndim != 1 or arr.size < 2 or np.any(np.diff(arr) <= 0):
        raise ValueError(f"simulate_edge({name}=...): must be 1-D, strictly increasing, with at least 2 edges")
    return arr


def simulate_edge(sigma_a, sigma_s, g, n, photons: int, *, edge_distance, n_outside=1.0, top_edges, side_edges,
                  seed: int = 0, lanes: int = 1024, batch_size: int = 2**18, max_steps: int = 10**6,
                  weight_threshold: float = 1e-4, roulette_chance: float = 0.1) -> EdgeResult:
    """Monte Carlo transport of a normally incident pencil beam near a right-angled edge (quarter-space).

    Args:
        sigma_a, sigma_s: absorption and scattering coefficients, 1/mm (``>= 0``, ``sigma_a + sigma_s > 0``).
        g: Henyey-Greenstein anisotropy in ``(-1, 1)``.
        n: refractive index of the medium, ``> 0``; ``n_outside``: of the surroundings (both faces), ``> 0``.
        photons: incident photons, ``>= 1``.
        edge_distance: distance of the beam from the side face, mm, ``>= 0``.
        top_edges: ``(x_edges, y_edges)`` of the top-face histogram, mm.
        side_edges: ``(z_edges, y_edges)`` of the side-face histogram, mm.
        seed, lanes, batch_size, max_steps, weight_threshold, roulette_chance: as :func:`jaxsss.mc.simulate`.

    Returns:
        :class:`EdgeResult`.
    """
    owner = "simulate_edge"
    sigma_a = float(check_range(sigma_a, "sigma_a", 0.0, None, owner=owner))
    sigma_s = float(check_range(sigma_s, "sigma_s", 0.0, None, owner=owner))
    if sigma_a + sigma_s <= 0:
        raise ValueError(f"{owner}(sigma_a + sigma_s=0): the medium must absorb or scatter; allowed range (0, inf)")
    g = float(check_range(g, "g", -1.0, 1.0, lo_open=True, hi_open=True, owner=owner))
    n = float(check_range(n, "n", 0.0, None, lo_open=True, owner=owner))
    n_outside = float(check_range(n_outside, "n_outside", 0.0, None, lo_open=True, owner=owner))
    edge_distance = float(check_range(edge_distance, "edge_distance", 0.0, None, owner=owner))
    for name, v, lo in (("photons", photons, 1), ("lanes", lanes, 1), ("batch_size", batch_size, 1),
                        ("max_steps", max_steps, 1), ("seed", seed, 0)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{owner}({name}={v!r}) must be an integer in the allowed range [{lo}, inf)")
    weight_threshold = float(check_range(weight_threshold, "weight_threshold", 0.0, 1.0, lo_open=True, owner=owner))
    roulette_chance = float(check_range(roulette_chance, "roulette_chance", 0.0, 1.0, lo_open=True, owner=owner))
    grids = [[_grid(top_edges[0], "top_edges[0]"), _grid(top_edges[1], "top_edges[1]")],
             [_grid(side_edges[0], "side_edges[0]"), _grid(side_edges[1], "side_edges[1]")]]
    cfg = _EdgeConfig(lanes=int(lanes), n_u=(grids[0][0].size - 1, grids[1][0].size - 1),
                      n_y=(grids[0][1].size - 1, grids[1][1].size - 1), max_steps=int(max_steps),
                      weight_threshold=weight_threshold, roulette_chance=roulette_chance)
    R_sp = float(fresnel_reflectance(n / n_outside, 1.0))
    params = {"sigma_a": sigma_a, "sigma_s": sigma_s, "g": g, "n": n, "n_outside": n_outside,
              "edge_distance": edge_distance, "w0": 1.0 - R_sp,
              "u_edges0": grids[0][0], "y_edges0": grids[0][1], "u_edges1": grids[1][0], "y_edges1": grids[1][1]}
    params = {k: jnp.asarray(v, jnp.float64) for k, v in params.items()}
    root = jax.random.key(int(seed))
    t0 = time.perf_counter()
    sig = (cfg, tuple((k, v.shape) for k, v in sorted(params.items())))
    if sig not in _COMPILED:
        _COMPILED[sig] = _jitted.lower(cfg, params, root, jnp.asarray(batch_size, jnp.int64)).compile()
    fn = _COMPILED[sig]
    compile_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    tot: dict = {}
    for b in range(math.ceil(photons / batch_size)):
        budget = min(batch_size, photons - b * batch_size)
        out = fn(params, jax.random.fold_in(root, b), jnp.asarray(budget, jnp.int64))
        for k, v in out.items():
            tot[k] = np.asarray(v) + tot.get(k, 0.0)
    seconds = time.perf_counter() - t0
    N = int(photons)
    ex = tot["exit"]
    face_sum = ex.sum(axis=1)
    hists = []
    for k in range(2):
        h = tot[f"hist{k}"].reshape(N_ORDER, cfg.n_u[k], cfg.n_y[k], 2)
        cell = np.outer(np.diff(grids[k][0]), np.diff(grids[k][1]))
        hists.append((h[..., 0] / N / cell, stderr_of_mean(h[..., 0], h[..., 1], N) / cell))
    return EdgeResult(
        photons=N, seconds=seconds, compile_seconds=compile_seconds, R_specular=R_sp,
        R_top=float(face_sum[0, 0] / N), R_top_stderr=float(stderr_of_mean(face_sum[0, 0], face_sum[0, 1], N)),
        R_side=float(face_sum[1, 0] / N), R_side_stderr=float(stderr_of_mean(face_sum[1, 0], face_sum[1, 1], N)),
        R_top_order=ex[0, :, 0] / N, R_top_order_stderr=stderr_of_mean(ex[0, :, 0], ex[0, :, 1], N),
        R_side_order=ex[1, :, 0] / N, R_side_order_stderr=stderr_of_mean(ex[1, :, 0], ex[1, :, 1], N),
        A=float(tot["absorbed"][0] / N), A_stderr=float(stderr_of_mean(tot["absorbed"][0], tot["absorbed"][1], N)),
        roulette_balance=float(tot["roulette"] / N), step_cap_weight=float(tot["cap"][0] / N),
        step_cap_hits=round(float(tot["cap"][1])),
        top_x_edges=grids[0][0], top_y_edges=grids[0][1], side_z_edges=grids[1][0], side_y_edges=grids[1][1],
        top_hist=hists[0][0], top_hist_stderr=hists[0][1], side_hist=hists[1][0], side_hist_stderr=hists[1][1])
