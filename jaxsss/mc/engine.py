"""``simulate``: stream photon batches through the jitted kernel and assemble an :class:`~jaxsss.mc.MCResult`.

Conventions and choices (see also :mod:`jaxsss.mc._kernel`):

- Incidence: a collimated pencil beam hits the top face at the origin, at ``angle_deg`` degrees from the normal in
  the ``x``-``z`` plane (the beam travels towards ``+x``). The specular reflection ``F(theta_i)`` (exact Fresnel,
  ambient ``n_above`` onto layer 1) is removed from the weight deterministically and reported as ``R_specular``;
  the rest enters refracted by Snell's law.
- Interfaces: all-or-none reflection with probability ``R`` (MCML's default), at every interface including the outer
  faces. Chosen over weight splitting because a lane then always carries one packet.
- Absorption by weight at each interaction (``w *= albedo``); Russian roulette below ``weight_threshold`` with
  survival chance ``roulette_chance``.
- Determinism: the result is a function of ``(stack, photons, seed, angle, grids, batch_size, lanes, devices)``.
  Batch ``b`` uses ``jax.random.fold_in(jax.random.key(seed), b)`` (and device ``d`` of several folds in ``d``);
  changing ``lanes``, ``batch_size`` or the number of devices changes the random streams (not the expectation).
- Devices: each batch's photons are split over ``devices`` with ``jax.shard_map``; every device runs its share in
  its own loop and the tallies are summed (``psum``). See :func:`simulate` and :func:`use_cpu_devices`.
- Radial splitting (``split_length``): a weight window for the far field (:mod:`jaxsss.mc._kernel`). Copies of
  one history are correlated, so standard errors then come from the spread of ``SPLIT_BATCHES`` independent batch
  means (``MCResult.stderr_method == "batches"``) instead of per-photon second moments.
- Compilation: one XLA program per :class:`~jaxsss.mc._kernel.KernelConfig` (number of layers, grid sizes, lanes,
  step cap, roulette settings); coefficients, edges, angle, seed and the batch budget are runtime values, so a new
  medium or the last partial batch does not recompile.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range
from jaxsss.mc._kernel import N_ORDER, KernelConfig, batch_kernel
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc.result import MCResult, stderr_of_mean
from jaxsss.mc.stack import Stack

__all__ = ["simulate", "usable_cores", "use_cpu_devices"]

DEFAULT_LANES = 2**12  # per device; 4096 lanes ran 8% faster per event than 8192 on this CPU (cache), same run
DEFAULT_BATCH = 2**20
DEFAULT_MAX_STEPS = 10**6
SPLIT_BATCHES = 16  # default number of batches (for batch-means standard errors) with radial splitting
MIN_SPLIT_BATCHES = 8
SPLIT_POOL_PER_LANE = 64  # rows of the shared pool of waiting copies, per lane (a full pool skips further splits)

_COMPILED: dict = {}
_jitted = jax.jit(batch_kernel, static_argnums=0)
AXIS = "photons"  # the mesh axis the photons of a batch are split over


def _sharded_kernel(cfg: KernelConfig, mesh: Mesh):
    """``batch_kernel`` on every device of ``mesh``: device ``d`` of ``D`` runs ``budget // D`` photons (one more
    for ``d < budget % D``) with the key ``fold_in(key, d)`` in its own ``while_loop`` (no lock-step across devices),
    and the tallies are summed over devices (``psum``), so the output is replicated."""

    def per_device(params, key, budget):
        d = lax.axis_index(AXIS).astype(budget.dtype)
        D = mesh.shape[AXIS]
        share = budget // D + (d < budget % D).astype(budget.dtype)
        tallies = batch_kernel(cfg, params, jax.random.fold_in(key, d), share)
        return jax.tree.map(lambda v: lax.psum(v, AXIS), tallies)

    return jax.jit(jax.shard_map(per_device, mesh=mesh, in_specs=(P(), P(), P()), out_specs=P(),
                                 check_vma=False))


def _devices(devices) -> list:
    """The devices to split photons over: ``None`` -> all of ``jax.devices()``; an int ``N`` -> the first ``N``; or a
    sequence of devices."""
    available = jax.devices()
    if devices is None:
        return list(available)
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        if not 1 <= devices <= len(available):
            raise ValueError(
                f"simulate(devices={devices}) is outside the allowed range [1, {len(available)}] (the devices JAX "
                f"has: {len(available)} {available[0].platform}; for more CPU devices call "
                "jaxsss.mc.use_cpu_devices(N) or set JAX_NUM_CPU_DEVICES=N before JAX starts)")
        return list(available[:devices])
    devices = list(devices)
    if not devices:
        raise ValueError("simulate(devices=[]) must name at least one device")
    return devices


def use_cpu_devices(n: int | None = None) -> int:
    """Ask JAX for ``n`` CPU devices (default: the cores this process may run on), so that :func:`simulate` splits
    its photons over them; returns ``n``. Must run before JAX starts its backend (before the first array is made or
    anything is compiled); the same as ``JAX_NUM_CPU_DEVICES=n`` in the environment, or
    ``jax.config.update("jax_num_cpu_devices", n)``. On a GPU machine the GPUs are the default devices and this only
    affects the CPU backend.

    Raises:
        ValueError: ``n < 1``, or JAX's backend is already running with another number of CPU devices.
    """
    if n is None:
        n = usable_cores()
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"use_cpu_devices(n={n!r}) must be an integer in the allowed range [1, inf)")
    n = int(n)
    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        have = len(jax.devices("cpu"))
        if have != n:
            raise ValueError(f"use_cpu_devices(n={n}): JAX's backend already runs with {have} CPU device(s); call "
                             "this before the first JAX computation (or set JAX_NUM_CPU_DEVICES before start)")
        return n
    jax.config.update("jax_num_cpu_devices", n)
    return n


def usable_cores() -> int:
    """Cores this process may run on (``os.sched_getaffinity`` where available, else ``os.cpu_count()``)."""
    import os

    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def _edges(edges, name: str, *, nonnegative: bool) -> np.ndarray:
    """Validate bin edges: 1-D, >= 2 finite values, strictly increasing (and >= 0 for radii and pathlengths)."""
    arr = np.asarray(edges, dtype=np.float64)
    if arr.ndim != 1 or arr.size < 2:
        raise ValueError(f"simulate({name}=array of shape {arr.shape}) must be 1-D with at least 2 edges")
    check_range(arr, name, 0.0 if nonnegative else None, None, owner="simulate")
    steps = np.diff(arr)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        raise ValueError(
            f"simulate({name}[{i}:{i + 2}]={arr[i:i + 2].tolist()}) is not strictly increasing; edges must be "
            "sorted ascending without repeats"
        )
    return arr


def _positive_int(x, name: str, lo: int = 1) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer, float, np.floating)) or x != int(x):
        raise ValueError(f"simulate({name}={x!r}) must be an integer in the allowed range [{lo}, inf)")
    if int(x) < lo:
        raise ValueError(f"simulate({name}={x!r}) is outside the allowed range [{lo}, inf)")
    return int(x)


def _compiled(cfg: KernelConfig, params: dict, key, budget, devices: tuple = ()):
    """The AOT-compiled kernel for ``cfg``, these argument shapes and ``devices`` (more than one: the sharded
    kernel), and the seconds spent compiling it now."""
    sig = (cfg, tuple((k, v.shape, str(v.dtype)) for k, v in sorted(params.items())), devices)
    if sig in _COMPILED:
        return _COMPILED[sig], 0.0
    t0 = time.perf_counter()
    if len(devices) > 1:
        mesh = Mesh(np.array(devices), (AXIS,))
        fn = _sharded_kernel(cfg, mesh).lower(params, key, budget).compile()
    else:
        fn = _jitted.lower(cfg, params, key, budget).compile()
    _COMPILED[sig] = fn
    return fn, time.perf_counter() - t0


def entry_state(n_above: float, n_1: float, angle_deg: float) -> tuple[float, float, float]:
    """Specular reflectance and refracted direction ``(R_specular, ux, uz)`` of the beam entering layer 1.

    Exact Fresnel (:func:`jaxsss.fresnel.fresnel_reflectance` with ``eta = n_1 / n_above``, light from outside) at
    the incidence cosine; Snell's law ``n_above sin(theta_i) = n_1 sin(theta_t)``.
    """
    theta = math.radians(angle_deg)
    cos_i, sin_i = math.cos(theta), math.sin(theta)
    R_sp = float(fresnel_reflectance(n_1 / n_above, cos_i))
    sin_t = n_above * sin_i / n_1
    if sin_t >= 1.0:  # cannot happen from the outside unless n_1 < n_above at grazing angles
        raise ValueError(f"simulate(angle_deg={angle_deg:g}): total reflection at entry (n_above={n_above:g} > "
                         f"n={n_1:g}); no light enters")
    return R_sp, sin_t, math.sqrt(1.0 - sin_t * sin_t)


def _auto_lanes(batch_photons: int) -> int:
    """Default lane count: the power of two nearest below ``batch_photons / 64``, clipped to [256, DEFAULT_LANES]."""
    target = max(batch_photons // 64, 1)
    return int(min(max(2 ** int(math.floor(math.log2(target))), 256), DEFAULT_LANES))


def _progress_enabled(progress, n_batches: int) -> bool:
    if progress is None:
        return n_batches > 1 and sys.stderr.isatty()
    return bool(progress)


def simulate(stack: Stack, photons: int, *, seed: int = 0, angle_deg: float = 0.0, r_edges=None, xy_edges=None,
             pathlength_edges=None, exit_mu_edges=None, exit_harmonics: int = 9, batch_size: int | None = None,
             lanes: int | None = None,
             max_steps: int = DEFAULT_MAX_STEPS, weight_threshold: float = 1e-4, roulette_chance: float = 0.1,
             split_length: float | None = None, split_start: float = 0.0, split_stop: float | None = None, progress: bool | None = None,
             devices=None) -> MCResult:
    """Monte Carlo photon transport (MCML family) through ``stack`` for ``photons`` incident photon packets.

    Args:
        stack: the medium (:class:`~jaxsss.mc.Stack`; coefficients in 1/mm, thicknesses in mm).
        photons: number of incident photons, ``>= 1``.
        seed: integer seed; equal seeds (with equal settings) give identical results.
        angle_deg: angle of incidence in the ambient medium above, **degrees** from the normal, ``[0, 90)``.
        r_edges: radial bin edges, mm, ``(M + 1,)`` strictly increasing, ``>= 0``: enables ``R_r``, ``T_r``.
        xy_edges: edges of the exit histogram ``R_xy``, mm: one array for both axes or a pair ``(x_edges, y_edges)``.
        pathlength_edges: pathlength bin edges, mm (e.g. log-spaced), ``>= 0``; enables ``R_r_path``; needs
            ``r_edges``.
        exit_mu_edges: exit-cosine bin edges in ``[0, 1]`` (``(U + 1,)``, strictly increasing): enables the direction
            tally ``R_mu_phi`` of the diffuse reflectance, ``exit_harmonics`` azimuthal harmonics ``cos(m phi)``
            (``m = 0 .. exit_harmonics - 1``, ``>= 1``) per bin (:class:`~jaxsss.mc.MCResult`).
        batch_size: photons per compiled call (memory is bounded by ``lanes``, not by this). Default ``2**20``;
            with ``split_length``, ``ceil(photons / 16)`` (16 batch means for the standard errors).
        lanes: photons advanced in lock-step. ``None`` (default) picks a power of two in ``[256, 4096]`` that gives
            each lane at least ~64 photons per batch: a batch ends with a tail in which only the longest walks
            (~1e4 events at albedo 0.999) still run, so lanes must be few for small runs. On a GPU pass a larger
            value (e.g. 2**16) for large runs.
        max_steps: events (interactions + interface hits) per photon before it is killed; hits are counted in
            ``step_cap_hits`` and their weight in ``step_cap_weight``.
        weight_threshold, roulette_chance: Russian roulette (MCML: 1e-4 and 0.1).
        split_length, split_start, split_stop: radial splitting for far-field profiles, mm (``split_length > 0``,
            ``0 <= split_start < split_stop``; ``split_length=None``: off; ``split_stop=None``: no stop). A weight window with target ``W(r) =
            exp(-(clip(r, split_start, split_stop) - split_start) / split_length)``, ``r`` the distance from the
            beam's axis at the entry point: a photon heavier than ``2 W`` is split into ``min(w / W, 16)`` copies,
            and roulette acts below ``weight_threshold * W``. All photons at ``r`` then weigh about ``W(r)``, so the
            number of photons follows ``R(r) r / W(r)``: with ``split_length = l_d = 1 / sigma_tr`` (the far-field
            decay of ``R``) it stays roughly constant out to ``split_stop``. Set ``split_stop`` to the last radius
            of interest: beyond it the window is flat, so the work stays bounded. Unbiased; standard errors then come
            from at least 8 independent batches (``stderr_method == "batches"``).
        progress: a tqdm bar over batches; ``None`` shows it when there is more than one batch and stderr is a
            terminal.
        devices: the JAX devices the photons of each batch are split over: ``None`` (default) all of
            ``jax.devices()``, an int ``N`` the first ``N``, or a sequence of devices. Each device runs its share
            (``batch_size / N`` photons, ``lanes`` lanes) in its own loop with its own random stream, and the tallies
            are summed. JAX starts with one CPU device; for one per core call :func:`use_cpu_devices` (or set
            ``JAX_NUM_CPU_DEVICES``) before the first JAX computation. Results are reproducible for a given device
            count and agree in distribution across counts (one device uses the batch keys unchanged; with ``N > 1``
            device ``d`` folds ``d`` into the batch key). With ``jax.distributed`` initialised, ``jax.devices()``
            spans the hosts and every process must make the same call.

    Returns:
        :class:`~jaxsss.mc.MCResult` (per incident photon; profiles per mm^2; see its docstring).

    Raises:
        ValueError: naming the argument, its value and the allowed range, for bad input.
    """
    if not isinstance(stack, Stack):
        raise ValueError(f"simulate(stack={stack!r}) must be a jaxsss.mc.Stack")
    photons = _positive_int(photons, "photons")
    seed = _positive_int(seed, "seed", lo=0)
    splitting = split_length is not None
    if splitting:
        split_length = float(check_range(split_length, "split_length", 0.0, None, lo_open=True, owner="simulate"))
        split_start = float(check_range(split_start, "split_start", 0.0, None, owner="simulate"))
        if split_stop is not None:
            split_stop = float(check_range(split_stop, "split_stop", split_start, None, lo_open=True, owner="simulate"))
    if batch_size is None:
        batch_size = max(math.ceil(photons / SPLIT_BATCHES), 1) if splitting else DEFAULT_BATCH
    batch_size = _positive_int(batch_size, "batch_size")
    if splitting and math.ceil(photons / batch_size) < MIN_SPLIT_BATCHES:
        raise ValueError(f"simulate(batch_size={batch_size}) gives {math.ceil(photons / batch_size)} batches for "
                         f"photons={photons}; radial splitting needs at least {MIN_SPLIT_BATCHES} (standard errors "
                         "come from batch means): use a smaller batch_size or more photons")
    devices = tuple(_devices(devices))
    per_device = max(min(photons, batch_size) // len(devices), 1)
    lanes = _auto_lanes(per_device) if lanes is None else _positive_int(lanes, "lanes")
    max_steps = _positive_int(max_steps, "max_steps")
    angle_deg = float(check_range(angle_deg, "angle_deg", 0.0, 90.0, hi_open=True, owner="simulate"))
    weight_threshold = float(check_range(weight_threshold, "weight_threshold", 0.0, 1.0, lo_open=True,
                                         owner="simulate"))
    roulette_chance = float(check_range(roulette_chance, "roulette_chance", 0.0, 1.0, lo_open=True,
                                        owner="simulate"))
    if r_edges is not None:
        r_edges = _edges(r_edges, "r_edges", nonnegative=True)
    if xy_edges is not None:
        if isinstance(xy_edges, (tuple, list)) and len(xy_edges) == 2 and np.ndim(xy_edges[0]) == 1:
            x_edges, y_edges = (_edges(e, n, nonnegative=False) for e, n in zip(xy_edges, ("x_edges", "y_edges")))
        else:
            x_edges = y_edges = _edges(xy_edges, "xy_edges", nonnegative=False)
    else:
        x_edges = y_edges = None
    if pathlength_edges is not None:
        if r_edges is None:
            raise ValueError("simulate(pathlength_edges=...) needs r_edges: R(r, L) is binned in r too")
        pathlength_edges = _edges(pathlength_edges, "pathlength_edges", nonnegative=True)
    if exit_mu_edges is not None:
        exit_mu_edges = _edges(exit_mu_edges, "exit_mu_edges", nonnegative=True)
        check_range(exit_mu_edges, "exit_mu_edges", 0.0, 1.0, owner="simulate")
        exit_harmonics = _positive_int(exit_harmonics, "exit_harmonics")

    L = stack.num_layers
    cfg = KernelConfig(
        num_layers=L,
        n_r=0 if r_edges is None else r_edges.size - 1,
        n_x=0 if x_edges is None else x_edges.size - 1,
        n_y=0 if y_edges is None else y_edges.size - 1,
        n_path=0 if pathlength_edges is None else pathlength_edges.size - 1,
        lanes=lanes,
        max_steps=max_steps,
        weight_threshold=weight_threshold,
        roulette_chance=roulette_chance,
        split_pool=SPLIT_POOL_PER_LANE * lanes if splitting else 0,
        n_mu=0 if exit_mu_edges is None else exit_mu_edges.size - 1,
        n_harm=0 if exit_mu_edges is None else exit_harmonics,
    )
    R_specular, ux0, uz0 = entry_state(stack.n_above, float(np.asarray(stack.n)[0]), angle_deg)
    dummy = np.zeros(2)
    params = {
        "sigma_a": np.asarray(stack.sigma_a), "sigma_s": np.asarray(stack.sigma_s), "g": np.asarray(stack.g),
        "n_ext": np.concatenate([[stack.n_above], np.asarray(stack.n), [stack.n_below]]),
        "z_edges": stack.boundaries(),
        "r_edges": dummy if r_edges is None else r_edges,
        "x_edges": dummy if x_edges is None else x_edges,
        "y_edges": dummy if y_edges is None else y_edges,
        "path_edges": dummy if pathlength_edges is None else pathlength_edges,
        "mu_edges": dummy if exit_mu_edges is None else exit_mu_edges,
        "entry": np.array([ux0, uz0, 1.0 - R_specular]),
    }
    if splitting:
        params["window"] = np.array([split_start, 1e300 if split_stop is None else split_stop, 1.0 / split_length])
    params = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}

    t_start = time.perf_counter()
    n_batches = math.ceil(photons / batch_size)
    root = jax.random.key(seed)
    fn, compile_seconds = _compiled(cfg, params, root, jnp.asarray(batch_size, jnp.int64), devices)
    totals: dict[str, np.ndarray] = {}
    per_batch: list[tuple[int, dict]] = []
    batches = range(n_batches)
    if _progress_enabled(progress, n_batches):
        from tqdm.auto import tqdm

        batches = tqdm(batches, desc="jaxsss mc", unit="batch", total=n_batches)
    for b in batches:
        budget = min(batch_size, photons - b * batch_size)
        out = fn(params, jax.random.fold_in(root, b), jnp.asarray(budget, jnp.int64))
        # Replicated over the devices (psum): any local copy is the total (also across hosts).
        out = {k: np.asarray(v.addressable_data(0)) for k, v in out.items()}
        if splitting:
            per_batch.append((budget, out))
        for k, v in out.items():
            totals[k] = v.copy() if k not in totals else totals[k] + v
    seconds = time.perf_counter() - t_start
    meta = dict(seed=seed, angle_deg=angle_deg, seconds=seconds, compile_seconds=compile_seconds,
                batches=n_batches, batch_size=batch_size, devices=len(devices))
    if not splitting:
        return _assemble(totals, photons, R_specular, cfg, r_edges, x_edges, y_edges, pathlength_edges, exit_mu_edges,
                         **meta)
    totals, mean_r_err = _batch_moments(per_batch, photons)
    res = _assemble(totals, photons, R_specular, cfg, r_edges, x_edges, y_edges, pathlength_edges, exit_mu_edges,
                    stderr_method="batches", split_length=split_length, split_start=split_start,
                    split_stop=split_stop, **meta)
    return dataclasses.replace(res, mean_exit_radius_stderr=mean_r_err)


def _batch_moments(per_batch: list[tuple[int, dict]], N: int) -> tuple[dict, float]:
    """Summed tallies whose second moments reproduce the *batch-means* variance (radial splitting).

    For a tally with batch sums ``S_b`` over ``n_b`` photons, the mean is ``m = sum S_b / N`` and its variance is
    estimated by ``B / (B - 1) * sum_b (n_b / N)^2 (S_b / n_b - m)^2``. :func:`_assemble` forms every standard
    error with :func:`stderr_of_mean` from (sum, sum of squares, N); this returns the pseudo sum of squares
    ``N ((N - 1) var + m^2)`` for which that formula gives the batch-means error, so the assembly is shared. Also
    returns the batch-means error of the mean exit radius (a ratio: batch ratios weighted by batch weight)."""
    B = len(per_batch)
    n = np.array([b for b, _ in per_batch], np.float64)
    totals = {k: sum(out[k] for _, out in per_batch) for k in per_batch[0][1]}

    def pseudo_sq(sums):  # sums: (B, ...) batch sums -> pseudo sum of squares
        m = sums.sum(0) / N
        x = sums / n.reshape((-1,) + (1,) * (sums.ndim - 1))
        var = B / (B - 1) * np.sum((n.reshape(x.shape[:1] + (1,) * (x.ndim - 1)) / N) ** 2 * (x - m) ** 2, axis=0)
        return N * ((N - 1) * var + m * m)

    for k in ("exit", "profile", "xy", "r_path", "exit_dir"):
        if k in totals:
            sums = np.stack([out[k][..., 0] for _, out in per_batch])
            totals[k] = np.stack([totals[k][..., 0], pseudo_sq(sums)], axis=-1)
    totals["absorbed_sq"] = pseudo_sq(np.stack([out["absorbed"].sum() for _, out in per_batch]))
    W = np.array([out["exit"][0, :, 0].sum() for _, out in per_batch])
    wr = np.array([out["exit_radius"][0] for _, out in per_batch])
    if W.sum() > 0:
        ratio = wr.sum() / W.sum()
        with np.errstate(invalid="ignore", divide="ignore"):
            var = B / (B - 1) * np.sum((W / W.sum()) ** 2 * (np.where(W > 0, wr / W, ratio) - ratio) ** 2)
        mean_r_err = float(np.sqrt(var))
    else:
        mean_r_err = float("nan")
    return totals, mean_r_err


def _assemble(t, N, R_specular, cfg, r_edges, x_edges, y_edges, path_edges, mu_edges=None, **meta) -> MCResult:
    exit_ = t["exit"]  # (R/T, order, moment)
    order_mean = exit_[..., 0] / N
    order_err = stderr_of_mean(exit_[..., 0], exit_[..., 1], N)
    # Each photon exits at most once, so the per-photon square of a sum over orders is the sum of the squares.
    tot = exit_.sum(axis=1)
    R_err, T_err = stderr_of_mean(tot[:, 0], tot[:, 1], N)
    A_sum = float(t["absorbed"].sum())
    wr, wr2, w2r = t["exit_radius"]
    W, W2 = tot[0]
    if W > 0:
        mean_r = wr / W
        # Delta method for a ratio of means: var(mean(wr) / mean(w)) ~ var(wr - m w) / (N mean(w)^2).
        var = max(wr2 - 2.0 * mean_r * w2r + mean_r * mean_r * W2, 0.0) / N - (wr / N - mean_r * W / N) ** 2
        mean_r_err = math.sqrt(max(var, 0.0) / max(N - 1, 1)) / (W / N)
    else:
        mean_r, mean_r_err = float("nan"), float("nan")
    kw = dict(
        photons=N, lanes=cfg.lanes, max_steps=cfg.max_steps, events=int(t["events"]), iterations=int(t["iterations"]),
        R_specular=float(R_specular),
        R_diffuse=float(tot[0, 0] / N), R_diffuse_stderr=float(R_err),
        R_order=order_mean[0], R_order_stderr=order_err[0],
        T=float(tot[1, 0] / N), T_stderr=float(T_err), T_order=order_mean[1], T_order_stderr=order_err[1],
        A=A_sum / N, A_stderr=float(stderr_of_mean(A_sum, t["absorbed_sq"], N)), A_layer=t["absorbed"] / N,
        roulette_balance=float(t["roulette"]) / N, step_cap_hits=int(t["cap_hits"]),
        step_cap_weight=float(t["cap_weight"]) / N,
        mean_exit_radius=float(mean_r), mean_exit_radius_stderr=float(mean_r_err),
    )
    if cfg.n_r:
        area = np.pi * np.diff(r_edges**2)
        prof = t["profile"].reshape(2, N_ORDER, cfg.n_r, 2)
        by_order = prof[..., 0] / N / area
        by_order_err = stderr_of_mean(prof[..., 0], prof[..., 1], N) / area
        summed = prof.sum(axis=1)
        err = stderr_of_mean(summed[..., 0], summed[..., 1], N) / area
        kw.update(r_edges=r_edges, R_r=summed[0, :, 0] / N / area, R_r_stderr=err[0], R_r_order=by_order[0],
                  R_r_order_stderr=by_order_err[0], T_r=summed[1, :, 0] / N / area, T_r_stderr=err[1],
                  T_r_order=by_order[1], T_r_order_stderr=by_order_err[1])
    if cfg.n_x:
        cell = np.outer(np.diff(x_edges), np.diff(y_edges))
        xy_order = t["xy"].reshape(N_ORDER, cfg.n_x, cfg.n_y, 2)
        xy = xy_order.sum(axis=0)  # each photon exits once: the orders' squares add up to the per-photon squares
        kw.update(x_edges=x_edges, y_edges=y_edges, R_xy=xy[..., 0] / N / cell,
                  R_xy_stderr=stderr_of_mean(xy[..., 0], xy[..., 1], N) / cell,
                  R_xy_order=xy_order[..., 0] / N / cell,
                  R_xy_order_stderr=stderr_of_mean(xy_order[..., 0], xy_order[..., 1], N) / cell)
    if cfg.n_path:
        area = np.pi * np.diff(r_edges**2)[:, None]
        rp = t["r_path"].reshape(cfg.n_r, cfg.n_path, 2)
        kw.update(pathlength_edges=path_edges, R_r_path=rp[..., 0] / N / area,
                  R_r_path_stderr=stderr_of_mean(rp[..., 0], rp[..., 1], N) / area)
    if cfg.n_mu:
        ed = t["exit_dir"].reshape(cfg.n_mu, cfg.n_harm, 2)
        kw.update(exit_mu_edges=mu_edges, R_mu_phi=ed[..., 0] / N, R_mu_phi_stderr=stderr_of_mean(ed[..., 0],
                                                                                               ed[..., 1], N))
    return MCResult(**meta, **kw)
