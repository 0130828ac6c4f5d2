"""Perturbation ("replay") Monte Carlo for slabs and layered stacks: simulate once, reweight for any coefficients.

One run without absorption at reference scattering coefficients ``sigma_s0_i`` (per layer; the layers' ``g``, ``n``
and thicknesses and the ambient indices fixed) records, for every photon, where it ended (top face, bottom face, or
killed at the cap), its exit radius, and per layer ``i`` the path length ``L_i`` (mm) and the number of scattering
events ``k_i``. Because every other factor of a walk's probability density (Henyey-Greenstein deflections, Fresnel
decisions at the interfaces) depends on ``g`` and ``n`` only, the weight of the same walk in a medium with
``(sigma_a_i, sigma_s_i)`` is the likelihood ratio (Hayakawa et al. 2001, Opt. Lett. 26:1335, "Perturbation Monte
Carlo methods to solve inverse photon migration problems in heterogeneous tissues"; Sassaroli 2012 for layers)::

    w = w0 * prod_i (sigma_s_i / sigma_s0_i)^k_i * exp(-(sigma_s_i + sigma_a_i - sigma_s0_i) L_i)

with ``sigma_s_i = sigma_s'_i / (1 - g_i)`` (the MCML convention: ``g`` is the layer's anisotropy, ``sigma_s`` is not
reduced). ``exp(-sigma_a L)`` is the absorption weight of the walk (MCML's implicit capture gives the same
expectation); the rest is the ratio of the walk's densities. :func:`replay` evaluates this in JAX, so R(r), T(r), the
totals and their derivatives with respect to every layer's ``(sigma_a, sigma_s')`` come from one recorded sample.

Conventions (chosen to match MCML 1.2.2's files, so its ``Rd_r``, ``Tt_r``, ``Rd`` and ``Tt`` compare directly):

- A normal pencil beam at the origin. The specular reflection ``R_specular = F(n_1 / n_above, cos = 1)`` is removed
  deterministically: every photon enters with weight ``w0 = 1 - R_specular`` (MCML's ``Rsp``), and ``R`` excludes it.
- ``T`` includes the unscattered (ballistic) beam; it lands in the first radial bin (``r = 0``). It is also reported
  on its own (``T_unscattered``: photons with no scattering event at all that leave through the bottom), so data
  without the collimated beam compare with ``T - T_unscattered``. Unscattered photons that are reflected by the
  bottom face and leave through the top are part of ``R`` (as in MCML).
- All-or-none Fresnel reflection at every interface (MCML's default), as in :func:`jaxsss.mc.simulate`.
- Profiles per incident photon per mm^2 of the annulus ``[r_lo, r_hi)``.

The cap. Without absorption nothing ends a walk except leaving the stack, and in a half-space (or a thick slab) a
few walks are very long (the return-time distribution has a ``t^(-3/2)`` tail). A photon is killed when its path
reaches ``max_path`` mm or its events reach ``max_steps``; it is recorded with ``side = 2``. Its replayed weight at the
moment of the kill bounds what it could still have contributed, so :func:`replay` reports ``cap_bound``, an upper
bound on the reflectance plus transmittance lost to the cap at the replayed coefficients (``<= w0 exp(-sigma_a
max_path)`` per capped photon in a one-layer medium).

Effective sample size. The Kish ESS ``(sum w)^2 / sum w^2`` of the detected photons' replayed weights, and
``ess_fraction``: the ESS divided by the ESS of the same walks weighted by absorption alone (the scattering ratio set
to 1). At the reference point ``ess_fraction = 1``; it measures what the change of scattering costs, not what
absorption costs (a direct absorbing simulation pays that as well). The same ratio is reported per radial bin: it
matters more than the global one, because the log-weight's variance grows with the number of scattering events
(``~ k log^2(sigma_s / sigma_s0)``), so the far bins (photons with many events) degrade first while the near-source
photons keep the global ESS high. When a bin's ESS is small the weights are heavy-tailed and a typical sample
*underestimates* their mean: the replayed profile is then biased towards the reference's, not only noisy (measured in
``benchmarks/replay_fits.py``). Fits re-simulate when it falls below a threshold (:mod:`fitting.replay_fit`).

Speed. The recording walk is the engine's (:mod:`jaxsss.mc._kernel`): lock-step lanes in one ``lax.while_loop``
with regeneration, SplitMix64 per lane, the same Henyey-Greenstein, rotation and Fresnel helpers. With no absorption
it needs no roulette and no weight, so an event is cheaper; walks are longer.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float, Int

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_integer, check_range
from jaxsss.mc._kernel import _hg_cos, _interface, _spin, _uniform
from jaxsss.mc.engine import _auto_lanes, entry_state
from jaxsss.mc.stack import Stack

__all__ = ["ReplayEstimate", "ReplaySample", "record", "replay", "rebin"]

DEFAULT_MAX_STEPS = 10**5
DEFAULT_BATCH = 2**17
SIDE_R, SIDE_T, SIDE_CAP = 0, 1, 2


class _RecordConfig(NamedTuple):
    """Static settings of the compiled recording walk."""

    num_layers: int
    lanes: int
    rows: int  # photons per batch (the size of the per-photon output buffers)
    max_steps: int


def _record_kernel(cfg: _RecordConfig, params: dict, key, budget):
    """Walk ``budget`` (<= ``cfg.rows``) photons without absorption; return per-photon rows (see :func:`record`)."""
    L, lanes, B = cfg.num_layers, cfg.lanes, cfg.rows
    f64 = jnp.float64
    sigma_s, g_layer, n_ext, z_edges = params["sigma_s"], params["g"], params["n_ext"], params["z_edges"]
    max_path = params["max_path"]
    budget = jnp.asarray(budget, jnp.int64)
    layers = jnp.arange(L, dtype=jnp.int32)[None, :]
    zeros = jnp.zeros((lanes,), f64)
    izeros = jnp.zeros((lanes,), jnp.int32)
    state = {
        "x": zeros, "y": zeros, "z": zeros, "ux": zeros, "uy": zeros, "uz": zeros + 1.0, "s": zeros,
        "L": jnp.zeros((lanes, L), f64), "k": jnp.zeros((lanes, L), f64),
        "layer": izeros, "steps": izeros, "row": jnp.zeros((lanes,), jnp.int64),
        "alive": jnp.zeros((lanes,), bool), "rng": jax.random.bits(key, (lanes,), jnp.uint64),
    }
    out = {"side": jnp.full((B,), -1, jnp.int8), "radius": jnp.zeros((B,), f64),
           "L": jnp.zeros((B, L), f64), "k": jnp.zeros((B, L), f64), "events": jnp.zeros((), jnp.int64)}

    def cond(carry):
        st, _, launched = carry
        return jnp.any(st["alive"]) | (launched < budget)

    def body(carry):
        st, out, launched = carry
        st = dict(st)
        # --- Regeneration: dead lanes launch the next photons of the batch (MCML manual 3.2); row = photon index.
        dead = ~st["alive"]
        rank = jnp.cumsum(dead.astype(jnp.int64))
        launch = dead & (rank <= budget - launched)
        row = jnp.where(launch, launched + rank - 1, st["row"])
        launched = launched + jnp.sum(launch.astype(jnp.int64))
        start = {"x": 0.0, "y": 0.0, "z": 0.0, "ux": params["ux0"], "uy": 0.0, "uz": params["uz0"], "s": 0.0}
        for k_, v in start.items():
            st[k_] = jnp.where(launch, v, st[k_])
        for k_ in ("L", "k"):
            st[k_] = jnp.where(launch[:, None], 0.0, st[k_])
        layer = jnp.where(launch, 0, st["layer"])
        steps = jnp.where(launch, 0, st["steps"])
        alive = ~dead | launch

        rng = st["rng"]
        rng, u_step = _uniform(rng)
        rng, u_a = _uniform(rng)
        rng, u_b = _uniform(rng)
        x, y, z, ux, uy, uz = st["x"], st["y"], st["z"], st["ux"], st["uy"], st["uz"]
        mu = sigma_s[layer]
        # --- Step size: dimensionless step -ln(xi), carried over interfaces (MCML manual 3.3, 3.7).
        s = jnp.where(st["s"] <= 0.0, -jnp.log1p(-u_step), st["s"])
        z_top, z_bot = z_edges[layer], z_edges[layer + 1]
        d_b = jnp.where(uz > 0.0, (z_bot - z) / jnp.where(uz > 0.0, uz, 1.0),
                        jnp.where(uz < 0.0, (z_top - z) / jnp.where(uz < 0.0, uz, -1.0), jnp.inf))
        s_geo = s / mu
        hit = d_b <= s_geo
        # --- Hop (MCML manual 3.4); the path length is tallied in the current layer.
        dist = jnp.where(hit, d_b, s_geo)
        x = x + dist * ux
        y = y + dist * uy
        z = jnp.where(hit, jnp.where(uz > 0.0, z_bot, z_top), z + dist * uz)
        in_layer = layer[:, None] == layers
        Lp = st["L"] + jnp.where(in_layer & alive[:, None], dist[:, None], 0.0)
        s = jnp.where(hit, jnp.maximum(s - d_b * mu, 0.0), 0.0)
        # --- Interface: all-or-none Fresnel reflection (MCML manual 3.7.1), else refract (Snell).
        nl, exit_top, exit_bot, inner, (ux_b, uy_b, uz_b) = _interface(ux, uy, uz, layer, hit, alive, n_ext, L, u_a)
        # --- Scattering: Henyey-Greenstein deflection (MCML manual 3.6); no absorption, so no weight and no roulette.
        interact = alive & ~hit
        cos_s = _hg_cos(g_layer[layer], u_a)
        sx, sy, sz = _spin(ux, uy, uz, cos_s, u_b)
        ux = jnp.where(interact, sx, ux_b)
        uy = jnp.where(interact, sy, uy_b)
        uz = jnp.where(interact, sz, uz_b)
        kp = st["k"] + jnp.where(in_layer & interact[:, None], 1.0, 0.0)
        steps = steps + 1
        exited = exit_top | exit_bot
        capped = alive & ~exited & ((steps >= cfg.max_steps) | (jnp.sum(Lp, axis=1) >= max_path))
        died = exited | capped
        # --- Record the photon's row when it dies (rows are unique: each photon dies once).
        idx = jnp.where(died, row, B)
        side = jnp.where(exit_top, SIDE_R, jnp.where(exit_bot, SIDE_T, SIDE_CAP)).astype(jnp.int8)
        out = dict(out)
        out["side"] = out["side"].at[idx].set(side, mode="drop")
        out["radius"] = out["radius"].at[idx].set(jnp.sqrt(x * x + y * y), mode="drop")
        out["L"] = out["L"].at[idx].set(Lp, mode="drop")
        out["k"] = out["k"].at[idx].set(kp, mode="drop")
        out["events"] = out["events"] + jnp.sum(alive.astype(jnp.int64))
        new = {"x": x, "y": y, "z": z, "ux": ux, "uy": uy, "uz": uz, "s": s, "L": Lp, "k": kp,
               "layer": jnp.where(inner, nl, layer), "steps": steps, "row": row, "alive": alive & ~died, "rng": rng}
        return new, out, launched

    _, out, _ = lax.while_loop(cond, body, (state, out, jnp.zeros((), jnp.int64)))
    return out


_jitted_record = jax.jit(_record_kernel, static_argnums=0)
_COMPILED: dict = {}


def _compiled(cfg: _RecordConfig, params: dict, key, budget):
    """The compiled recording walk for ``cfg`` and these argument shapes, and the seconds spent compiling it now."""
    sig = (cfg, tuple((k, v.shape) for k, v in sorted(params.items())))
    if sig in _COMPILED:
        return _COMPILED[sig], 0.0
    t0 = time.perf_counter()
    _COMPILED[sig] = _jitted_record.lower(cfg, params, key, budget).compile()
    return _COMPILED[sig], time.perf_counter() - t0


class ReplaySample(eqx.Module):
    """The recorded photons of one reference run (:func:`record`); a pytree of arrays, ``N`` photons, ``L`` layers.

    Attributes:
        side: ``(N,)`` int8: 0 left through the top (reflectance), 1 through the bottom (transmittance), 2 killed
            at the cap.
        radius: ``(N,)`` exit radius, mm (at the kill for capped photons).
        path: ``(N, L)`` path length per layer, mm.
        scatterings: ``(N, L)`` scattering events per layer (float64, exact integers).
        bin: ``(N,)`` int32 radial bin of the exit point in ``r_edges`` (``M`` for outside the grid).
        r_edges: ``(M + 1,)`` radial bin edges, mm.
        sigma_s0: ``(L,)`` reference scattering coefficients, 1/mm (not reduced).
        g: ``(L,)`` anisotropies (fixed by the run).
        w0: weight of every photon entering, ``1 - R_specular``.
        R_specular: specular reflectance of the top face (excluded from ``R``).
        photons: ``N`` (static).
        seconds, events: wall time of the recording (compilation included in ``compile_seconds``) and walk events.
        max_path, max_steps: the cap (mm, events).
    """

    side: Int[Array, " N"]
    radius: Float[Array, " N"]
    path: Float[Array, "N L"]
    scatterings: Float[Array, "N L"]
    bin: Int[Array, " N"]
    r_edges: Float[Array, " M1"]
    sigma_s0: Float[Array, " L"]
    g: Float[Array, " L"]
    w0: Array
    R_specular: Array
    stack: Stack
    photons: int = eqx.field(static=True)  # the only static field: run metadata below must not force recompiles
    seconds: Array
    compile_seconds: Array
    events: Array
    max_path: Array
    max_steps: Array

    @property
    def capped(self) -> int:
        """Number of photons killed at the cap."""
        return int(np.sum(np.asarray(self.side) == SIDE_CAP))


def _bins(radius: np.ndarray, r_edges: np.ndarray) -> np.ndarray:
    i = np.searchsorted(r_edges, radius, side="right") - 1
    return np.where((radius >= r_edges[0]) & (radius < r_edges[-1]), i, r_edges.size - 1).astype(np.int32)


def _check_edges(r_edges) -> np.ndarray:
    e = np.asarray(r_edges, dtype=np.float64)
    if e.ndim != 1 or e.size < 2 or not np.all(np.isfinite(e)) or e[0] < 0 or np.any(np.diff(e) <= 0):
        raise ValueError(f"record(r_edges=array of shape {e.shape}) must be 1-D, >= 2 finite edges, >= 0, strictly "
                         "increasing")
    return e


def record(stack: Stack, photons: int, *, r_edges, seed: int = 0, max_path: float = math.inf,
           max_steps: int = DEFAULT_MAX_STEPS, batch_size: int = DEFAULT_BATCH, lanes: int | None = None
           ) -> ReplaySample:
    """Simulate ``photons`` photons through ``stack`` *without absorption* and record them for :func:`replay`.

    Args:
        stack: the geometry and the reference (:class:`~jaxsss.mc.Stack`): its ``g``, ``n``, thicknesses and ambient
            indices are kept; its ``sigma_s`` (1/mm, not reduced, ``> 0`` in every layer) is the reference
            ``sigma_s0``; its ``sigma_a`` is ignored (the walk has none).
        photons: incident photons, ``>= 2``.
        r_edges: radial bin edges, mm, ``(M + 1,)``, increasing, ``>= 0`` (:func:`rebin` changes them later).
        seed: integer seed; batch ``b`` uses ``fold_in(key(seed), b)``.
        max_path: the cap on a walk's total path length, mm (``> 0``; default no cap but ``max_steps``).
        max_steps: the cap on a walk's events (scatterings + interface hits), ``>= 1``.
        batch_size: photons per compiled call (the per-photon buffers have this many rows).
        lanes: photons advanced in lock-step (default: the engine's, ``batch_photons / 64`` rounded to a power of two in [256, 4096]).

    Returns:
        :class:`ReplaySample`.

    Raises:
        ValueError: naming the argument, its value and the allowed range.
    """
    if not isinstance(stack, Stack):
        raise ValueError(f"record(stack={stack!r}) must be a jaxsss.mc.Stack")
    for name, v, lo in (("photons", photons, 2), ("seed", seed, 0), ("max_steps", max_steps, 1),
                        ("batch_size", batch_size, 1)) + ((("lanes", lanes, 1),) if lanes is not None else ()):
        check_integer(v, name, lo, owner="record")
    if max_path != math.inf:
        max_path = float(check_range(max_path, "max_path", 0.0, None, lo_open=True, owner="record"))
    sigma_s0 = np.asarray(stack.sigma_s)
    if np.any(sigma_s0 <= 0.0):
        i = int(np.argmax(sigma_s0 <= 0.0))
        raise ValueError(f"record(stack.sigma_s[{i}]={sigma_s0[i]:g}) is outside the allowed range (0, inf): the "
                         "reference run needs scattering in every layer")
    r_edges = _check_edges(r_edges)
    photons, batch_size = int(photons), int(min(batch_size, photons))
    lanes = _auto_lanes(batch_size) if lanes is None else int(lanes)
    cfg = _RecordConfig(num_layers=stack.num_layers, lanes=lanes, rows=batch_size, max_steps=int(max_steps))
    R_sp, ux0, uz0 = entry_state(stack.n_above, float(np.asarray(stack.n)[0]), 0.0)
    params = {k: jnp.asarray(v, jnp.float64) for k, v in {
        "sigma_s": sigma_s0, "g": np.asarray(stack.g),
        "n_ext": np.concatenate([[stack.n_above], np.asarray(stack.n), [stack.n_below]]),
        "z_edges": stack.boundaries(), "max_path": max_path, "ux0": ux0, "uz0": uz0}.items()}
    root = jax.random.key(seed)
    fn, compile_seconds = _compiled(cfg, params, root, jnp.asarray(batch_size, jnp.int64))
    t0 = time.perf_counter()
    parts, events = [], 0
    for b in range(math.ceil(photons / batch_size)):
        budget = min(batch_size, photons - b * batch_size)
        out = fn(params, jax.random.fold_in(root, b), jnp.asarray(budget, jnp.int64))
        out = {k: np.asarray(v) for k, v in out.items()}
        events += int(out.pop("events"))
        parts.append({k: v[:budget] for k, v in out.items()})
    seconds = time.perf_counter() - t0
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    assert np.all(cat["side"] >= 0), "record: a photon was launched but never recorded"
    return ReplaySample(
        side=jnp.asarray(cat["side"]), radius=jnp.asarray(cat["radius"]), path=jnp.asarray(cat["L"]),
        scatterings=jnp.asarray(cat["k"]), bin=jnp.asarray(_bins(cat["radius"], r_edges)),
        r_edges=jnp.asarray(r_edges), sigma_s0=jnp.asarray(sigma_s0), g=jnp.asarray(np.asarray(stack.g)),
        # Scalars as arrays: under eqx.filter_jit (Optimistix) Python scalars would be static and recompile per run.
        w0=jnp.asarray(1.0 - float(R_sp)), R_specular=jnp.asarray(float(R_sp)), stack=stack, photons=photons,
        seconds=jnp.asarray(seconds), compile_seconds=jnp.asarray(compile_seconds), events=jnp.asarray(events),
        max_path=jnp.asarray(max_path), max_steps=jnp.asarray(int(max_steps)))


def rebin(sample: ReplaySample, r_edges) -> ReplaySample:
    """The same sample with other radial bin edges (mm)."""
    e = _check_edges(r_edges)
    return eqx.tree_at(lambda s: (s.bin, s.r_edges), sample,
                       (jnp.asarray(_bins(np.asarray(sample.radius), e)), jnp.asarray(e)))


class ReplayEstimate(NamedTuple):
    """Output of :func:`replay` (per incident photon; profiles per mm^2; ``M`` radial bins).

    ``R``: diffuse reflectance (specular excluded), ``T``: total transmittance (unscattered beam included),
    ``T_unscattered``: the unscattered part of ``T``; ``*_stderr``: standard errors of the mean over the recorded
    photons; ``R_r``, ``T_r`` ``(M,)``; ``ess`` and ``ess_fraction`` (module docstring); ``R_r_ess_fraction``,
    ``T_r_ess_fraction`` ``(M,)``: the same ratio per radial bin (0 for an empty bin); ``cap_bound``: upper bound on
    the ``R + T`` lost to the cap.
    """

    R: Array
    R_stderr: Array
    T: Array
    T_stderr: Array
    T_unscattered: Array
    R_r: Array
    R_r_stderr: Array
    T_r: Array
    T_r_stderr: Array
    ess: Array
    ess_fraction: Array
    R_r_ess_fraction: Array
    T_r_ess_fraction: Array
    cap_bound: Array


def _mean_and_stderr(c, N: int, axis=0):
    """Mean of per-photon contributions ``c`` over ``N`` photons (``c`` summed over ``axis``) and its standard error."""
    s1, s2 = jnp.sum(c, axis=axis), jnp.sum(c * c, axis=axis)
    mean = s1 / N
    # Standard error of a mean: sqrt((E[c^2] - E[c]^2) / (N - 1)).
    return mean, jnp.sqrt(jnp.maximum(s2 / N - mean * mean, 0.0) / (N - 1))


def _kish(w):
    """Kish effective sample size ``(sum w)^2 / sum w^2`` (0 when every weight is 0)."""
    s2 = jnp.sum(w * w)
    return jnp.where(s2 > 0.0, jnp.sum(w) ** 2 / jnp.where(s2 > 0.0, s2, 1.0), 0.0)


def photon_weights(sample: ReplaySample, sigma_a, sigma_s_prime):
    """Replayed weight of every recorded photon, ``(N,)`` (module docstring), and the absorption-only weight.

    ``sigma_a``, ``sigma_s_prime``: ``(L,)`` per layer, 1/mm (``sigma_s' > 0``, ``sigma_a >= 0``).
    """
    sigma_s = sigma_s_prime / (1.0 - sample.g)
    # Likelihood ratio of the walk: k log(sigma_s / sigma_s0) - (sigma_s - sigma_s0) L, per layer, summed.
    log_ratio = sample.scatterings @ jnp.log(sigma_s / sample.sigma_s0) - sample.path @ (sigma_s - sample.sigma_s0)
    # Absorption weight exp(-sigma_a L) (Beer-Lambert along the walk).
    log_abs = -(sample.path @ sigma_a)
    return sample.w0 * jnp.exp(log_ratio + log_abs), sample.w0 * jnp.exp(log_abs)


def replay(sample: ReplaySample, sigma_a, sigma_s_prime) -> ReplayEstimate:
    """R(r), T(r) and the totals of ``sample``'s stack with per-layer ``sigma_a`` and ``sigma_s_prime`` (1/mm).

    Args:
        sample: a :func:`record` run.
        sigma_a: ``(L,)`` absorption coefficients, 1/mm, ``>= 0``.
        sigma_s_prime: ``(L,)`` reduced scattering coefficients, 1/mm, ``> 0``; ``sigma_s = sigma_s' / (1 - g)`` at
            the sample's ``g``.

    Returns:
        :class:`ReplayEstimate`; differentiable in ``sigma_a`` and ``sigma_s_prime`` (jit-compiled once per sample
        shape).

    Raises:
        ValueError: for a wrong shape, and for out-of-range values when they are concrete (under ``jit``/``grad``
        the values are not checked: no host callback, so the compiled code can go to the persistent cache).
    """
    sigma_a = jnp.asarray(sigma_a, jnp.float64)
    sigma_s_prime = jnp.asarray(sigma_s_prime, jnp.float64)
    for name, v, lo_ok in (("sigma_a", sigma_a, lambda x: x >= 0.0), ("sigma_s_prime", sigma_s_prime,
                                                                       lambda x: x > 0.0)):
        if v.shape != sample.sigma_s0.shape:
            raise ValueError(f"replay({name}=array of shape {v.shape}) must have shape {sample.sigma_s0.shape}: one "
                             "value per layer")
        if not isinstance(v, jax.core.Tracer):
            arr = np.asarray(v)
            if not np.all(lo_ok(arr) & np.isfinite(arr)):
                raise ValueError(f"replay({name}={arr.tolist()}) is outside the allowed range "
                                 f"{'[0, inf)' if name == 'sigma_a' else '(0, inf)'}")
    return _replay(sample, sigma_a, sigma_s_prime)


@jax.jit
def _replay(sample: ReplaySample, sigma_a, sigma_s_prime) -> ReplayEstimate:
    N = sample.photons
    w, w_abs = photon_weights(sample, sigma_a, sigma_s_prime)
    is_R, is_T = sample.side == SIDE_R, sample.side == SIDE_T
    detected = is_R | is_T
    R, R_err = _mean_and_stderr(jnp.where(is_R, w, 0.0), N)
    T, T_err = _mean_and_stderr(jnp.where(is_T, w, 0.0), N)
    unscattered = is_T & (jnp.sum(sample.scatterings, axis=1) == 0.0)
    T_un = jnp.sum(jnp.where(unscattered, w, 0.0)) / N
    M = sample.r_edges.shape[0] - 1
    area = jnp.pi * jnp.diff(sample.r_edges**2)

    def sums(c):
        return (jax.ops.segment_sum(c, sample.bin, num_segments=M + 1)[:M],
                jax.ops.segment_sum(c * c, sample.bin, num_segments=M + 1)[:M])

    def profile(mask):
        # Per-bin sums of the photons' contributions and of their squares (each photon lies in one bin).
        s1, s2 = sums(jnp.where(mask, w, 0.0))
        mean = s1 / N
        # Per-bin Kish ESS, relative to the same photons weighted by absorption alone.
        a1, a2 = sums(jnp.where(mask, w_abs, 0.0))
        ess_bin = s1 * s1 / jnp.where(s2 > 0.0, s2, 1.0)
        ess_abs = a1 * a1 / jnp.where(a2 > 0.0, a2, 1.0)
        frac = jnp.where(ess_abs > 0.0, ess_bin / jnp.where(ess_abs > 0.0, ess_abs, 1.0), 0.0)
        return mean / area, jnp.sqrt(jnp.maximum(s2 / N - mean * mean, 0.0) / (N - 1)) / area, frac

    R_r, R_r_err, R_r_ess = profile(is_R)
    T_r, T_r_err, T_r_ess = profile(is_T)
    ess = _kish(jnp.where(detected, w, 0.0))
    ess_abs = _kish(jnp.where(detected, w_abs, 0.0))
    cap = jnp.sum(jnp.where(sample.side == SIDE_CAP, w, 0.0)) / N
    return ReplayEstimate(R, R_err, T, T_err, T_un, R_r, R_r_err, T_r, T_r_err, ess,
                          jnp.where(ess_abs > 0.0, ess / jnp.where(ess_abs > 0.0, ess_abs, 1.0), 0.0), R_r_ess,
                          T_r_ess, cap)
