"""Recover ``sigma_a`` and ``sigma_s'`` per channel from a rendered image (issue 5, "Differentiable in the material").

Every registered render method exposes ``image = prepared.image(medium)`` once its geometry is fixed
(:func:`jaxsss.render.prepare_method`; the methods are those of :func:`jaxsss.render.method_names`).
:func:`fit_image` looks the method up, builds that function on a random subset of the object's pixels,
starts from the best of a small grid of (Rd, l_d) candidates per channel (through the reparameterisation, so the start
is physically sensible without knowing the answer), and runs an Optimistix least-squares solve in the
log-parameters. Residuals are relative: ``(model - target) / mean(target)`` per channel, on the chosen pixels.

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
from fitting.solvers import resolve_solver

__all__ = ["LD_CANDIDATES_MM", "RD_CANDIDATES", "ImageFit", "fit_image"]

RD_CANDIDATES = (0.2, 0.5, 0.8, 0.95)
LD_CANDIDATES_MM = (0.3, 1.0, 3.0, 10.0)
"""The start grid: 16 (Rd, l_d) pairs per channel, each a full image evaluation on the fit's pixels."""


class ImageFit(eqx.Module):
    """Result of :func:`fit_image`.

    Attributes:
        sigma_a, sigma_s_prime: ``(C,)`` estimates, 1/mm.
        start_sigma_a, start_sigma_s_prime: ``(C,)`` the grid start.
        result: the Optimistix ``RESULTS`` of the solve (``successful`` when converged).
        n_steps: solver steps taken.
        rms_relative: RMS of the relative residuals at the solution.
        n_pixels: pixels used.
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
    n_pixels: int = eqx.field(static=True)
    seconds: dict = eqx.field(static=True)

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
            "rms_relative": self.rms_relative, "n_pixels": self.n_pixels, "seconds": self.seconds,
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
    return jaxsss.Medium(jnp.exp(theta[:c]), jnp.exp(theta[c:]), eta, g, fresnel=fresnel)


@eqx.filter_jit
def _residuals(theta, args):
    prepared, target, scale, mask, eta, g, fresnel = args
    img = prepared.image(_medium(theta, eta, g, fresnel))
    return jnp.where(mask[..., None], (img - target) / scale, 0.0).reshape(-1)


@eqx.filter_jit
def _solve(theta0, args, solver, max_steps):
    return optx.least_squares(_residuals, solver, theta0, args=args, max_steps=max_steps, throw=False)


def _grid_start(residuals, args, eta, n_channels):
    """Per channel, the (Rd, l_d) grid candidate with the smallest squared relative residual (``residuals`` is the
    compiled :func:`_residuals`)."""
    rd = np.repeat(RD_CANDIDATES, len(LD_CANDIDATES_MM))
    ld = np.tile(LD_CANDIDATES_MM, len(RD_CANDIDATES))
    rep = jaxsss.from_rd_ld(jnp.asarray(rd)[:, None] * jnp.ones(n_channels), jnp.asarray(ld)[:, None] *
                            jnp.ones(n_channels), eta)
    sa, ss = np.asarray(rep.medium.sigma_a), np.asarray(rep.medium.sigma_s_prime)  # (K, C)
    cost = np.empty((len(rd), n_channels))
    for k in range(len(rd)):
        r = residuals(jnp.log(jnp.concatenate([jnp.asarray(sa[k]), jnp.asarray(ss[k])])), args)
        cost[k] = np.asarray(r).reshape(-1, n_channels).__pow__(2).sum(axis=0)
    best = np.argmin(np.where(np.isfinite(cost), cost, np.inf), axis=0)
    return sa[best, np.arange(n_channels)], ss[best, np.arange(n_channels)]


def fit_image(scene, target_image, *, method: str = "hierarchical", max_pixels: int | None = 4096,
              solver: str = "levenberg_marquardt", rtol: float = 1e-8, atol: float = 1e-10, max_steps: int = 100,
              seed: int = 0, progress: bool = False, **options) -> ImageFit:
    """Fit ``sigma_a`` and ``sigma_s'`` (per channel) of the scene's material to ``target_image``.

    Args:
        scene: the :class:`jaxsss.render.Scene` whose geometry, lights, camera, eta and g produced the target (its
            own sigma_a and sigma_s' are NOT used).
        target_image: ``(H, W, C)`` linear radiance at the camera's resolution.
        method: a registered render method (:func:`jaxsss.render.method_names`: hierarchical, direct, cached,
            photon, layered). The cached method places its caches once with the scene's own material (its ``l_d``
            and split-disk constant) and keeps them; the photon method keeps its traced walks (source power is
            reweighted, Eq. 8); the layered method fits the outer layer (``[material]``), the layers below fixed.
        **options: the method's options (e.g. ``eps``; cached ``error_bound``; photon ``n_photons``; layered
            ``samples``), as for :func:`jaxsss.render.render`.
        max_pixels: fit on at most this many lit pixels, chosen at random (``None``: all of them).
        solver: a name in :data:`fitting.SOLVERS`.
        rtol, atol, max_steps: Optimistix termination.
        seed: pixel-subset seed.

    Returns:
        An :class:`ImageFit`; check ``converged``.
    """
    from jaxsss.render import prepare_method, resolve_method

    target = np.asarray(target_image, dtype=np.float64)
    w, h = scene.camera.resolution
    if target.ndim != 3 or target.shape[:2] != (h, w):
        raise ValueError(f"fit_image(target_image=...) has shape {target.shape}; the scene's camera gives "
                         f"({h}, {w}, C)")
    if not np.isfinite(target).all() or (target < 0).any():
        raise ValueError("fit_image(target_image=...) must be finite and non-negative")
    seconds = {}
    t0 = time.perf_counter()
    mask = _choose_pixels(target, max_pixels, seed)
    entry = resolve_method(method)
    prepared = prepare_method(scene, entry.name, pixel_mask=mask, fit=True, progress=progress, **options).state
    seconds["prepare"] = time.perf_counter() - t0
    medium = entry.params(scene)
    eta, g, fresnel = medium.eta, medium.g, medium.fresnel
    n_channels = target.shape[-1]
    scale = jnp.asarray(np.maximum(target[mask].mean(axis=0), 1e-300))
    tgt, msk = jnp.asarray(target), jnp.asarray(mask)

    opt = resolve_solver(solver).make(rtol=rtol, atol=atol)
    args = (prepared, tgt, scale, msk, eta, g, fresnel)
    theta_shape = jnp.zeros(2 * n_channels)
    # Compile first (timed apart): the residuals (the start grid) and the solve.
    t0 = time.perf_counter()
    residuals = _residuals.lower(theta_shape, args).compile()
    compiled = _solve.lower(theta_shape, args, opt, max_steps).compile()
    seconds["compile"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sa0, ss0 = _grid_start(residuals, args, eta, n_channels)
    seconds["start"] = time.perf_counter() - t0

    theta0 = jnp.log(jnp.concatenate([jnp.asarray(sa0), jnp.asarray(ss0)]))
    t0 = time.perf_counter()
    sol = compiled(theta0, args, opt, max_steps)
    theta = jax.block_until_ready(sol.value)
    seconds["solve"] = time.perf_counter() - t0
    res = _residuals(theta, args)
    rms = jnp.sqrt(jnp.sum(res**2) / float(mask.sum() * n_channels))
    c = n_channels
    return ImageFit(jnp.exp(theta[:c]), jnp.exp(theta[c:]), jnp.asarray(sa0), jnp.asarray(ss0), sol.result,
                    sol.stats["num_steps"], rms, int(mask.sum()), seconds)
