"""Fit sigma_a and sigma_s' (per channel) to radial profiles R(r) and/or T(r) with Optimistix.

Data and normalisation. Absolute profiles are per *incident* photon, in 1/mm^2 (:mod:`fitting.models`: the forward
models multiply jaxsss's per-entering-flux profiles by ``1 - fresnel_reflectance(eta, 1.0)``). Relative profiles
(``relative=True``) carry a free positive scale per channel.

Unknowns: ``sigma_a`` and ``sigma_s'`` per channel (1/mm), fitted as logarithms; optionally the scale (relative
data) and ``eta`` (``free_eta=True``; usually fixed). Channels and profiles are independent problems: one compiled,
vmapped call solves all of them (and shards them over the devices when there are several).

Fit range. By default the fit uses the radii ``r >= l_u`` (one transport mean free path ``1 / sigma_t'``) at the
initial guess: within half a transport mean free path the dipole is 10-20x too low, and 10-30% high at 1-5
(shared/reference/README.md, "How good the dipole is"). The transport model ``mc`` starts at ``0.1 l_u`` instead
(:data:`fitting.models.MC_R_MIN_LU`). ``r_min``/``r_max`` override it. The result records the range and the reason.

Weights: ``1 / stderr`` when standard errors are given, else relative residuals ``(model - data) / data`` (points
with ``data <= 0`` are then left out).
"""

from __future__ import annotations

import time
import warnings
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

import jaxsss
from jaxsss._config import compile_bound_options
from jaxsss._exported import exported_program
from jaxsss.validate import trusted_traces
from jaxsss.fresnel import resolve_fresnel_method
from fitting import _kernel as K
from fitting.io import ProfileData
from fitting.models import MODEL_NOISE_LIMIT, ROUGH_RELATIVE_R_MIN_LD, resolve_model
from fitting.result import CONDITION_LIMIT, CORRELATION_LIMIT, ProfileFit
from fitting.solvers import resolve_solver, results_from_code

__all__ = ["FitWarning", "fit_jacobian_wrt_data", "fit_profile", "fit_profiles"]

# Optimistix's Cauchy test on the log-parameters and the residual norm. 1e-10 recovers noise-free data to ~1e-13 (LM
# converges superlinearly, so the last step is far above the final error); 1e-12 sits at the float64 rounding floor
# of noisy problems and can stall until max_steps with an unchanged answer (seen on 1% noise, 30 radii).
DEFAULT_RTOL = 1e-10
DEFAULT_ATOL = 1e-10


class FitWarning(UserWarning):
    """A fit that did not converge, or whose data cannot separate the parameters."""


# --- Boundary validation ------------------------------------------------------------------------------------------
def _as_array(x, name, owner):
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{owner}({name}=...): not a number or array of numbers") from None
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{owner}({name}=...): element {tuple(int(i) for i in bad)} is {arr[tuple(bad)]}, not finite")
    return arr


