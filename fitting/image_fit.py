"""Recover ``sigma_a`` and ``sigma_s'`` per channel from a rendered image (issue 5, "Differentiable in the material").

Every registered render method exposes ``image = prepared.image(medium)`` once its geometry is fixed
(:func:`jaxsss.render.prepare_method`; the methods are those of :func:`jaxsss.render.method_names`).
:func:`fit_image` looks the method up, builds that function on a random subset of the object's pixels,
starts from the best of a small grid of (Rd, l_d) candidates per channel (through the reparameterisation, so the start
is physically sensible without knowing the answer; ``Rd`` taken between the grid's nodes by interpolating the
residuals, :data:`RD_START_FINE`), and runs an Optimistix least-squares solve in the
log-parameters. Residuals are relative: ``(model - target) / mean(target)`` per channel, on the chosen pixels, or
``(model - target) / target_stderr`` when the target's per-pixel standard errors are given.

Several views (issue 17, item 4). One light on a sphere fixes ``Rd`` well but barely ``l_d``: the image is mostly the
total diffuse reflectance times the irradiance, and ``l_d`` shows only in the blur at shadow edges and the
terminator. ``scene`` and ``target_image`` may be sequences (the same object and material under several lights or
from several cameras); their residuals are stacked into one least-squares problem.

Standard errors. At the solution the Jacobian ``J`` of the weighted residuals gives ``Cov(theta) = s^2 (J^T J)^-1``
in ``theta = (log sigma_a, log sigma_s')``; ``s^2`` is the residual variance ``RSS / (m - p)`` for relative
residuals, and ``max(1, RSS / (m - p))`` with ``target_stderr`` (inflated when the model misses by more than the
target's noise, as a path-traced reference shows it: the model's own error then sets the uncertainty). ``(Rd, l_d)``
and their errors follow by the delta method through :func:`jaxsss.to_rd_ld`. A model error is not noise: it is
smooth over the image, and neighbouring residuals share it, so the pixels carry fewer independent facts than their
count and ``s^2 (J^T J)^-1`` claims too much. Each standard error is therefore the larger of that and the
cluster-robust (sandwich) one over spatial blocks, ``(J^T J)^-1 (sum_b g_b g_b^T) (J^T J)^-1 K / (K - 1)`` with
``g_b = J_b^T r_b`` the score of block ``b`` (a :data:`BLOCK_GRID` x :data:`BLOCK_GRID` grid over each view, ``K`` the
blocks with fitted pixels): independent pixel noise gives about the same as the model-based one, while a smooth misfit
that pulls the parameters one way on one side of the object and another way elsewhere widens it (what the parameters
absorb alike everywhere leaves no trace in the residuals, and no estimate from them can show it). That part needs a
statement of the renderer's accuracy: ``model_error`` (a model discrepancy, Kennedy and O'Hagan 2001;
:mod:`fitting.discrepancy`) is the relative error the render method may have against the real light transport, alike
over the image per channel (its brightness) and, with a :class:`fitting.ModelError`, alike over each band of the
cosine to each light (the terminator, where the blur that separates ``sigma_a`` from ``sigma_s'`` is seen and where
the renderer is least accurate). Each mode's effect on the estimates, ``(J^T J)^-1 J^T d_j`` per unit error (``d_j``
the model's image in residual units on the mode's rows), enters the covariance with the mode's variance. It is 0 by
default (fitting the renderer's own images); for a photograph or a path-traced image, the renderer's measured
accuracy is the honest value (:data:`RENDER_MODEL_ERROR`, measured against Mitsuba). A channel is
**identifiable** when both coefficients have relative standard errors at most :data:`REL_STDERR_LIMIT` and their
correlation is at most :data:`fitting.CORRELATION_LIMIT`, and the fitted ``l_d`` spans at least
:data:`RESOLVED_LD_PIXELS` pixels on the object in the finest view (:func:`pixel_footprint`); otherwise the result's
``warnings`` say which parameter the views do not constrain and what they do constrain (usually ``Rd``).

Fixed during the fit: ``eta`` and ``g`` (from the scene), everything geometric (sample positions, octree centroids,
cache positions, photon walks), and the plan's shortcuts that depend on the material (cut-off radius, shared channel)
are switched off (``fit=True`` in the method's ``prepare``).
"""

from __future__ import annotations

import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import jaxsss
from jaxsss._config import compile_bound_options, render_jit
from jaxsss._exported import compiled_program
from jaxsss.validate import trusted_traces
from fitting.discrepancy import RENDER_MODEL_ERROR, ModelError, discrepancy_modes, light_key
from fitting.result import CORRELATION_LIMIT
from fitting.solvers import resolve_solver, results_from_code

