"""Autodiff checks shared by the test suite: gradients against central finite differences in float64.

``jax.test_util.check_grads`` steps by an absolute ``eps``, which is wrong for parameters spanning 1e-9..1e4 (the
stability matrix). :func:`assert_grad_matches_fd` steps relative to each coordinate instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxsss.validate import trusted_traces


def central_difference(f, x, rel_step=1e-6):
    """Central finite-difference gradient of scalar ``f`` at float64 array ``x``, steps ``rel_step * |x_i|``."""
    x = np.asarray(x, dtype=np.float64)
    grad = np.zeros_like(x)
    for idx in np.ndindex(x.shape):
        h = rel_step * max(abs(x[idx]), 1e-300)
        xp, xm = x.copy(), x.copy()
        xp[idx] += h
        xm[idx] -= h
        grad[idx] = (float(f(jnp.asarray(xp))) - float(f(jnp.asarray(xm)))) / (xp[idx] - xm[idx])
    return grad


def assert_grad_matches_fd(f, x, *, rel_step=1e-6, rtol=1e-6, atol=0.0, jit=False):
    """Assert ``jax.grad(f)(x)`` (reverse mode) and ``jax.jvp`` (forward mode) match central differences.

    ``jit=True`` compiles ``f``, its gradient and its JVP (three programs) instead of dispatching them op by op. It
    pays for a large ``f`` evaluated many times (the refracted exit distribution: 10 s op by op against 3 s), not for
    a small one, nor for one that builds a large jitted program itself (the curved white kernel: 20 s against 39 s);
    measured per test, docs/architecture.md ("The suite's time, 2026-11-28").

    ``f`` is traced without the traced argument checks (:func:`jaxsss.validate.trusted_traces`): they are host
    callbacks, which keep a compiled program (``jit=True``, or an ``f`` that is jitted itself) out of JAX's persistent
    cache. Gradients are checked at valid points; bad input has tests of its own.
    """
    with trusted_traces():
        _assert_grad_matches_fd(f, x, rel_step, rtol, atol, jit)


def _assert_grad_matches_fd(f, x, rel_step, rtol, atol, jit):
    x = jnp.asarray(x, dtype=jnp.float64)
    grad = jax.jit(jax.grad(f)) if jit else jax.grad(f)
    g_rev = np.asarray(grad(x))
    g_fd = central_difference(jax.jit(f) if jit else f, x, rel_step)
    assert np.all(np.isfinite(g_rev)), g_rev
    np.testing.assert_allclose(g_rev, g_fd, rtol=rtol, atol=atol, err_msg="reverse mode vs central differences")
    # Forward mode along each coordinate.
    basis = np.eye(x.size).reshape((x.size,) + x.shape)

    def jvp(x, v):
        return jax.jvp(f, (x,), (v,))[1]

    jvp = jax.jit(jvp) if jit else jvp
    g_fwd = np.array([float(jvp(x, jnp.asarray(e))) for e in basis]).reshape(x.shape)
    np.testing.assert_allclose(g_fwd, g_rev, rtol=1e-10, atol=1e-300, err_msg="forward vs reverse mode")