class _Problem:
    """The data normalised to ``P`` independent problems (profiles x channels) of ``K`` outputs and ``N`` radii."""

    def __init__(self, owner, r, R, R_stderr, T, T_stderr, eta, thickness, model, batched, r_min, r_max):
        self.owner = owner
        r = _as_array(r, "r", owner)
        if r.ndim != 1 or r.size < 2:
            raise ValueError(f"{owner}(r=...): radii must be 1-D with at least 2 values, got shape {r.shape}")
        if np.any(r < 0):
            raise ValueError(f"{owner}(r={r[r < 0][0]:g}) is outside the allowed range [0, inf)")
        if np.any(np.diff(r) <= 0):
            i = int(np.argmax(np.diff(r) <= 0)) + 1
            raise ValueError(f"{owner}(r=...): radii must be strictly increasing (r[{i}] = {r[i]:g} <= {r[i - 1]:g})")
        N = r.size
        given = {k: v for k, v in (("R", R), ("T", T)) if v is not None}
        if not given:
            raise ValueError(f"{owner}: give R and/or T (the measured profiles)")
        for k in given:
            if k not in model.outputs:
                raise ValueError(
                    f"{owner}(model={model.name!r}): the model predicts {', '.join(model.outputs)} only, not {k}; "
                    "transmittance data need a slab model ('multipole')"
                )
        self.outputs = tuple(k for k in ("R", "T") if k in given)
        ses = {"R": R_stderr, "T": T_stderr}
        for k, v in ses.items():
            if v is not None and k not in given:
                raise ValueError(f"{owner}: {k}_stderr given without {k}")
        arrays, stderrs = [], []
        shape = None
        for k in self.outputs:
            a = _as_array(given[k], k, owner)
            lead = 1 if batched else 0
            if a.ndim not in (lead + 1, lead + 2) or a.shape[lead] != N:
                want = "(B, N) or (B, N, C)" if batched else "(N,) or (N, C)"
                raise ValueError(f"{owner}({k}=...): shape {a.shape}; expected {want} with N = len(r) = {N}")
            if shape is not None and a.shape != shape:
                raise ValueError(f"{owner}: R and T have different shapes {shape} and {a.shape}")
            shape = a.shape
            s = ses[k]
            if s is not None:
                s = _as_array(s, f"{k}_stderr", owner)
                if s.shape != a.shape:
                    raise ValueError(f"{owner}({k}_stderr=...): shape {s.shape} differs from {k}'s {a.shape}")
                if np.any(s <= 0):
                    raise ValueError(f"{owner}({k}_stderr={s[s <= 0].flat[0]:g}) is outside the allowed range (0, inf)")
            arrays.append(a)
            stderrs.append(s)
        self.has_stderr = tuple(s is not None for s in stderrs)
        # Canonical layout (B, N, C).
        self.squeeze_channels = shape[-1] == N and len(shape) == (2 if batched else 1)
        canon = lambda a: (a if batched else a[None]) if not self.squeeze_channels else (  # noqa: E731
            (a if batched else a[None])[..., None])
        Y = np.stack([canon(a) for a in arrays], axis=1)  # (B, K, N, C)
        # Missing standard errors are stored as 0 (the kernel then weights by 1 / data).
        S = np.stack([canon(s) if s is not None else np.zeros_like(canon(a)) for a, s in zip(arrays, stderrs)], axis=1)
        B, Kn, _, C = Y.shape
        self.batch_shape = ((B,) if batched else ()) + (() if self.squeeze_channels else (C,))
        self.B, self.C, self.K, self.N = B, C, Kn, N
        self.r = r
        # Problems: (P, K, N) with P = B * C.
        self.y = np.moveaxis(Y, 3, 1).reshape(B * C, Kn, N)
        self.se = np.moveaxis(S, 3, 1).reshape(B * C, Kn, N)
        self.eta = self._per_problem(eta, "eta", lo_open=0.0)
        if model.needs_thickness:
            if thickness is None:
                raise ValueError(f"{owner}(model={model.name!r}) needs thickness=... (slab thickness, mm)")
            self.d = self._per_problem(thickness, "thickness", lo_open=0.0)
        else:
            if thickness is not None:
                raise ValueError(f"{owner}(thickness=...) applies to slab models only, not model={model.name!r}")
            self.d = np.ones(B * C)
        # r_min / r_max: scalars, or (new in issue 18) arrays broadcasting to (profiles, channels) like eta.
        lo = np.full(B * C, -np.inf) if r_min is None else self._per_problem(r_min, "r_min", lo_open=None)
        hi = np.full(B * C, np.inf) if r_max is None else self._per_problem(r_max, "r_max", lo_open=None)
        if np.any(lo >= hi):
            i = int(np.argmax(lo >= hi))
            raise ValueError(f"{owner}(r_min={lo[i]:g}, r_max={hi[i]:g}): r_min must be below r_max")
        self.r_lo, self.r_hi = lo, hi
        self.auto = np.full(B * C, r_min is None)
        inside = ((r[None, :] >= lo[:, None]) & (r[None, :] <= hi[:, None])).sum(axis=1)
        if np.any(inside < 3):
            i = int(np.argmin(inside))
            raise ValueError(f"{owner}(r_min={lo[i]:g}, r_max={hi[i]:g}): only {int(inside[i])} radii in range; "
                             "need >= 3")

    def _per_problem(self, x, name, lo_open):
        arr = _as_array(x, name, self.owner)
        if lo_open is not None and np.any(arr <= lo_open):
            raise ValueError(f"{self.owner}({name}={arr[arr <= lo_open].flat[0]:g}) is outside the allowed range (0, inf)")
        try:
            full = np.broadcast_to(arr, (self.B, self.C))
        except ValueError:
            raise ValueError(
                f"{self.owner}({name}=...): shape {arr.shape} does not broadcast to (profiles, channels) = "
                f"{(self.B, self.C)}"
            ) from None
        return np.ascontiguousarray(full).reshape(-1)

    def unflatten(self, x):
        x = np.asarray(x)
        return x.reshape((self.B, self.C) + x.shape[1:]).reshape(self.batch_shape + x.shape[1:])


# --- Compiled, batched stages (one cache entry per static configuration) ------------------------------------------
def _mesh(n_problems):
    devices = jax.devices()
    if len(devices) < 2 or n_problems < 2:
        return None
    # Auto axes: the inputs' placement is a hint for jit's partitioner (the code itself is unaware of sharding).
    return jax.make_mesh((len(devices),), ("batch",), axis_types=(jax.sharding.AxisType.Auto,), devices=devices)


_STAGES = {"fit": K.fit, "starts": K.starts, "solve": K.solve_starts, "valley": K.valley_starts, "finish": K.finish}


def _split(cfg: K.Config):
    """``(compile key, operand leaves)``: a model's static setting that is data (:attr:`ForwardModel.operands`, the
    ``mc`` model's table block for its ``(g, n)``) leaves the configuration that keys the compiled programs and
    becomes a runtime argument, so one compilation serves every value. The key keeps the model's own key and the
    operands' tree structure; other configurations pass through with no operands."""
    model = resolve_model(cfg.model)
    if model.operands is None or cfg.static is None:
        return cfg, ()
    key, ops = model.operands(cfg.static)
    leaves, tree = jax.tree_util.tree_flatten(ops)
    return cfg._replace(static=("operands", key, tree)), tuple(leaves)


def _bind(cfg: K.Config, leaves) -> K.Config:
    """The configuration a traced stage sees: :func:`_split`'s key with the (traced) operands back in ``static``."""
    if not (isinstance(cfg.static, tuple) and cfg.static and cfg.static[0] == "operands"):
        return cfg
    return cfg._replace(static=jax.tree_util.tree_unflatten(cfg.static[2], leaves))


@lru_cache(maxsize=64)
def _compiled(stage: str, cfg: K.Config, options: bool = True):
    """The jitted, vmapped stage (``r`` and the model's operands shared, every other argument per problem); ``cfg``
    is :func:`_split`'s key. Sharding needs no code of its own: :func:`_run` places the problem axis of the inputs
    over a device mesh and jit's SPMD partitioner splits the computation accordingly. Compiled with
    :func:`jaxsss._config.compile_bound_options`; ``options=False`` for :mod:`jax.export`, which refuses a jit that
    carries compiler options (the exported call carries them instead)."""
    fn = _STAGES[stage]
    return jax.jit(lambda r, ops, *per_problem: jax.vmap(lambda *a: fn(*_order(stage, r, a), _bind(cfg, ops)))(
        *per_problem), compiler_options=compile_bound_options() if options else None)


def _order(stage, r, a):
    """The kernel functions take ``r`` after the per-problem start/solution arguments (solve, valley, finish) or
    first."""
    if stage == "solve":
        return (a[0], a[1], r, *a[2:])
    if stage in ("finish", "valley"):
        return (*a[:5], r, *a[5:])
    return (r, *a)