__all__ = ["LD_CANDIDATES_MM", "RD_CANDIDATES", "REL_STDERR_LIMIT", "RENDER_MODEL_ERROR", "ImageFit", "ModelError",
           "fit_image"]

RD_CANDIDATES = (0.2, 0.5, 0.8, 0.95)
LD_CANDIDATES_MM = (0.3, 1.0, 3.0, 10.0)
"""The start grid: 16 (Rd, l_d) pairs per channel, each a full image evaluation on the fit's pixels."""
RD_START_FINE = tuple(np.round(np.linspace(0.02, 0.98, 97), 2))
"""The start's ``Rd`` per ``l_d`` candidate: each candidate's residuals interpolated linearly in ``Rd`` between the
grid's (extrapolated below 0.2) onto this finer set, and the best ``(Rd, l_d)`` of those taken. A coarse ``Rd`` step
favours the wrong ``l_d``: on the sky-lit skin1 sphere at eta 1.4 (red ``Rd`` 0.41, ``l_d`` 3.7 mm) the grid's best was
``(0.5, 0.3 mm)``, where a short ``l_d`` offsets the high ``Rd``, and the solve ended on the short-``l_d`` plateau
(``l_d`` 0.13 mm, ``Rd`` 0.47 +- 0.016, chi^2 per pixel 19 against 2.6 at the truth)."""
REL_STDERR_LIMIT = 0.3
"""A coefficient whose relative standard error exceeds this is reported as not constrained by the views."""
RESOLVED_LD_PIXELS = 2.0
"""The fitted ``l_d`` must span at least this many pixels on the object (:func:`pixel_footprint`, the finest view)
for ``sigma_a`` and ``sigma_s'`` to be reported apart: a blur narrower than two pixels is not resolved, and the split
then follows the renderer's model error, which the pixel noise's standard errors do not cover. Measured on the
Mitsuba skin1 references (docs/benchmarks.md, "fit_image from the Mitsuba skin1 image"): l_d of 4.6 pixels (red)
came back within 2-4%, 1.7 pixels (green) 9-10% off, 0.9 pixels (blue) 30-46% off, each with standard errors of 1-4%."""


class ImageFit(eqx.Module):
    """Result of :func:`fit_image`.

    Attributes:
        sigma_a, sigma_s_prime: ``(C,)`` estimates, 1/mm.
        start_sigma_a, start_sigma_s_prime: ``(C,)`` the grid start.
        result: the Optimistix ``RESULTS`` of the solve (``successful`` when converged).
        n_steps: solver steps taken.
        rms_relative: RMS of the relative residuals ``(model - target) / mean(target)`` at the solution.
        sigma_a_stderr, sigma_s_prime_stderr: ``(C,)`` standard errors, 1/mm (module docstring).
        rd, rd_stderr: ``(C,)`` total diffuse reflectance (Eq. 15) at the solution and its standard error.
        ld, ld_stderr: ``(C,)`` diffuse mean free path ``1 / sigma_tr`` (mm) and its standard error.
        correlation: ``(C,)`` correlation of ``log sigma_a`` and ``log sigma_s'``.
        stderr_inflation: ``(2C,)`` cluster-robust over model-based standard error of ``log sigma_a`` then
            ``log sigma_s'`` (module docstring): about 1 for pixel noise, well above 1 where a smooth model error
            drives the fit; the reported standard errors use the larger of the two.
        identifiable: ``(C,)`` booleans (module docstring).
        warnings: what the views do not constrain, one line per channel concerned.
        n_pixels: pixels used, over all views.
        n_views: number of (scene, target) pairs.
        seconds: ``{"prepare": ..., "compile": ..., "start": ..., "solve": ...}`` (compilation of the residuals and
            the solve apart; a second fit with the same pixel count and eps reuses the compilation).
    """

    sigma_a: jax.Array
    sigma_s_prime: jax.Array
    start_sigma_a: jax.Array
    start_sigma_s_prime: jax.Array
    result: optx.RESULTS
    n_steps: jax.Array
    rms_relative: jax.Array
    sigma_a_stderr: jax.Array
    sigma_s_prime_stderr: jax.Array
    rd: jax.Array
    rd_stderr: jax.Array
    ld: jax.Array
    ld_stderr: jax.Array
    correlation: jax.Array
    identifiable: jax.Array
    stderr_inflation: jax.Array
    n_pixels: int = eqx.field(static=True)
    seconds: dict = eqx.field(static=True)
    warnings: tuple = eqx.field(static=True, default=())
    n_views: int = eqx.field(static=True, default=1)

    @property
    def converged(self) -> bool:
        return bool(self.result == optx.RESULTS.successful)

    @property
    def message(self) -> str:
        return "converged" if self.converged else f"did not converge: {optx.RESULTS[self.result]}"

    def to_dict(self) -> dict[str, Any]:
        return jaxsss.json_ready({
            "sigma_a": self.sigma_a, "sigma_s_prime": self.sigma_s_prime,
            "start_sigma_a": self.start_sigma_a, "start_sigma_s_prime": self.start_sigma_s_prime,
            "converged": self.converged, "message": self.message, "n_steps": self.n_steps,
            "rms_relative": self.rms_relative, "sigma_a_stderr": self.sigma_a_stderr,
            "sigma_s_prime_stderr": self.sigma_s_prime_stderr, "rd": self.rd, "rd_stderr": self.rd_stderr,
            "ld": self.ld, "ld_stderr": self.ld_stderr, "correlation": self.correlation,
            "stderr_inflation": self.stderr_inflation,
            "identifiable": np.asarray(self.identifiable).tolist(), "warnings": list(self.warnings),
            "n_pixels": self.n_pixels, "n_views": self.n_views, "seconds": self.seconds,
        })


