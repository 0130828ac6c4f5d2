"""The jitted photon-transport kernel: one batch of photon packets advanced in lock-step lanes.

The physics is MCML's (Wang, Jacques and Zheng 1995, "MCML -- Monte Carlo modeling of light transport in
multi-layered tissues", Comput. Methods Programs Biomed. 47:131); the comments name the section of the MCML manual.

Lanes and regeneration. ``lanes`` photons are advanced together inside one ``lax.while_loop``; each iteration moves
every live lane by one *event* (a hop to the next interaction site, or a hop to the next interface). When a lane's
photon dies (it leaves the stack, loses the roulette, or hits the step cap) a new photon is launched in that lane at
the next iteration, until the batch's budget of photons has been launched; the loop ends when every launched photon
is dead. Long random walks at high albedo therefore do not leave lanes idle, except in the batch's final tail.

Random numbers. Each lane carries its own 64-bit SplitMix64 state (Steele, Lea and Flood 2014), seeded from
``jax.random.bits`` of the batch key; four 53-bit uniforms are drawn per event. A counter-based generator in the loop
carry costs a few integer operations per number, against ~20 rounds of Threefry for ``jax.random`` (measured: the
engine ran ~2x slower with ``jax.random.split`` per step). Lane streams start at independent random points of the
2^64 cycle; overlaps need ~2^64 / (lanes x draws) -- never in practice.

Radial splitting (``cfg.split_pool > 0``; a variance reduction for the far field) is a weight window in the
exit-plane radius ``r = sqrt(x^2 + y^2)``: the target weight is ``W(r) = exp(-(clip(r, r_0, r_1) - r_0) / lambda)``
(``r_0, r_1, 1 / lambda`` in ``params["window"]``). A live photon heavier than ``2 W(r)`` becomes ``m = min(floor(w /
W), 16)`` copies of weight ``w / m``: it continues as one, and the other ``m - 1`` go to a pool shared by all lanes
(no split when the pool is full). Dead lanes take waiting copies from the pool before new photons, so the work of
a copious history spreads over the lanes (a per-lane stack, tried first, left one lane working through a deep split
tree while the batch waited: ~200x slower per event than a plain run; with the pool, ~2.2x). Russian roulette acts below ``weight_threshold * W(r)``, so it does not undo the
splitting. Splitting conserves weight exactly, hence the expectation of every tally; copies of one history are
correlated, so :func:`jaxsss.mc.simulate` forms standard errors from independent batches instead of per-photon
moments.

Tallies are scatter-adds (``.at[index].add(..., mode="drop")``; lanes that do not contribute get an index one past
the end, which is dropped). They are deferred by one iteration (:func:`_tally`): each event stores its outcome in
the lane (an exit class, roulette or step-cap death, the weight absorbed), and the next iteration, or the end of the
loop, adds it up from the carried values. This halves the time per event on CPU: tallied in place, XLA fused the
event's whole computation into every reduction and recomputed it there. Every per-photon tally also accumulates the square of the photon's contribution, so the
host can form standard errors from per-photon second moments (each photon exits at most once, so the sum of squares
of the exit weights *is* the sum of squared per-photon contributions; absorption is accumulated per photon in the
lane and squared when the photon dies).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.fresnel import fresnel_cosines, snell_cosine

__all__ = ["KernelConfig", "batch_kernel", "new_tallies"]

_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB
N_ORDER = 3  # scattering-order classes: 0 (unscattered), 1 (single), >= 2 (multiple)


class KernelConfig(NamedTuple):
    """Everything that changes the compiled program (static); values (coefficients, edges, angle) are not here."""

    num_layers: int
    n_r: int  # radial bins (0: no profile)
    n_x: int  # x bins of the exit histogram (0: none)
    n_y: int
    n_path: int  # pathlength bins of R(r, L) (0: none; needs n_r > 0)
    lanes: int
    max_steps: int  # events per photon before it is killed and counted as a step-cap hit
    weight_threshold: float  # Russian roulette below this weight
    roulette_chance: float  # survival probability; survivors' weight is divided by it
    split_pool: int = 0  # radial splitting: rows of the shared pool of waiting copies (0: off); see params["window"]
    n_mu: int = 0  # exit-cosine bins of the reflected light's direction tally (0: none); see params["mu_edges"]
    n_harm: int = 0  # azimuthal harmonics cos(m phi), m = 0 .. n_harm - 1, per exit-cosine bin


def _uniform(s):
    """SplitMix64: advance the per-lane state ``s`` (uint64) and return ``(s, u)``, ``u`` uniform in [0, 1)."""
    s = s + jnp.uint64(_GOLDEN)
    z = s
    z = (z ^ (z >> jnp.uint64(30))) * jnp.uint64(_MIX1)
    z = (z ^ (z >> jnp.uint64(27))) * jnp.uint64(_MIX2)
    z = z ^ (z >> jnp.uint64(31))
    return s, (z >> jnp.uint64(11)).astype(jnp.float64) * (2.0**-53)


def _bin(edges, v):
    """Bin index of ``v`` in sorted ``edges`` (``len(edges) - 1`` bins) and whether it falls inside them."""
    # Comparing against every edge vectorises, but its (lanes, edges) intermediate grows with both: at 4096 lanes
    # the binary search (``scan``) was as fast at 41 edges and 2-4x faster at 112 (radii) and 242 (pathlengths;
    # the R(r, L) histogram of the white tables ran 4.3x slower than a plain run with compare_all, 0.8x with scan).
    method = "compare_all" if edges.shape[0] <= 64 else "scan"
    i = jnp.searchsorted(edges, v, side="right", method=method).astype(jnp.int32) - 1
    inside = (v >= edges[0]) & (v < edges[-1])
    return i, inside


def new_tallies(cfg: KernelConfig) -> dict:
    """Zeroed tallies. ``[..., 0]`` holds sums of weights, ``[..., 1]`` sums of squared weights, per photon."""
    f = jnp.float64
    t = {
        # (R or T, order class, moment)
        "exit": jnp.zeros((2, N_ORDER, 2), f),
        "absorbed": jnp.zeros((cfg.num_layers,), f),
        "absorbed_sq": jnp.zeros((), f),
        "roulette": jnp.zeros((), f),  # weight removed by roulette minus weight added to survivors
        "cap_hits": jnp.zeros((), jnp.int64),
        "cap_weight": jnp.zeros((), f),
        "events": jnp.zeros((), jnp.int64),  # lane events of live photons (interactions + boundary hits)
        "iterations": jnp.zeros((), jnp.int64),
        # Mean exit radius of the diffuse reflectance (ratio estimator): sum w r, sum (w r)^2, sum w^2 r.
        "exit_radius": jnp.zeros((3,), f),
    }
    if cfg.n_r:
        t["profile"] = jnp.zeros((2 * N_ORDER * cfg.n_r, 2), f)  # flat (R/T, order, r bin), moment
    if cfg.n_x:
        t["xy"] = jnp.zeros((N_ORDER * cfg.n_x * cfg.n_y, 2), f)  # flat (order, x bin, y bin), moment
    if cfg.n_path:
        t["r_path"] = jnp.zeros((cfg.n_r * cfg.n_path, 2), f)
    if cfg.n_mu:
        t["exit_dir"] = jnp.zeros((cfg.n_mu * cfg.n_harm, 2), f)  # flat (mu_o bin, harmonic), moment
    return t


def _fresnel(cos_i, rel, xp=jnp):
    """Unpolarised Fresnel reflectance and refraction cosine for incidence cosine ``cos_i`` onto relative index
    ``rel = n_t / n_i`` (total internal reflection gives ``R = 1``), from the physics core's Snell's law and Fresnel
    equations (:mod:`jaxsss.fresnel`), with the walk's exact cases: a matched interface passes straight through and
    grazing incidence reflects. ``xp``: the array namespace."""
    cos_t, ok = snell_cosine(cos_i, rel, xp=xp)
    cos_t = xp.where(rel == 1.0, cos_i, cos_t)  # exact pass-through at matched interfaces
    F = xp.where(rel == 1.0, 0.0, fresnel_cosines(cos_i, cos_t, rel))
    F = xp.where(cos_i <= 0.0, 1.0, F)  # grazing: nothing crosses (and no 0/0)
    return xp.where(ok, F, 1.0), cos_t


def _interface(ux, uy, uz, layer, hit, alive, n_ext, L: int, u_a):
    """A walk's step at the boundary its hop hit (``hit``): all-or-none Fresnel reflection with probability
    ``R(theta_i)`` (MCML manual 3.7.1, uniform ``u_a``), else crossing with Snell's law. ``n_ext``: the indices
    ``(n_above, n_1 ... n_L, n_below)``. Returns ``(next layer index, exit_top, exit_bot, inner crossing, direction
    after the boundary (ux, uy, uz))``; lanes that did not hit keep their direction."""
    up = uz < 0.0
    nl = layer + jnp.where(up, -1, 1).astype(jnp.int32)
    rel = n_ext[nl + 1] / n_ext[layer + 1]
    F, cos_t = _fresnel(jnp.abs(uz), rel)
    reflect = hit & (u_a < F)
    cross = hit & ~reflect
    exit_top = alive & cross & (nl < 0)
    exit_bot = alive & cross & (nl >= L)
    inner = cross & (nl >= 0) & (nl < L)
    # Snell's law for the transmitted direction.
    ux_b = jnp.where(cross, ux / rel, ux)
    uy_b = jnp.where(cross, uy / rel, uy)
    uz_b = jnp.where(reflect, -uz, jnp.where(cross, jnp.where(up, -cos_t, cos_t), uz))
    return nl, exit_top, exit_bot, inner, (ux_b, uy_b, uz_b)


def _hg_cos(g, u):
    """Henyey-Greenstein deflection cosine by exact inversion (MCML manual Eq. 3.28); isotropic for ``g = 0``."""
    gs = jnp.where(g == 0.0, 0.5, g)
    tmp = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    cos_hg = (1.0 + gs * gs - tmp * tmp) / (2.0 * gs)
    return jnp.clip(jnp.where(g == 0.0, 2.0 * u - 1.0, cos_hg), -1.0, 1.0)


# Taylor coefficients of sin and cos (through a^17 and a^16): on |a| <= pi/4 the truncation error is below 1e-17.
_SIN_C = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(9))
_COS_C = tuple((-1) ** k / math.factorial(2 * k) for k in range(9))


def _cos_sin_2pi(u):
    """``(cos 2 pi u, sin 2 pi u)`` for ``u`` in [0, 1), to float64 rounding.

    XLA's float64 ``sin``/``cos`` on CPU are scalar library calls (~20 ns each per lane, measured; more than the rest
    of an event). Quadrant reduction ``2 pi u = k pi/2 + a``, ``|a| <= pi/4``, then polynomials in ``a``: exact
    arithmetic apart from rounding, and fully vectorised.
    """
    w = 4.0 * u
    k = jnp.round(w)
    a = (w - k) * (0.5 * math.pi)
    a2 = a * a
    s = _SIN_C[-1]
    for c in _SIN_C[-2::-1]:
        s = s * a2 + c
    s = s * a
    c_ = _COS_C[-1]
    for c in _COS_C[-2::-1]:
        c_ = c_ * a2 + c
    q = k.astype(jnp.int32) % 4
    cos_p = jnp.where(q == 0, c_, jnp.where(q == 1, -s, jnp.where(q == 2, -c_, s)))
    sin_p = jnp.where(q == 0, s, jnp.where(q == 1, c_, jnp.where(q == 2, -s, -c_)))
    return cos_p, sin_p


def _spin(ux, uy, uz, cos_t, u_phi):
    """New direction after deflection by ``theta`` and azimuth ``phi = 2 pi u_phi`` from ``(ux, uy, uz)`` (MCML
    manual Eq. 3.30-3.31)."""
    sin_t = jnp.sqrt(jnp.maximum(1.0 - cos_t * cos_t, 0.0))
    cos_p, sin_p = _cos_sin_2pi(u_phi)
    near_pole = jnp.abs(uz) > 1.0 - 1e-12
    tmp = jnp.sqrt(jnp.maximum(1.0 - uz * uz, 1e-300))
    nx = sin_t * (ux * uz * cos_p - uy * sin_p) / tmp + ux * cos_t
    ny = sin_t * (uy * uz * cos_p + ux * sin_p) / tmp + uy * cos_t
    nz = -sin_t * cos_p * tmp + uz * cos_t
    px = sin_t * cos_p
    py = sin_t * sin_p
    pz = jnp.sign(uz) * cos_t
    return jnp.where(near_pole, px, nx), jnp.where(near_pole, py, ny), jnp.where(near_pole, pz, nz)


_SPLIT_F = ("x", "y", "z", "ux", "uy", "uz", "w", "s", "path")  # the state a waiting copy keeps
_SPLIT_I = ("layer", "order", "steps")
MAX_COPIES = 16


def _window(params: dict, r):
    """Target weight of the radial weight window, ``exp(-(clip(r, r_0, r_1) - r_0) / lambda)``."""
    r0, r1, inv_len = params["window"][0], params["window"][1], params["window"][2]
    return jnp.exp(-(jnp.clip(r, r0, r1) - r0) * inv_len)


def _split(cfg: KernelConfig, params: dict, old: dict, new: dict, r):
    """Radial splitting after an event (see the module docstring): a live photon heavier than twice the window's
    target keeps ``1 / m`` of its weight and writes ``m - 1`` copies to the shared pool, if they fit."""
    P = cfg.split_pool
    n = old["pool_n"]
    target = _window(params, r)
    m_f = jnp.clip(jnp.floor(new["w"] / target), 2.0, float(MAX_COPIES))
    m = m_f.astype(jnp.int32)
    want = new["alive"] & (new["w"] > 2.0 * target)
    end = n + jnp.cumsum(jnp.where(want, m - 1, 0)).astype(jnp.int32)  # each lane's copies end here (exclusive)
    split = want & (end <= P)
    w = jnp.where(split, new["w"] / m_f, new["w"])
    out = dict(new, w=w)
    vals_f = jnp.stack([out[k] for k in _SPLIT_F], axis=-1)
    vals_i = jnp.stack([out[k] for k in _SPLIT_I], axis=-1)
    # Row j < m - 1 of lane i goes to pool[end_i - (m_i - 1) + j]; the rest are dropped (index P).
    j = jnp.arange(MAX_COPIES - 1, dtype=jnp.int32)[None, :]
    rows = jnp.where(split[:, None] & (j < (m - 1)[:, None]), (end - (m - 1))[:, None] + j, P)
    rows = rows.reshape(-1)
    rep = MAX_COPIES - 1
    out["pool_f"] = old["pool_f"].at[rows].set(jnp.repeat(vals_f, rep, axis=0), mode="drop")
    out["pool_i"] = old["pool_i"].at[rows].set(jnp.repeat(vals_i, rep, axis=0), mode="drop")
    # Lanes are in order, so the accepted copies fill [n, n + sum) without gaps (a refused lane ends the run).
    out["pool_n"] = n + jnp.sum(jnp.where(split, m - 1, 0)).astype(jnp.int32)
    return out


def _take_copies(st: dict, dead):
    """Dead lanes take waiting copies from the top of the pool (before any new photon); returns the state and the
    lanes still dead."""
    n = st["pool_n"]
    rank = jnp.cumsum(dead.astype(jnp.int32)).astype(jnp.int32)  # 1, 2, ... over the dead lanes
    take = dead & (rank <= n)
    row = jnp.clip(n - rank, 0, st["pool_f"].shape[0] - 1)
    top_f, top_i = st["pool_f"][row], st["pool_i"][row]
    st = dict(st)
    for j, k in enumerate(_SPLIT_F):
        st[k] = jnp.where(take, top_f[:, j], st[k])
    for j, k in enumerate(_SPLIT_I):
        st[k] = jnp.where(take, top_i[:, j], st[k])
    st["pool_n"] = n - jnp.sum(take.astype(jnp.int32)).astype(jnp.int32)
    return st, dead & ~take


CODE_NONE = 2 * N_ORDER  # no exit and no death at the last event (codes 0 .. 2 N_ORDER - 1 are exits)
CODE_ROULETTE = 2 * N_ORDER + 1
CODE_CAP = 2 * N_ORDER + 2


def _tally(cfg: KernelConfig, params: dict, tal: dict, st: dict) -> dict:
    """Add the outcome of each lane's last event (``st["code"]``, ``st["dw"]``, ``st["d_roulette"]`` and the
    position, weight and pathlength it left in ``st``) to the tallies.

    Deferred by one iteration on purpose: the loop body's outputs are materialised in the carry, so these reductions
    read stored lane values. Tallying inside the event, XLA's CPU fusion copied the event's whole computation (random
    numbers, Fresnel, spin) into every reduction and into the ``(lanes, 6)`` one-hot of the exit classes, which cost
    ~40% of the run time (docs/benchmarks.md, "Monte Carlo throughput").
    """
    L = cfg.num_layers
    f64 = jnp.float64
    code, w, x, y, dw = st["code"], st["w"], st["x"], st["y"], st["dw"]
    exited = code < 2 * N_ORDER
    exit_top = code < N_ORDER
    died = exited | (code == CODE_ROULETTE) | (code == CODE_CAP)
    capped = code == CODE_CAP
    tal = dict(tal)
    w_exit = jnp.where(exited, w, 0.0)
    moments = jnp.stack([w_exit, w_exit * w_exit], axis=1)
    # Exits by (side, order class): a scatter-add into 6 rows (non-exits go to the dropped row 6).
    tal["exit"] = tal["exit"] + jnp.zeros((2 * N_ORDER, 2), f64).at[code].add(moments, mode="drop").reshape(
        2, N_ORDER, 2)
    if L == 1:
        tal["absorbed"] = tal["absorbed"] + jnp.sum(dw)
    else:
        tal["absorbed"] = tal["absorbed"] + jnp.zeros((L,), f64).at[st["layer"]].add(dw)
    tal["absorbed_sq"] = tal["absorbed_sq"] + jnp.sum(jnp.where(died, st["absorbed"] * st["absorbed"], 0.0))
    tal["roulette"] = tal["roulette"] + jnp.sum(st["d_roulette"])
    tal["cap_hits"] = tal["cap_hits"] + jnp.sum(capped.astype(jnp.int64))
    tal["cap_weight"] = tal["cap_weight"] + jnp.sum(jnp.where(capped, w, 0.0))
    r = jnp.sqrt(x * x + y * y)
    wr = jnp.where(exit_top, w * r, 0.0)
    tal["exit_radius"] = tal["exit_radius"] + jnp.stack(
        [jnp.sum(wr), jnp.sum(wr * wr), jnp.sum(jnp.where(exit_top, w * w * r, 0.0))])
    if cfg.n_r:
        ir, in_r = _bin(params["r_edges"], r)
        # code = side * N_ORDER + order class for exits
        idx = jnp.where(exited & in_r, code * cfg.n_r + ir, 2 * N_ORDER * cfg.n_r)
        tal["profile"] = tal["profile"].at[idx].add(moments, mode="drop")
        if cfg.n_path:
            ip, in_p = _bin(params["path_edges"], st["path"])
            idx = jnp.where(exit_top & in_r & in_p, ir * cfg.n_path + ip, cfg.n_r * cfg.n_path)
            tal["r_path"] = tal["r_path"].at[idx].add(moments, mode="drop")
    if cfg.n_x:
        ix, in_x = _bin(params["x_edges"], x)
        iy, in_y = _bin(params["y_edges"], y)
        # Split by scattering order like the radial profile (photon-diffusion tests need the multiple part).
        n_xy = cfg.n_x * cfg.n_y
        idx = jnp.where(exit_top & in_x & in_y, code * n_xy + ix * cfg.n_y + iy, N_ORDER * n_xy)
        tal["xy"] = tal["xy"].at[idx].add(moments, mode="drop")
    if cfg.n_mu:
        # Direction of the reflected light: exit cosine mu_o = -u_z and azimuth phi from the beam's plane (+x).
        ux, uy = st["ux"], st["uy"]
        mu_o = -st["uz"]
        cos_phi = ux / jnp.sqrt(jnp.maximum(ux * ux + uy * uy, 1e-300))
        im, in_mu = _bin(params["mu_edges"], mu_o)
        # cos(m phi) by the Chebyshev recurrence T_m+1 = 2 c T_m - T_m-1 (no trigonometric calls).
        harm = [jnp.ones_like(cos_phi), cos_phi]
        while len(harm) < cfg.n_harm:
            harm.append(2.0 * cos_phi * harm[-1] - harm[-2])
        h = jnp.stack(harm[:cfg.n_harm], axis=1)  # (lanes, n_harm)
        wh = jnp.where(exit_top, w, 0.0)[:, None] * h
        m = jnp.arange(cfg.n_harm, dtype=jnp.int32)[None, :]
        idx = jnp.where((exit_top & in_mu)[:, None], im[:, None] * cfg.n_harm + m, cfg.n_mu * cfg.n_harm)
        tal["exit_dir"] = tal["exit_dir"].at[idx.reshape(-1)].add(
            jnp.stack([wh, wh * wh], axis=-1).reshape(-1, 2), mode="drop")
    return tal


def batch_kernel(cfg: KernelConfig, params: dict, key, budget):
    """Run one batch of ``budget`` photons; return the batch's tallies (see :func:`new_tallies`).

    ``params`` (all float64 arrays): ``sigma_a, sigma_s, g`` of shape ``(L,)``; ``n_ext = [n_above, n_1..n_L,
    n_below]``; ``z_edges`` ``(L + 1,)`` (last may be inf); ``r_edges``, ``x_edges``, ``y_edges``, ``path_edges``
    (bin edges, used when the matching ``cfg`` size is non-zero); ``mu_edges`` (exit cosines of the direction tally,
    when ``cfg.n_mu``); ``entry`` = ``(ux0, uz0, w0)``, the refracted
    direction and the weight that enters (1 - specular). ``budget`` is an int64 scalar (dynamic: the last, partial
    batch reuses the compiled program).
    """
    L = cfg.num_layers
    lanes = cfg.lanes
    f64 = jnp.float64
    sigma_a, sigma_s, g_layer = params["sigma_a"], params["sigma_s"], params["g"]
    sigma_t = sigma_a + sigma_s
    n_ext, z_edges = params["n_ext"], params["z_edges"]
    ux0, uz0, w0 = params["entry"][0], params["entry"][1], params["entry"][2]
    budget = jnp.asarray(budget, jnp.int64)

    zeros = jnp.zeros((lanes,), f64)
    izeros = jnp.zeros((lanes,), jnp.int32)
    state = {
        "x": zeros, "y": zeros, "z": zeros, "ux": zeros, "uy": zeros, "uz": zeros + 1.0,
        "w": zeros, "s": zeros, "path": zeros, "absorbed": zeros,
        "layer": izeros, "order": izeros, "steps": izeros,
        "alive": jnp.zeros((lanes,), bool),
        "rng": jax.random.bits(key, (lanes,), jnp.uint64),
        # The last event's outcome, tallied at the start of the next iteration (see _tally): CODE_NONE, an exit
        # class side * N_ORDER + order class, CODE_ROULETTE or CODE_CAP; and the weight absorbed / removed by roulette.
        "code": jnp.full((lanes,), CODE_NONE, jnp.int32), "dw": zeros, "d_roulette": zeros,
    }
    if cfg.split_pool:
        # Shared pool of waiting copies (float and int fields); rows [0, pool_n) are in use.
        state["pool_n"] = jnp.zeros((), jnp.int32)
        state["pool_f"] = jnp.zeros((cfg.split_pool, len(_SPLIT_F)), f64)
        state["pool_i"] = jnp.zeros((cfg.split_pool, len(_SPLIT_I)), jnp.int32)

    def cond(carry):
        st, _, launched = carry
        waiting = st["pool_n"] > 0 if cfg.split_pool else False
        return jnp.any(st["alive"]) | (launched < budget) | waiting

    def body(carry):
        st, tal, launched = carry
        tal = _tally(cfg, params, tal, st)
        st = dict(st)
        # --- Photon regeneration: dead lanes take new photons while the budget lasts (MCML manual 3.2: launch).
        dead = ~st["alive"]
        if cfg.split_pool:  # waiting copies first (see _take_copies)
            st, dead = _take_copies(st, dead)
        rank = jnp.cumsum(dead.astype(jnp.int64))
        launch = dead & (rank <= budget - launched)
        launched = launched + jnp.sum(launch.astype(jnp.int64))
        start = {"x": 0.0, "y": 0.0, "z": 0.0, "ux": ux0, "uy": 0.0, "uz": uz0, "w": w0, "s": 0.0, "path": 0.0,
                 "absorbed": 0.0}
        for k, v in start.items():
            st[k] = jnp.where(launch, v, st[k])
        for k in ("layer", "order", "steps"):
            st[k] = jnp.where(launch, 0, st[k])
        alive = ~dead | launch

        rng = st["rng"]
        rng, u_step = _uniform(rng)
        rng, u_a = _uniform(rng)
        rng, u_b = _uniform(rng)
        rng, u_c = _uniform(rng)

        layer = st["layer"]
        x, y, z, ux, uy, uz, w = st["x"], st["y"], st["z"], st["ux"], st["uy"], st["uz"], st["w"]
        mu_t = sigma_t[layer]
        # --- Step size: a fresh dimensionless step -ln(xi) when the last one is used up (MCML manual 3.3).
        s = jnp.where(st["s"] <= 0.0, -jnp.log1p(-u_step), st["s"])
        z_top, z_bot = z_edges[layer], z_edges[layer + 1]
        d_b = jnp.where(uz > 0.0, (z_bot - z) / jnp.where(uz > 0.0, uz, 1.0),
                        jnp.where(uz < 0.0, (z_top - z) / jnp.where(uz < 0.0, uz, -1.0), jnp.inf))
        s_geo = jnp.where(mu_t > 0.0, s / jnp.where(mu_t > 0.0, mu_t, 1.0), jnp.inf)
        hit = d_b <= s_geo
        # --- Hop (MCML manual 3.4); at an interface the remaining dimensionless step carries over (3.7).
        dist = jnp.where(hit, d_b, s_geo)
        x = x + dist * ux
        y = y + dist * uy
        z = jnp.where(hit, jnp.where(uz > 0.0, z_bot, z_top), z + dist * uz)
        path = st["path"] + dist
        s = jnp.where(hit, jnp.maximum(s - d_b * mu_t, 0.0), 0.0)

        # --- Interface: reflect with probability R(theta_i) (all-or-none, MCML manual 3.7.1), else cross.
        nl, exit_top, exit_bot, inner, (ux_b, uy_b, uz_b) = _interface(ux, uy, uz, layer, hit, alive, n_ext, L, u_a)

        # --- Interaction: absorb by weight (implicit capture, MCML manual 3.5), then scatter (3.6).
        interact = alive & ~hit
        frac_abs = jnp.where(mu_t > 0.0, sigma_a[layer] / jnp.where(mu_t > 0.0, mu_t, 1.0), 0.0)
        dw = jnp.where(interact, w * frac_abs, 0.0)
        w = w - dw
        absorbed = st["absorbed"] + dw
        cos_s = _hg_cos(g_layer[layer], u_a)
        sx, sy, sz = _spin(ux, uy, uz, cos_s, u_b)
        ux = jnp.where(interact, sx, ux_b)
        uy = jnp.where(interact, sy, uy_b)
        uz = jnp.where(interact, sz, uz_b)
        order = st["order"] + interact.astype(jnp.int32)
        # Russian roulette below the weight threshold (MCML manual 3.8); with splitting, relative to the window.
        threshold = cfg.weight_threshold
        if cfg.split_pool:
            threshold = threshold * _window(params, jnp.sqrt(x * x + y * y))
        low = interact & (w < threshold)
        w_new = jnp.where(low, jnp.where(u_c < cfg.roulette_chance, w / cfg.roulette_chance, 0.0), w)
        roulette_dead = low & (w_new == 0.0)
        w_before_roulette, w = w, w_new

        steps = st["steps"] + 1
        exited = exit_top | exit_bot
        capped = alive & ~exited & ~roulette_dead & (steps >= cfg.max_steps)
        died = alive & (exited | roulette_dead | capped)

        # --- Outcome of the event, tallied at the start of the next iteration (_tally).
        cls = jnp.minimum(order, N_ORDER - 1)
        code = jnp.where(exited, jnp.where(exit_top, 0, N_ORDER) + cls,
                         jnp.where(roulette_dead, CODE_ROULETTE, jnp.where(capped, CODE_CAP, CODE_NONE)))
        tal = dict(tal, events=tal["events"] + jnp.sum(alive.astype(jnp.int64)), iterations=tal["iterations"] + 1)

        new = {
            "x": x, "y": y, "z": z, "ux": ux, "uy": uy, "uz": uz, "w": w, "s": s, "path": path,
            "absorbed": absorbed, "layer": jnp.where(inner, nl, layer), "order": order, "steps": steps,
            "alive": alive & ~died, "rng": rng, "code": code.astype(jnp.int32), "dw": dw,
            "d_roulette": jnp.where(low, w_before_roulette - w, 0.0),
        }
        if cfg.split_pool:
            new = _split(cfg, params, st, new, jnp.sqrt(x * x + y * y))
        return new, tal, launched

    final, tallies, _ = lax.while_loop(cond, body, (state, new_tallies(cfg), jnp.zeros((), jnp.int64)))
    return _tally(cfg, params, tallies, final)  # the last iteration's outcomes