def _bucket(n_problems: int, multiple: int = 1) -> int:
    """The padded problem count: a power of two up to 64 (at least 4), then a multiple of 64; and a multiple of
    ``multiple`` (the device count). Few distinct shapes mean few compilations: one profile of 1-4 channels, or a
    handful of profiles, all reuse one compiled fit; the padding costs at most 2x on tiny batches and < 1% on big ones."""
    n = max(4, 1 << (n_problems - 1).bit_length()) if n_problems <= 64 else -(-n_problems // 64) * 64
    return -(-n // multiple) * multiple


def _run(stage, cfg, shard, r, *per_problem):
    """Run a stage over all problems. The problem axis is padded (copies of the last problem, see :func:`_bucket`);
    with several devices (and ``shard``) it is placed with a :class:`jax.sharding.NamedSharding` over a 1-D mesh
    (``r`` replicated) and jit's SPMD partitioner splits the work."""
    # Padding and unpadding in NumPy: each eager jnp op would compile a small program of its own in a new process.
    per_problem = jax.tree_util.tree_map(np.asarray, per_problem)
    P_ = jax.tree_util.tree_leaves(per_problem)[0].shape[0]
    mesh = _mesh(P_) if shard in (None, True) else None
    if mesh is None and P_ > RUN_CHUNK:
        # Large batches in chunks of RUN_CHUNK problems (the last one padded to it: one compilation): the start
        # candidates' predictions alone are 180 x 32 values per problem (1.4 GB for 30,000 problems), and one call
        # of that size hung in XLA's CPU runtime here (batch 10,000 x 3, every thread idle).
        parts = [_run(stage, cfg, False, r, *jax.tree_util.tree_map(lambda x: x[i:i + RUN_CHUNK], per_problem))
                 for i in range(0, P_, RUN_CHUNK)]
        return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)
    n_dev = 1 if mesh is None else mesh.size
    pad = (RUN_CHUNK if P_ > RUN_CHUNK // 2 and mesh is None else _bucket(P_, n_dev)) - P_
    if pad:
        per_problem = jax.tree_util.tree_map(lambda x: np.concatenate([x, np.repeat(x[-1:], pad, axis=0)]),
                                             per_problem)
    r = np.asarray(r)
    if mesh is not None:
        from jax.sharding import NamedSharding
        from jax.sharding import PartitionSpec as P

        r = jax.device_put(r, NamedSharding(mesh, P()))
        per_problem = jax.tree_util.tree_map(lambda x: jax.device_put(x, NamedSharding(mesh, P("batch"))),
                                             per_problem)
    key, ops = _split(cfg)
    with trusted_traces():  # inputs validated on the host: no host callbacks, so the persistent cache can store it
        if stage == "fit" and mesh is None:
            out = _exported_fit(key, r, ops, per_problem)
        else:
            out = _compiled(stage, key)(r, ops, *per_problem)
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[:P_], out)  # drop the padding


def _exported_fit(cfg, r, ops, per_problem):
    """The fused fit through :mod:`jax.export` (:func:`jaxsss._exported.exported_program`, keyed by the
    configuration): a new process skips tracing and lowering (~1 s of a warm first fit on this machine) and the
    compilation cache serves the rest. The status leaves as its integer code (the exported output holds plain arrays)
    and becomes an ``optimistix.RESULTS`` again here. Without an export directory, or for a user's registered model
    (the source digest covers jaxsss and fitting, not the model's own code), the jitted function as before."""
    own = resolve_model(cfg.model).evaluate.__module__.split(".")[0] in ("fitting", "jaxsss")
    fn = _compiled("fit", cfg, False)

    def plain(r, ops, *a):
        out, *rest = fn(r, ops, *a)
        return ({**out, "result": out["result"]._value}, *rest)

    program = exported_program("fit", repr(cfg), plain, (r, ops, *per_problem), compile_bound_options()) if own \
        else None
    if program is None:
        return _compiled("fit", cfg)(r, ops, *per_problem)
    out, *rest = program(r, ops, *per_problem)
    out = {**out, "result": results_from_code(out["result"])}
    return (out, *rest)


# Batches of more than FUSED_MAX problems (profiles x channels) run the LM loop in blocks of BLOCK_STEPS iterations
# over at most SLOTS problems at a time; a converged problem leaves its slot and the next start takes it, so the
# batch costs about its mean iteration count, not its largest (issue 18: 143 iterations against a mean of 18.5).
RUN_CHUNK = 4096  # problems per call of the starts and finish stages (see _run)
R_MAX_SLACK = 1.25  # a fit's range may end this factor past the model's r_max_ld l_d at the solution, no more
FUSED_MAX = 64
SLOTS = 512
BLOCK_STEPS = 8


@lru_cache(maxsize=16)
def _compiled_block(key: K.Config):
    """The jitted slot block; ``key`` is :func:`_split`'s (the model's operands are an argument)."""
    def block(r, ops, state, pidx, y, se, mask, eta, d):
        cfg = _bind(key, ops)

        def one(st, i):
            w = K.weights(y[i], se[i], cfg)[0]
            return K.lm_block(st, (r, y[i], w, mask[i], eta[i], d[i], cfg), cfg, BLOCK_STEPS)

        return jax.vmap(one)(state, pidx)

    return jax.jit(block, compiler_options=compile_bound_options())


def _solve_slots(cfg, r, theta0, mask, y, se, eta, d):
    """The native LM from every start of every problem, ``theta0 (P, S, p)``, in slot blocks (see :data:`SLOTS`):
    ``(thetas (P, S, p), results (P, S), steps (P, S), stationary (P, S))``.

    Slots hold problems; after each block of :data:`BLOCK_STEPS` iterations the host records the stopped ones and
    refills their slots from the queue. When the queue is empty and at most a quarter of the slots still run, the
    survivors move to a block a quarter of the width (a power of two, at least 8), so the tail of slow problems does
    not run at the full width."""
    P_, S, p = theta0.shape
    Q = P_ * S
    starts0 = np.asarray(theta0).reshape(Q, p)
    limits0 = np.tile(np.asarray(K.step_limits(S, cfg)), P_)
    # The problems' data go to the device once, padded to a bucketed count (one compilation per bucket, not per
    # batch size); each block gathers its slots' problems there.
    pad = _bucket(P_) - P_
    data = [np.asarray(a) for a in (y, se, mask, np.broadcast_to(eta, (P_,)), np.broadcast_to(d, (P_,)))]
    if pad:
        data = [np.concatenate([a, np.repeat(a[-1:], pad, axis=0)]) for a in data]
    y, se, mask, eta, d = (jax.device_put(a) for a in data)
    n = min(_bucket(Q), SLOTS)
    slot_q = np.full(n, -1)
    theta = np.zeros((n, p))
    lam, nu = np.full(n, K.LM_LAMBDA0), np.full(n, 2.0)
    steps, status = np.zeros(n, np.int32), np.full(n, K._CONVERGED, np.int32)
    limit = np.ones(n, np.int32)
    out_theta, out_steps, out_status = np.zeros((Q, p)), np.zeros(Q, np.int32), np.zeros(Q, np.int32)
    nxt = 0
    r = jnp.asarray(r)
    key, ops = _split(cfg)
    while True:
        # Refill the free slots from the queue.
        free = np.flatnonzero(slot_q < 0)
        take = min(free.size, Q - nxt)
        if take:
            f = free[:take]
            slot_q[f] = np.arange(nxt, nxt + take)
            theta[f], lam[f], nu[f], steps[f], status[f] = starts0[nxt:nxt + take], K.LM_LAMBDA0, 2.0, 0, K._RUNNING
            limit[f] = limits0[nxt:nxt + take]
            nxt += take
        active = np.flatnonzero(slot_q >= 0)
        if active.size == 0:
            break
        if nxt == Q and active.size <= n // 4 and n > 8:
            # Compact the survivors into a narrower block.
            m = max(8, n // 4)
            keep = np.concatenate([active, np.flatnonzero(slot_q < 0)[:m - active.size]])
            slot_q, theta, lam, nu, steps, status, limit = (a[keep] for a in (slot_q, theta, lam, nu, steps, status,
                                                                              limit))
            n = m
        state = K.LMState(*(jnp.asarray(a) for a in (theta, lam, nu, steps, status, limit)))
        with trusted_traces():
            state = _compiled_block(key)(r, ops, state, jnp.asarray(np.maximum(slot_q, 0) // S), y, se, mask, eta, d)
        theta, lam, nu, steps, status, limit = (np.array(x) for x in state)
        done = (status != K._RUNNING) & (slot_q >= 0)
        if np.any(done):
            q = slot_q[done]
            out_theta[q], out_steps[q], out_status[q] = theta[done], steps[done], status[done]
            slot_q[done] = -1
            status[done] = K._CONVERGED  # an empty slot is a frozen one
    status = out_status.reshape(P_, S)
    return (jnp.asarray(out_theta.reshape(P_, S, p)), K.status_result(status), jnp.asarray(out_steps.reshape(P_, S)),
            jnp.asarray(status == K._CONVERGED))


def _solve(cfg, shard, r, theta0, mask, y, se, eta, d):
    if cfg.native and theta0.shape[0] * theta0.shape[1] > FUSED_MAX:
        return _solve_slots(cfg, r, theta0, mask, y, se, eta, d)
    return _run("solve", cfg, shard, r, theta0, mask, y, se, eta, d)


# --- Public entry points ------------------------------------------------------------------------------------------
RADII_BUCKET_MIN = 64  # the radii are padded to a power of two of at least this many, up to ...
RADII_BUCKET_STEP = 512  # ... this many, then to a multiple of it


def _radii_bucket(n: int) -> int:
    """The padded radius count (:func:`_pad_radii`): a power of two of at least :data:`RADII_BUCKET_MIN`, then a
    multiple of :data:`RADII_BUCKET_STEP`."""
    if n > RADII_BUCKET_STEP:
        return -(-n // RADII_BUCKET_STEP) * RADII_BUCKET_STEP
    return max(RADII_BUCKET_MIN, 1 << (n - 1).bit_length())


def _pad_radii(r, y, se):
    """``(r, y, se)`` padded along the radii to :func:`_radii_bucket`: copies of the last radius with ``y = 0`` and
    ``se = -1``, which :func:`fitting._kernel.weights` never uses and :func:`fitting._kernel.score_radii` skips. The
    compiled fit is keyed by the shapes, so profiles of 65 to 128 radii share one compilation (tens of seconds for a
    tabulated model) instead of one per length; the padded points cost at most twice the evaluations."""
    n = r.shape[0]
    pad = _radii_bucket(n) - n
    if not pad:
        return r, y, se
    r = np.concatenate([r, np.full(pad, r[-1])])
    widths = [(0, 0)] * (np.ndim(y) - 1) + [(0, pad)]
    return r, np.pad(y, widths), np.pad(se, widths, constant_values=-1.0)


def _unpack_data(r, R, R_stderr, T, T_stderr):
    if isinstance(r, ProfileData):
        if any(x is not None for x in (R, R_stderr, T, T_stderr)):
            raise ValueError("fit_profile(ProfileData, ...): do not also pass R/T arrays")
        return r.r, r.R, r.R_stderr, r.T, r.T_stderr
    return r, R, R_stderr, T, T_stderr


STATIC_BUCKET = 4  # integer static settings (the multipole's pair count) are rounded up to powers of this ...
STATIC_MIN = 16  # ... and at least this


def _static_bucket(n, cap):
    """An integer static setting rounded up to a power of :data:`STATIC_BUCKET` (at least :data:`STATIC_MIN`),
    capped at ``cap``. Each distinct value is a compilation of the solve and finish stages (tens of seconds for the
    multipole on this machine; a sweep of 40 slabs took 730 s with a power of 2); more image pairs than needed only
    add terms below the tolerance, so a coarse rounding costs at most 4x in evaluation and buys few compilations."""
    if not isinstance(n, (int, np.integer)):
        return n
    b = STATIC_MIN
    while b < n:
        b *= STATIC_BUCKET
    return int(min(b, cap)) if cap is not None else int(b)


def _model_noise(model, cfg, r, mask, out) -> np.ndarray:
    """Median over each fit's range (``mask (P, K, N)``) of the model's relative noise at the solution: ``(P,)``."""
    sa, ss = np.asarray(out["sigma_a"]), np.asarray(out["sigma_s_prime"])
    rel = np.asarray(model.noise(np.asarray(r)[None, :], sa[:, None], ss[:, None], cfg.static))  # (P, N)
    used = np.any(mask, axis=1)  # (P, N): radii in the range of any output
    return np.array([np.median(rel[i][used[i]]) if used[i].any() else 0.0 for i in range(rel.shape[0])])


def _prepare_static(model, problem, sa, ss, eta, fresnel, notes):
    """The model's static setting for the given (concrete) parameters of every problem; if the model cannot settle
    one (e.g. the multipole's pair count for an almost non-absorbing slab), its ``static_cap`` with a note."""
    medium = jaxsss.Medium(np.asarray(sa), np.asarray(ss), np.asarray(eta), fresnel=fresnel)
    try:
        return model.prepare(problem.r, medium, problem.d)
    except ValueError as err:
        note = f"{model.name}: static setting capped at {model.static_cap} ({' '.join(str(err).split())})"
        if note not in notes:
            notes.append(note)
        return model.static_cap


def _configure(owner, model, pb, g, free_eta):
    """The static setting fixed by the fit's settings (the ``mc`` model's table), or ``None``; checks ``g``."""
    if g is not None and not model.uses_g:
        raise ValueError(f"{owner}(g={g!r}) applies to the transport model only ('mc'), not model={model.name!r}")
    if g is not None:
        g = float(_as_array(g, "g", owner))
        if not -1.0 < g < 1.0:
            raise ValueError(f"{owner}(g={g:g}) is outside the allowed range (-1, 1)")
    if model.configure is None:
        return None
    if free_eta:
        raise ValueError(f"{owner}(free_eta=True) is not available for model={model.name!r}: its table fixes eta")
    return model.configure(owner, pb.eta, g)


def _fit(owner, batched, r, R, R_stderr, T, T_stderr, *, eta, model, thickness, relative, free_eta, r_min, r_max,
         solver, rtol, atol, max_steps, fresnel, warn, shard=None, g=None):
    t0 = time.perf_counter()
    model = resolve_model(model)
    resolve_solver(solver)
    resolve_fresnel_method(fresnel)  # validates the F_dr method name (lists the valid ones)
    r, R, R_stderr, T, T_stderr = _unpack_data(r, R, R_stderr, T, T_stderr)
    pb = _Problem(owner, r, R, R_stderr, T, T_stderr, eta, thickness, model, batched, r_min, r_max)
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"{owner}(max_steps={max_steps!r}) must be an int >= 1")
    static0 = _configure(owner, model, pb, g, free_eta)
    cfg = K.Config(model=model.name, static=static0, outputs=pb.outputs,
                   relative=bool(relative), free_eta=bool(free_eta), solver=solver,
                   rtol=float(rtol), atol=float(atol), max_steps=int(max_steps), fresnel=fresnel)
    source_bin = False
    if model.name == "mc" and r_min is None and pb.r[0] > 0:
        # Binned data (e.g. `jaxsss mc`): radii at the centres of equal bins starting at 0. The first bin holds the
        # source, where R is steep (~1/r): its average is far from the transport point value at its centre (3% bias
        # in sigma_a at albedo 0.99, 100 bins), so the default range starts at the second bin.
        from fitting.io import equal_bin_edges

        if equal_bin_edges(pb.r) is not None:
            source_bin = True
            pb.r_lo = np.maximum(pb.r_lo, 0.5 * (pb.r[0] + pb.r[1]))
    n_r = len(pb.r)
    r, y, se = _pad_radii(pb.r, pb.y, pb.se)
    eta_p, d = pb.eta, pb.d
    per_problem = (y, se, eta_p, d, pb.r_lo, pb.r_hi, pb.auto)
    notes = []
    P_ = pb.B * pb.C
    if model.prepare is None and not (cfg.native and P_ * K.N_STARTS > FUSED_MAX):
        # One compiled call: starts, solves from every start, choice and checks.
        out, theta0, mask, r_cut, flags = _run("fit", cfg, shard, r, *per_problem)
    else:
        # Models with a static setting score the start candidates with a fixed, cheap one (ranking needs no
        # precision, and a fixed value means one compilation for every data set).
        cfg_s = cfg._replace(static=model.guess_static) if model.prepare is not None else cfg
        theta0, mask, r_cut, flags = _run("starts", cfg_s, shard, r, *per_problem)
        # Solve; for models with a static setting, re-solve if the solution needs a larger one. The static setting is
        # chosen at the start with a factor 2 margin (the solution usually needs no more, so one compilation
        # serves); if the solution needs more, solve again from it and add the iterations.
        steps_total = 0
        start = theta0

        def static_need(theta):
            # The setting every start (or solution) needs, each at its own parameters (eta too when it is free).
            p = np.exp(np.asarray(theta))
            return max(_prepare_static(model, pb, p[:, i, 0], p[:, i, 1], p[:, i, -1] if cfg.free_eta else eta_p,
                                       fresnel, notes) for i in range(p.shape[1]))

        for attempt in range(3):
            if model.prepare is not None:
                need = static_need(start)
                cfg = cfg._replace(static=_static_bucket(max(2 * need, cfg.static if attempt else 0),
                                                         model.static_cap))
            thetas, results, steps, stationary = _solve(cfg, shard, r, start, mask, y, se, eta_p, d)
            steps_total = steps_total + steps
            if model.prepare is None:
                break
            need = static_need(thetas)
            if need <= cfg.static:
                break
            start = thetas
        for _ in range(K.VALLEY_ROUNDS if model.rough else 0):
            # Two more starts along the valley of the best solution (tabulated models; fitting._kernel.valley_starts).
            v0 = _run("valley", cfg, shard, r, thetas, results, steps_total, stationary, mask, y, se, eta_p, d)
            extra = _solve(cfg, shard, r, v0, mask, y, se, eta_p, d)
            thetas, results, steps_total, stationary = jax.tree_util.tree_map(
                lambda a, b: np.concatenate([np.asarray(a), np.asarray(b)], axis=1),
                (thetas, results, steps_total, stationary), tuple(extra))
        out = _run("finish", cfg, shard, r, thetas, results, steps_total, stationary, mask, y, se, eta_p, d)
    out = jax.block_until_ready(out)
    seconds = time.perf_counter() - t0
    slope_failed, fallback, ratio_raised = (np.asarray(f) for f in flags)
    if np.any(slope_failed):
        notes.append(f"initial guess: no usable far-field decay for {int(np.sum(slope_failed))} fit(s); l_d set to "
                     "the span of the radii")
    ratio_min = None if model.ratio_min is None else float(model.ratio_min(cfg.static))
    if np.any(ratio_raised):
        notes.append(f"initial guess: sigma_a / sigma_s' raised to {ratio_min:.3g} (the {model.name} model's "
                     f"validity limit) for {int(ratio_raised.sum())} fit(s)")
    if np.any(fallback):
        notes.append(f"fit range: fewer than {cfg.n_params + 1} points beyond r_min for {int(np.sum(fallback))} "
                     "fit(s); all radii in [r_min, r_max] used there")

    if r_min is None:
        reason = "default: " + model.range_reason
        if source_bin:
            reason += ("; the first radius left out: the data look like centres of equal bins from r = 0, and the "
                       "first bin's average over the source is not the model's point value")
    else:
        reason = f"user: r_min = {_mm(r_min)}"
    if r_max is not None:
        reason += f"; r_max = {_mm(r_max)}"
    elif model.r_max_ld is not None:
        reason += f"; r_max = {model.r_max_ld:g} l_d at the initial guess (the {model.name} model's validity)"
    else:
        reason += "; r_max = all radii"
    if not all(pb.has_stderr):
        reason += "; points with data <= 0 left out (relative weights)"
    corr = np.asarray(out["correlation"])
    cond = np.asarray(out["condition_number"])
    identifiable = (np.abs(corr) <= CORRELATION_LIMIT) & (cond <= CONDITION_LIMIT)
    if model.rough and relative:
        # Relative data of a tabulated model from beyond ROUGH_RELATIVE_R_MIN_LD: sigma_a and sigma_s' not separable.
        sa_f, ss_f = np.asarray(out["sigma_a"]), np.asarray(out["sigma_s_prime"])
        far = np.asarray(out["r_min"]) * np.sqrt(3.0 * sa_f * (sa_f + ss_f)) > ROUGH_RELATIVE_R_MIN_LD
        if np.any(far):
            identifiable = identifiable & ~far
            notes.append(f"{int(far.sum())} fit(s) of relative data start beyond {ROUGH_RELATIVE_R_MIN_LD:g} l_d: "
                         f"the {model.name} model's table noise (~1% far out) is as large as what separates "
                         "sigma_a from sigma_s' there, so they are reported as not identifiable")
    model_warnings = []
    if ratio_min is not None:
        ratio = np.asarray(out["sigma_a"]) / np.asarray(out["sigma_s_prime"])
        outside = ratio < ratio_min * (1.0 - 1e-9)
        if np.any(outside):
            i = int(np.argmax(outside))
            model_warnings.append(
                f"{int(outside.sum())} of {outside.size} fits left the {model.name} model's validity range "
                f"sigma_a / sigma_s' >= {ratio_min:.3g} (first: fit {i}: {ratio[i]:.3g}); the table loses long paths "
                "there and the solution is biased (sigma_a too low)")
    if model.r_max_ld is not None:
        # The range past the model's validity (a user's r_max, or a solution far from the start): say so.
        sa_f, ss_f = np.asarray(out["sigma_a"]), np.asarray(out["sigma_s_prime"])
        ld_f = 1.0 / np.sqrt(3.0 * sa_f * (sa_f + ss_f))
        past = np.asarray(out["r_max"]) > R_MAX_SLACK * model.r_max_ld * ld_f
        if np.any(past):
            i = int(np.argmax(past))
            model_warnings.append(
                f"{int(past.sum())} of {past.size} fits used radii beyond the {model.name} model's validity "
                f"r <= {model.r_max_ld:g} l_d (first: fit {i}: r_max = {float(np.asarray(out['r_max'])[i]):.3g} mm "
                f"= {float(np.asarray(out['r_max'])[i] / ld_f[i]):.3g} l_d); the far field's table noise can make "
                "local minima -- give a smaller r_max")
    if model.noise is not None:
        # The model's own Monte Carlo noise over each fit's range, at the solution (MODEL_NOISE_LIMIT).
        noisy = _model_noise(model, cfg, pb.r, np.asarray(mask)[..., :n_r], out)
        if np.any(noisy > MODEL_NOISE_LIMIT):
            i = int(np.argmax(noisy > MODEL_NOISE_LIMIT))
            model_warnings.append(
                f"{int((noisy > MODEL_NOISE_LIMIT).sum())} of {noisy.size} fits lie where the {model.name} model's own "
                f"Monte Carlo noise exceeds {MODEL_NOISE_LIMIT:.0%} per annulus (first: fit {i}: median "
                f"{noisy[i]:.1%} over its range): the table's noise can hold the solver in a wrong minimum -- use "
                "radii where the model is precise (nearer the source at weak absorption, farther at strong)")
    u = pb.unflatten
    zeros = np.zeros(pb.B * pb.C)
    res = ProfileFit(
        sigma_a=u(out["sigma_a"]), sigma_s_prime=u(out["sigma_s_prime"]),
        sigma_a_stderr=u(out["sigma_a_stderr"]), sigma_s_prime_stderr=u(out["sigma_s_prime_stderr"]),
        correlation=u(corr), scale=u(out["scale"]), scale_stderr=u(out.get("scale_stderr", zeros)),
        eta=u(out["eta"]), eta_stderr=u(out.get("eta_stderr", zeros)), residual_norm=u(out["residual_norm"]),
        reduced_chi2=u(out["reduced_chi2"]), n_points=u(out["n_points"]), r_min=u(out["r_min"]),
        r_max=u(out["r_max"]), r_cut=u(r_cut), iterations=u(out["iterations"]),
        result=jax.tree_util.tree_map(u, out["result"]), condition_number=u(cond), identifiable=u(identifiable),
        guess_sigma_a=u(np.exp(theta0[:, 0, 0])), guess_sigma_s_prime=u(np.exp(theta0[:, 0, 1])),
        thickness=u(pb.d) if model.needs_thickness else None, model=model.name, solver=solver,
        outputs=pb.outputs, relative=bool(relative), free_eta=bool(free_eta), range_reason=reason,
        notes=tuple(notes), seconds=seconds, static=cfg.static, fresnel=fresnel,
        model_warnings=tuple(model_warnings), suspect=u(out["suspect"]), alt_sigma_a=u(out["alt_sigma_a"]),
        alt_sigma_s_prime=u(out["alt_sigma_s_prime"]), alt_cost_ratio=u(out["alt_cost_ratio"]),
        residual_autocorrelation=u(out["residual_autocorrelation"]),
    )
    if warn:
        for text in res.warnings:
            warnings.warn(text, FitWarning, stacklevel=3)
    return res


def _mm(x) -> str:
    a = np.asarray(x, dtype=np.float64)
    return f"{float(a):g} mm" if a.ndim == 0 else f"{a.min():g}-{a.max():g} mm (per fit)"


_DOC_ARGS = """
    Args:
        r: radii, mm, 1-D, ``>= 0`` and strictly increasing (shared by every profile and channel); or a
            :class:`fitting.ProfileData` (then leave R/T out).
        R, T: measured reflectance / transmittance profiles, 1/mm^2 per incident photon (absolute) or any unit
            (``relative=True``). {shape}
        R_stderr, T_stderr: optional per-point standard errors (same shape, ``> 0``): weights ``1 / stderr``.
            Without them the residuals are relative, ``(model - data) / data``.
        eta: relative index ``n_inside / n_outside`` (``> 0``), scalar or broadcasting to {eta_shape}. Fixed unless
            ``free_eta``.
        model: forward model name (:data:`fitting.FORWARD_MODELS`: ``"dipole"``, ``"multipole"``, ``"mc"``).
        thickness: slab thickness, mm (models that need it only), broadcasting like ``eta``.
        relative: the data carry an unknown positive scale, fitted per channel.
        free_eta: also fit ``eta`` (per channel).
        r_min, r_max: fit range in mm, scalars or broadcasting like ``eta``. Default ``r_min``: one transport mean
            free path ``l_u`` at the initial guess (``0.1 l_u`` for ``"mc"``); default ``r_max``: all radii.
        solver: :data:`fitting.SOLVERS` name (``"levenberg_marquardt"``, ``"gauss_newton"``, ``"dogleg"``).
        rtol, atol: solver tolerances (on the log-parameters and the residual norm).
        max_steps: iteration cap; fits that hit it report ``converged = False``.
        fresnel: ``F_dr`` method of the models (``"poly"`` or ``"exact"``).
        warn: emit :class:`FitWarning` for non-converged or non-identifiable fits (the flags are in the result
            either way).
        g: Henyey-Greenstein anisotropy, fixed: required by ``model="mc"`` (with ``eta`` it picks the white Monte
            Carlo table, :func:`jaxsss.mc.available_white_tables`), rejected by the diffusion models (they depend on
            ``sigma_s'`` only).

    Returns:
        :class:`fitting.ProfileFit`.
"""


def fit_profile(r, R=None, *, T=None, R_stderr=None, T_stderr=None, eta, model="dipole", thickness=None,
                relative=False, free_eta=False, r_min=None, r_max=None, solver="levenberg_marquardt",
                rtol=DEFAULT_RTOL, atol=DEFAULT_ATOL, max_steps=256, fresnel="poly", warn=True, g=None) -> ProfileFit:
    """Fit ``sigma_a`` and ``sigma_s'`` to one profile (all its channels in one compiled call)."""
    return _fit("fit_profile", False, r, R, R_stderr, T, T_stderr, eta=eta, model=model, thickness=thickness,
                relative=relative, free_eta=free_eta, r_min=r_min, r_max=r_max, solver=solver, rtol=rtol, atol=atol,
                max_steps=max_steps, fresnel=fresnel, warn=warn, g=g)


def fit_profiles(r, R=None, *, T=None, R_stderr=None, T_stderr=None, eta, model="dipole", thickness=None,
                 relative=False, free_eta=False, r_min=None, r_max=None, solver="levenberg_marquardt",
                 rtol=DEFAULT_RTOL, atol=DEFAULT_ATOL, max_steps=256, fresnel="poly", warn=True,
                 shard=None, g=None) -> ProfileFit:
    """Fit a batch of profiles on one radius grid in one compiled, vmapped call.

    With several JAX devices (``jax.devices()``) the problems (profiles x channels) are split over a 1-D mesh with
    a :class:`jax.sharding.NamedSharding` on the inputs (padded to a multiple of the device count) and jit's SPMD
    partitioner; the devices only agree on when the batched solver loop stops. ``shard=False`` keeps everything on one device; ``None`` (default) shards when possible.
    """
    return _fit("fit_profiles", True, r, R, R_stderr, T, T_stderr, eta=eta, model=model, thickness=thickness,
                relative=relative, free_eta=free_eta, r_min=r_min, r_max=r_max, solver=solver, rtol=rtol, atol=atol,
                max_steps=max_steps, fresnel=fresnel, warn=warn, shard=shard, g=g)


fit_profile.__doc__ += _DOC_ARGS.format(shape="Shape ``(N,)`` or ``(N, C)`` for ``C`` channels.",
                                        eta_shape="``(C,)``")
fit_profiles.__doc__ += _DOC_ARGS.format(shape="Shape ``(B, N)`` or ``(B, N, C)`` for ``B`` profiles.",
                                         eta_shape="``(B, C)``").replace(
    "    Returns:", "        shard: see above.\n\n    Returns:")


@lru_cache(maxsize=16)
def _compiled_data_jacobian(key: K.Config):
    """The jitted data Jacobian of :func:`fit_jacobian_wrt_data`, ``(P, 2, K, N)``: :func:`fitting._kernel.
    solution_jacobian` per problem; ``key`` is :func:`_split`'s. One program with no solve in it: the eager
    ``jax.jacfwd`` of a re-solve with Optimistix's implicit adjoint that it replaces took 8.7 s per call on a
    3-channel, 40-radius profile, and its linear solve's error check (a host callback) kept it out of the cache."""
    def jacobian(r, ops, theta, mask, y, se, eta, d):
        cfg = _bind(key, ops)
        return jax.vmap(lambda th, m, yy, s, e, dd: K.solution_jacobian(th, m, r, yy, s, e, dd, cfg))(
            theta, mask, y, se, eta, d)

    return jax.jit(jacobian, compiler_options=compile_bound_options())


def fit_jacobian_wrt_data(r, R=None, *, T=None, R_stderr=None, T_stderr=None, eta, model="dipole", thickness=None,
                          relative=False, r_min=None, r_max=None, solver="levenberg_marquardt", rtol=DEFAULT_RTOL,
                          atol=DEFAULT_ATOL, max_steps=256, fresnel="poly", g=None):
    """Derivatives of the fitted ``(sigma_a, sigma_s')`` with respect to the data, by the implicit function theorem.

    The fit (same arguments as :func:`fit_profile`, one profile) is solved first; at its solution the sum of squares
    is stationary in the log-parameters, and the implicit function theorem on that condition gives the derivatives
    (:func:`fitting._kernel.solution_jacobian`). The fit range is held fixed (a discrete choice). Linear error
    propagation follows: ``cov(theta) ~ J_data cov(data) J_data^T``. Where the data do not fix the parameters (a
    singular or near-singular Hessian of the sum of squares) the derivatives are non-finite or huge: check the fit's
    standard errors first.

    Returns:
        ``{"R": dR, "T": dT}`` for the outputs given, each of shape ``(*channels, 2, N)``: ``[..., 0, i]`` is
        ``d sigma_a / d data_i`` and ``[..., 1, i]`` is ``d sigma_s' / d data_i`` (1/mm per data unit). Channels are
        independent, so cross-channel derivatives are zero and not returned.
    """
    fit = fit_profile(r, R, T=T, R_stderr=R_stderr, T_stderr=T_stderr, eta=eta, model=model, thickness=thickness,
                      relative=relative, r_min=r_min, r_max=r_max, solver=solver, rtol=rtol, atol=atol,
                      max_steps=max_steps, fresnel=fresnel, warn=False, g=g)
    mdl = resolve_model(model)
    r_, R_, Rs_, T_, Ts_ = _unpack_data(r, R, R_stderr, T, T_stderr)
    pb = _Problem("fit_jacobian_wrt_data", r_, R_, Rs_, T_, Ts_, eta, thickness, mdl, False, r_min, r_max)
    cfg = K.Config(model=mdl.name, static=fit.static, outputs=pb.outputs,
                   relative=bool(relative), free_eta=False, solver=solver,
                   rtol=float(rtol), atol=float(atol), max_steps=int(max_steps), fresnel=fresnel)
    flat = lambda x: jnp.reshape(jnp.asarray(x), (-1,))  # noqa: E731
    cols = [jnp.log(flat(fit.sigma_a)), jnp.log(flat(fit.sigma_s_prime))]
    if relative:
        cols.append(jnp.log(flat(fit.scale)))
    theta = jnp.stack(cols, axis=1)
    # The fit range the fit used, rebuilt from its recorded cut (held fixed under differentiation).
    y, se = jnp.asarray(pb.y), jnp.asarray(pb.se)
    _, usable = jax.vmap(lambda a, b: K.weights(a, b, cfg))(y, se)
    rr = jnp.asarray(pb.r)
    inside = (rr >= jnp.asarray(pb.r_lo)[:, None]) & (rr <= jnp.asarray(pb.r_hi)[:, None])
    cut = flat(fit.r_cut)
    mask = usable & (inside & (rr[None, :] >= jnp.minimum(cut, flat(fit.r_min))[:, None]))[:, None, :]

    # The solver's settings do not enter the derivatives at the solution: one program whatever they were.
    key, ops = _split(cfg._replace(solver="", rtol=0.0, atol=0.0, max_steps=0))
    with trusted_traces():  # the data were checked by the fit above: no host callbacks, so the cache stores it
        diag = _compiled_data_jacobian(key)(rr, ops, theta, mask, y, se, jnp.asarray(pb.eta), jnp.asarray(pb.d))
    out = {}
    for k, name in enumerate(pb.outputs):
        block = np.asarray(diag[:, :, k, :])
        out[name] = block.reshape(pb.batch_shape[-1:] + (2, pb.N)) if pb.batch_shape else block[0]
    return out