def _choose_pixels(target: np.ndarray, max_pixels: int | None, seed: int) -> np.ndarray:
    lit = np.asarray(target).sum(axis=-1) > 0
    idx = np.flatnonzero(lit)
    if len(idx) == 0:
        raise ValueError("fit_image(target_image=...) has no lit pixels to fit")
    if max_pixels is not None and len(idx) > max_pixels:
        idx = np.sort(np.random.default_rng(seed).choice(idx, size=max_pixels, replace=False))
    mask = np.zeros(lit.size, dtype=bool)
    mask[idx] = True
    return mask.reshape(lit.shape)


def _medium(theta, eta, g, fresnel):
    c = theta.shape[0] // 2
    # exp of the log-parameters is valid by construction: no traced checks, which are host callbacks and would keep
    # the compiled fit out of the persistent compilation cache (eta and g are host values, checked as such).
    with trusted_traces():
        return jaxsss.Medium(jnp.exp(theta[:c]), jnp.exp(theta[c:]), eta, g, fresnel=fresnel)


def _stacked_residuals(theta, args):
    """Weighted residuals of every view, stacked: ``(model - target) * weight`` on each view's fit pixels; each view
    is ``(H, W, C)`` flattened, so row ``i`` belongs to channel ``i % C``."""
    views, eta, g, fresnel = args
    medium = _medium(theta, eta, g, fresnel)
    return jnp.concatenate([jnp.where(mask[..., None], (prepared.image(medium) - target) * weight, 0.0).reshape(-1)
                            for prepared, target, weight, mask in views])


@eqx.filter_custom_jvp
def _channel_residuals(theta, args):
    """:func:`_stacked_residuals` with a derivative that uses the channels' independence: channel ``k`` of the image
    depends on ``theta[k]`` (log sigma_a) and ``theta[C + k]`` (log sigma_s') only, so the ``(m, 2C)`` Jacobian has
    two non-zero entries per row and comes from two tangent passes (all log sigma_a at once, all log sigma_s' at
    once) instead of ``2C``. Every render method is checked for this against ``jax.jacfwd`` in the tests, and
    :func:`_uncertainty` checks it again at each solution."""
    return _stacked_residuals(theta, args)


@_channel_residuals.def_jvp
def _channel_residuals_jvp(primals, tangents):
    theta, args = primals
    t_theta, _ = tangents
    if t_theta is None:
        return _stacked_residuals(theta, args), None
    c = theta.shape[0] // 2
    ones, zeros = jnp.ones(c, theta.dtype), jnp.zeros(c, theta.dtype)
    # Columns of J summed per parameter kind: row i holds dr_i/dlog sigma_a[ch(i)] and dr_i/dlog sigma_s'[ch(i)].
    # Both tangents in one vmapped jvp (the primal is unbatched, so computed once): tracing it takes 4.3 s for the
    # skin1 sphere's white kernel against 5.0 s for jax.linearize, and the fit's solve program traces in 6.5 s, not
    # 8.4 s (every new process pays this; the persistent cache keeps only compiled programs).
    rs, (d_a, d_s) = jax.vmap(lambda t: jax.jvp(lambda th: _stacked_residuals(th, args), (theta,), (t,)))(
        jnp.stack([jnp.concatenate([ones, zeros]), jnp.concatenate([zeros, ones])]))
    r = rs[0]
    ch = jnp.arange(r.shape[0]) % c
    return r, d_a * t_theta[ch] + d_s * t_theta[c + ch]


@render_jit
def _residuals(theta, args):
    """:func:`_channel_residuals`, compiled (the start grid, the solve and the standard errors call it)."""
    return _channel_residuals(theta, args)


@render_jit
def _solve(theta0, args, solver, max_steps):
    """The solve: ``(theta, status code, steps)`` (plain arrays, so that :mod:`jax.export` can keep it)."""
    sol = optx.least_squares(_residuals, solver, theta0, args=args, max_steps=max_steps, throw=False)
    return sol.value, sol.result._value, sol.stats["num_steps"]


def _grid_start(residuals, args, eta, n_channels):
    """Per channel, the start ``(sigma_a, sigma_s')``: the (Rd, l_d) grid's residuals (``residuals`` is the compiled
    :func:`_residuals`), interpolated in ``Rd`` onto :data:`RD_START_FINE` per ``l_d`` candidate, and the pair with the
    smallest sum of squares (residuals are linear in the image, and the image is smooth in ``Rd`` at a fixed
    ``l_d``)."""
    rd = np.repeat(RD_CANDIDATES, len(LD_CANDIDATES_MM))
    ld = np.tile(LD_CANDIDATES_MM, len(RD_CANDIDATES))
    rep = jaxsss.from_rd_ld(jnp.asarray(rd)[:, None] * jnp.ones(n_channels), jnp.asarray(ld)[:, None] *
                            jnp.ones(n_channels), eta)
    sa, ss = np.asarray(rep.medium.sigma_a), np.asarray(rep.medium.sigma_s_prime)  # (K, C)
    res = []
    for k in range(len(rd)):
        r = residuals(jnp.log(jnp.concatenate([jnp.asarray(sa[k]), jnp.asarray(ss[k])])), args)
        res.append(np.asarray(r).reshape(-1, n_channels))
    res = np.stack(res).reshape(len(RD_CANDIDATES), len(LD_CANDIDATES_MM), -1, n_channels)  # (Rd, l_d, pixels, C)
    nodes, fine = np.asarray(RD_CANDIDATES), np.asarray(RD_START_FINE)
    # Linear in Rd between the grid's nodes (the first and last segments extended).
    j = np.clip(np.searchsorted(nodes, fine) - 1, 0, len(nodes) - 2)
    t = ((fine - nodes[j]) / (nodes[j + 1] - nodes[j]))[:, None, None, None]
    interpolated = res[j] + t * (res[j + 1] - res[j])  # (F, l_d, pixels, C)
    cost = np.sum(interpolated**2, axis=2)  # (F, l_d, C)
    cost = np.where(np.isfinite(cost), cost, np.inf).reshape(-1, n_channels)
    best = np.argmin(cost, axis=0)
    rd_best = fine[best // len(LD_CANDIDATES_MM)]
    ld_best = np.asarray(LD_CANDIDATES_MM)[best % len(LD_CANDIDATES_MM)]
    start = jaxsss.from_rd_ld(jnp.asarray(rd_best), jnp.asarray(ld_best), eta).medium
    return np.asarray(start.sigma_a), np.asarray(start.sigma_s_prime)


def _check_target(target_image, scene, name: str) -> np.ndarray:
    target = np.asarray(target_image, dtype=np.float64)
    w, h = scene.camera.resolution
    if target.ndim != 3 or target.shape[:2] != (h, w):
        raise ValueError(f"fit_image({name}=...) has shape {target.shape}; the scene's camera gives ({h}, {w}, C)")
    if not np.isfinite(target).all() or (target < 0).any():
        raise ValueError(f"fit_image({name}=...) must be finite and non-negative")
    return target


def _as_views(scene, target_image, target_stderr):
    """``(scenes, targets, stderrs)`` as equal-length lists (one view, or sequences)."""
    many = isinstance(scene, (list, tuple))
    scenes = list(scene) if many else [scene]
    targets = list(target_image) if many else [target_image]
    if not scenes:
        raise ValueError("fit_image(scene=...) is an empty sequence; give at least one scene")
    if len(targets) != len(scenes):
        raise ValueError(f"fit_image(target_image=...) has {len(targets)} images for {len(scenes)} scenes; give one "
                         "per scene")
    stderrs = [None] * len(scenes) if target_stderr is None else (list(target_stderr) if many else [target_stderr])
    if len(stderrs) != len(scenes):
        raise ValueError(f"fit_image(target_stderr=...) has {len(stderrs)} images for {len(scenes)} scenes")
    return scenes, targets, stderrs


FD_STEP = 1e-5
"""Central-difference step in ``log sigma`` for the Jacobian behind the standard errors (relative error ~1e-10)."""


def _uncertainty(theta, residuals, args, n_res: int, absolute: bool, blocks: np.ndarray,
                 discrepancy=None):
    """Standard errors and ``(Rd, l_d)`` at the solution (module docstring). The Jacobian is taken by central
    differences of the already compiled ``residuals`` (2 p evaluations): ``jax.jacfwd`` gives the same to 1e-10 but
    costs a compilation of its own, longer than the whole fit on small images. ``discrepancy``: None, or ``(weighted
    target (m,), cosines (m / C, L), ModelError)``: the target times its weight on the fitted rows (else 0), from
    which the model image in residual units is the residual plus it, each pixel's cosine to the views' distinct
    lights, and the stated error (:mod:`fitting.discrepancy`)."""
    res = np.asarray(residuals(theta, args))
    steps = FD_STEP * np.eye(theta.shape[0])
    jac = np.stack([(np.asarray(residuals(theta + h, args)) - np.asarray(residuals(theta - h, args))) / (2 * FD_STEP)
                    for h in steps], axis=1)
    p = theta.shape[0]
    coupling = _channel_coupling(jac)
    s2 = float(res @ res) / max(n_res - p, 1)
    if absolute:
        s2 = max(1.0, s2)
    bread = np.linalg.pinv(jac.T @ jac)
    cov = s2 * bread
    c = p // 2
    se_model = np.sqrt(np.maximum(np.diag(cov), 0.0))
    cluster, n_blocks = _cluster_covariance(jac, res, bread, blocks, np.any(jac != 0.0, axis=1))
    if cluster is not None:
        # Each standard error the larger of the two; the correlations from the model-based covariance.
        scale = np.maximum(1.0, np.sqrt(np.maximum(np.diag(cluster), 0.0)) / np.maximum(se_model, 1e-300))
        cov = cov * np.outer(scale, scale)
    else:
        scale = np.full(p, np.nan)
    if discrepancy is not None:
        weighted_target, cosines, error = discrepancy
        # Model discrepancy: a relative error e_j of shape d_j moves theta by -(J^T J)^+ J^T d_j e_j.
        modes, sigma = discrepancy_modes(res + weighted_target, c, cosines, error)
        shift = bread @ (jac.T @ modes)  # (p, M): d theta per unit relative error of each mode
        cov = cov + (shift * sigma**2) @ shift.T
    se_log = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov[np.arange(c), c + np.arange(c)] / np.maximum(se_log[:c] * se_log[c:], 1e-300)

    def rd_ld(th):
        rd, ld = jaxsss.to_rd_ld(_medium(th, *args[1:]))
        return jnp.concatenate([rd, ld])

    grad = np.asarray(jax.jacfwd(rd_ld)(theta))
    rd_ld_value = np.asarray(rd_ld(theta))
    se_rd_ld = np.sqrt(np.maximum(np.diag(grad @ cov @ grad.T), 0.0))
    return se_log, corr, rd_ld_value, se_rd_ld, coupling, scale, n_blocks


CHANNEL_COUPLING_LIMIT = 1e-6
"""Largest ``|dr_i/dtheta_k|`` for a parameter ``k`` of another channel than row ``i``'s, relative to the largest
entry, that :func:`_channel_residuals` tolerates (central differences are accurate to ~1e-10 here)."""


def _channel_coupling(jac: np.ndarray) -> float:
    """Largest Jacobian entry that couples a residual to another channel's parameters, relative to the largest."""
    m, p = jac.shape
    c = p // 2
    ch = np.arange(m) % c
    own = (np.arange(p)[None, :] % c) == ch[:, None]
    scale = np.max(np.abs(jac), initial=0.0)
    return float(np.max(np.abs(np.where(own, 0.0, jac)), initial=0.0) / scale) if scale > 0 else 0.0


BLOCK_GRID = 4
"""Each view is cut into ``BLOCK_GRID x BLOCK_GRID`` spatial blocks for the cluster-robust standard errors."""
MIN_BLOCKS = 6
"""Fewest blocks with fitted pixels for the cluster-robust standard errors; with fewer, the model-based ones stand and
the result's warnings say so."""


def _blocks(views, n_channels: int) -> np.ndarray:
    """The spatial block of every residual row (views stacked, each ``(H, W, C)`` flattened): ``BLOCK_GRID^2`` blocks
    per view, numbered across views."""
    out = []
    for k, (_, target, _, _) in enumerate(views):
        h, w = target.shape[:2]
        y, x = np.mgrid[0:h, 0:w]
        block = (y * BLOCK_GRID // h) * BLOCK_GRID + x * BLOCK_GRID // w + k * BLOCK_GRID**2
        out.append(np.repeat(block.reshape(-1), n_channels))
    return np.concatenate(out)


def _cluster_covariance(jac: np.ndarray, res: np.ndarray, bread: np.ndarray, blocks: np.ndarray,
                        fitted: np.ndarray):
    """``(cov, K)``: the cluster-robust covariance ``B (sum_b g_b g_b^T) B K / (K - 1)``, ``bread = B = (J^T J)^+``
    and ``g_b = J_b^T r_b`` over the blocks with fitted rows (``fitted``), and their number ``K`` (``cov`` None below
    :data:`MIN_BLOCKS`)."""
    ids, which = np.unique(blocks[fitted], return_inverse=True)
    k = len(ids)
    if k < MIN_BLOCKS:
        return None, k
    scores = np.zeros((k, jac.shape[1]))
    np.add.at(scores, which, jac[fitted] * res[fitted, None])  # (K, p): each block's J_b^T r_b, one pass
    return bread @ (scores.T @ scores) @ bread * (k / (k - 1)), k


def pixel_footprint(scene) -> float:
    """Width of one pixel on the object, mm: ``2 d tan(fov / 2) / H`` at the distance ``d`` from the camera to the
    centre of the translucent mesh's bounding box (``fov_deg`` is vertical, ``H`` the image height)."""
    cam = scene.camera
    d = float(np.linalg.norm(np.asarray(scene.mesh.bounding_box.centroid) - np.asarray(cam.position)))
    return 2.0 * d * float(np.tan(np.radians(cam.fov_deg) / 2.0)) / float(cam.resolution[1])


def _identifiability(se_log, corr, rd, se_rd, ld=None, footprint=None):
    """Per channel: identifiable, and a warning line for each channel that is not. With the fitted ``ld`` (mm) and
    the finest view's ``footprint`` (mm per pixel), a blur under :data:`RESOLVED_LD_PIXELS` pixels is not."""
    c = len(corr)
    rel_a, rel_s = se_log[:c], se_log[c:]  # delta method: se(sigma) / sigma = se(log sigma)
    ok = (rel_a <= REL_STDERR_LIMIT) & (rel_s <= REL_STDERR_LIMIT) & (np.abs(corr) <= CORRELATION_LIMIT)
    warnings = []
    if ld is not None and footprint is not None:
        pixels = np.asarray(ld) / footprint
        blurred = ok & ~(pixels >= RESOLVED_LD_PIXELS)  # also NaN / inf l_d
        for k in np.flatnonzero(blurred):
            warnings.append(f"channel {k}: l_d = {float(ld[k]):.3g} mm spans {float(pixels[k]):.1f} pixels on the "
                            f"object (< {RESOLVED_LD_PIXELS:g}): the views do not resolve the blur, so sigma_a and "
                            f"sigma_s' are not constrained apart whatever their standard errors; Rd = {rd[k]:.4g} +- "
                            f"{se_rd[k]:.2g} is what they fix; view the object closer or at a higher resolution")
        ok = ok & ~blurred
    for k in np.flatnonzero(~ok):
        if any(w.startswith(f"channel {k}:") for w in warnings):
            continue
        loose = [name for name, rel in (("sigma_a", rel_a[k]), ("sigma_s'", rel_s[k])) if rel > REL_STDERR_LIMIT]
        why = (f"{' and '.join(loose)} not constrained (relative standard errors {rel_a[k]:.0%} / {rel_s[k]:.0%})"
               if loose else f"sigma_a and sigma_s' correlated ({corr[k]:+.4f})")
        warnings.append(f"channel {k}: {why}; Rd = {rd[k]:.4g} +- {se_rd[k]:.2g} is what these views fix; add lights "
                        "or views that show the blur (shadow edges, the terminator) to fix l_d")
    return ok, tuple(warnings)


def _weighted_target(views) -> np.ndarray:
    """``(m,)`` the target times its weight on every view's fitted rows, 0 elsewhere (rows as the residuals')."""
    return np.concatenate([np.where(np.asarray(mask)[..., None], np.asarray(target) * np.asarray(weight), 0.0)
                           .reshape(-1) for _, target, weight, mask in views])


def _view_cosines(scenes, views) -> np.ndarray:
    """``(m / C, L)`` each pixel's cosine to each distinct light of the views (:func:`fitting.discrepancy.light_key`),
    NaN where the light is not in the pixel's view, has no terminator, or the pixel is not fitted."""
    from jaxsss.export.compare import pixel_light_cosines

    keys = list(dict.fromkeys(light_key(light) for sc in scenes for light in sc.lights))
    out = []
    for sc, (_, _, _, mask) in zip(scenes, views):
        _, cos = pixel_light_cosines(sc)
        block = np.full(cos.shape[:2] + (len(keys),), np.nan)
        for k, light in enumerate(sc.lights):
            block[..., keys.index(light_key(light))] = cos[..., k]
        block[~np.asarray(mask)] = np.nan
        out.append(block.reshape(-1, len(keys)))
    return np.concatenate(out)


def fit_image(scene, target_image, *, method: str = "hierarchical", max_pixels: int | None = 4096,
              target_stderr=None, solver: str = "levenberg_marquardt", rtol: float = 1e-8, atol: float = 1e-8,
              max_steps: int = 100, seed: int = 0, progress: bool = False, model_error: float | ModelError = 0.0,
              **options) -> ImageFit:
    """Fit ``sigma_a`` and ``sigma_s'`` (per channel) of the scene's material to ``target_image``.

    Args:
        scene: the :class:`jaxsss.render.Scene` whose geometry, lights, camera, eta and g produced the target (its
            own sigma_a and sigma_s' are NOT used), or a sequence of scenes of the same material (several lights
            or views; eta and g must agree).
        target_image: ``(H, W, C)`` linear radiance at the camera's resolution, or one per scene.
        target_stderr: optional per-pixel standard errors of the target(s), same shapes, ``> 0`` on the lit pixels
            (a path-traced reference's noise): residuals are weighted by them and the standard errors are absolute
            (inflated by the reduced chi^2 when above 1).
        method: a registered render method (:func:`jaxsss.render.method_names`: hierarchical, direct, cached,
            photon, layered). The cached method places its caches once with the scene's own material (its ``l_d``
            and split-disk constant) and keeps them; the photon method keeps its traced walks (source power is
            reweighted, Eq. 8); the layered method fits the outer layer (``[material]``), the layers below fixed.
        **options: the method's options (e.g. ``eps``; cached ``error_bound``; photon ``n_photons``; layered
            ``samples``), as for :func:`jaxsss.render.render`.
        max_pixels: fit on at most this many lit pixels per view, chosen at random (``None``: all of them).
        solver: a name in :data:`fitting.SOLVERS`.
        rtol, atol, max_steps: Optimistix termination (Cauchy: successive iterates within ``atol + rtol |theta|``
            and every residual within ``atol + rtol |r_i|``). The residuals are relative to the mean target or in
            units of its standard errors, so ``atol = 1e-8`` is far below any meaningful change; at ``1e-10`` a
            converged fit went on for 5-13 more steps of rounding noise (14-23 steps instead of 9 in ``jaxsss run``).
        seed: pixel-subset seed.
        model_error: the render method's error against the real light transport (module docstring), added to the
            covariance: a number (a relative brightness error alike over the image, in ``[0, 1)``) or a
            :class:`fitting.ModelError` (with errors per band of the cosine to each light); 0 (default) for the
            renderer's own images, :data:`RENDER_MODEL_ERROR` (measured against Mitsuba) for a photograph or a
            path-traced image.

    Returns:
        An :class:`ImageFit`; check ``converged``, ``identifiable`` and ``warnings``.
    """
    from jaxsss.render import prepare_method, resolve_method

    scenes, targets, stderrs = _as_views(scene, target_image, target_stderr)
    error = ModelError.coerce(model_error, "fit_image")
    entry = resolve_method(method)
    mediums = [entry.params(s) for s in scenes]
    eta, g, fresnel = mediums[0].eta, mediums[0].g, mediums[0].fresnel
    for k, m in enumerate(mediums[1:], start=1):
        same_g = (m.g is None and g is None) or (m.g is not None and g is not None and np.allclose(m.g, g))
        if not (np.allclose(m.eta, eta) and same_g and m.fresnel == fresnel):
            raise ValueError(f"fit_image(scene[{k}]): eta, g and fresnel must equal scene[0]'s (eta {m.eta} vs "
                             f"{eta}, g {m.g} vs {g}): one material is fitted")
    seconds = {}
    t0 = time.perf_counter()
    views, relative = [], []
    for k, (sc, tg, se) in enumerate(zip(scenes, targets, stderrs)):
        name = "target_image" if len(scenes) == 1 else f"target_image[{k}]"
        target = _check_target(tg, sc, name)
        mask = _choose_pixels(target, max_pixels, seed + k)
        prepared = prepare_method(sc, entry.name, pixel_mask=mask, fit=True, progress=progress, **options).state
        scale = np.maximum(target[mask].mean(axis=0), 1e-300)
        if se is None:
            weight = np.broadcast_to(1.0 / scale, target.shape)
        else:
            se = np.asarray(se, dtype=np.float64)
            if se.shape != target.shape or not np.all(np.isfinite(se)) or np.any(se[mask] <= 0):
                raise ValueError(f"fit_image(target_stderr=...) for view {k} must have the target's shape "
                                 f"{target.shape}, be finite, and be > 0 on the fitted pixels")
            weight = 1.0 / np.where(se > 0, se, np.inf)
        views.append((prepared, jnp.asarray(target), jnp.asarray(weight), jnp.asarray(mask)))
        relative.append((prepared, jnp.asarray(target), jnp.asarray(np.broadcast_to(1.0 / scale, target.shape)),
                         jnp.asarray(mask)))
    seconds["prepare"] = time.perf_counter() - t0
    n_channels = targets[0].shape[-1] if np.ndim(targets[0]) == 3 else 1
    n_pixels = int(sum(int(v[3].sum()) for v in views))

    opt = resolve_solver(solver).make(rtol=rtol, atol=atol)
    args = (tuple(views), eta, g, fresnel)
    theta_shape = jnp.zeros(2 * n_channels)
    # Compile first (timed apart): the residuals (the start grid) and the solve.
    t0 = time.perf_counter()
    # From disk where they were exported before (jaxsss._exported: a new process skips tracing and lowering, 8-10 s
    # of a warm first fit on the white kernel); the key holds the views' static fields, eta, g, Fresnel, the solver.
    residuals = compiled_program("image-residuals", _residuals, (theta_shape, args),
                                 compiler_options=compile_bound_options())
    solve = compiled_program("image-solve", _solve, (theta_shape, args), (opt, max_steps), compile_bound_options())
    seconds["compile"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sa0, ss0 = _grid_start(residuals, args, eta, n_channels)
    seconds["start"] = time.perf_counter() - t0

    theta0 = jnp.log(jnp.concatenate([jnp.asarray(sa0), jnp.asarray(ss0)]))
    t0 = time.perf_counter()
    theta, code, n_steps = solve(theta0, args)
    theta = jax.block_until_ready(theta)
    result = results_from_code(code)
    seconds["solve"] = time.perf_counter() - t0
    res = residuals(theta, (tuple(relative), eta, g, fresnel))
    rms = jnp.sqrt(jnp.sum(res**2) / float(n_pixels * n_channels))
    t0 = time.perf_counter()
    discrepancy = (_weighted_target(views), _view_cosines(scenes, views), error) if error.stated else None
    se_log, corr, rd_ld, se_rd_ld, coupling, inflation, n_blocks = _uncertainty(
        theta, residuals, args, n_pixels * n_channels, target_stderr is not None, _blocks(views, n_channels),
        discrepancy)
    seconds["stderr"] = time.perf_counter() - t0
    c = n_channels
    ok, warnings = _identifiability(se_log, corr, rd_ld[:c], se_rd_ld[:c], rd_ld[c:],
                                    min(pixel_footprint(sc) for sc in scenes))
    if n_blocks < MIN_BLOCKS:
        warnings = warnings + (f"the fitted pixels fall in {n_blocks} of the {BLOCK_GRID}x{BLOCK_GRID} blocks per view "
                               f"(< {MIN_BLOCKS}): the standard errors assume independent pixels, which a model error "
                               "is not; fit pixels spread over more of the object",)
    if coupling > CHANNEL_COUPLING_LIMIT:
        warnings = warnings + (f"method {entry.name!r} couples the channels (a residual moves with another "
                               f"channel's coefficients by {coupling:.2g} of the largest derivative): the solve's "
                               "per-channel Jacobian was wrong, so the fit may have stopped early; please report it",)
    sa, ss = jnp.exp(theta[:c]), jnp.exp(theta[c:])
    return ImageFit(sa, ss, jnp.asarray(sa0), jnp.asarray(ss0), result, n_steps, rms,
                    sa * se_log[:c], ss * se_log[c:], jnp.asarray(rd_ld[:c]), jnp.asarray(se_rd_ld[:c]),
                    jnp.asarray(rd_ld[c:]), jnp.asarray(se_rd_ld[c:]), jnp.asarray(corr), jnp.asarray(ok),
                    jnp.asarray(inflation), n_pixels, seconds, warnings, len(views))
