"""The stability matrix (DESIGN.md, tests/test_stability.py) extended to the photon-diffusion models.

Grid: alpha' in {1e-6, 1e-3, 0.5, 0.99, 1 - 1e-9} x sigma_t' in {1e-4, 1e-2, 1, 1e2, 1e4} /mm x eta in {0.5, 1,
1.0001, 1.3, 2.5} x distance in {1e-3, 1, 10, 1e4} l_d (the oblique profile rejects the entry point itself; the blend grid
adds r = 0, and tests/profiles/test_quadpole.py differentiates the quadpole right above its source). Models: the oblique profile (Eq. 8 quadrature, theta_i = 0.4 rad, kappa = sigma_t' and none), the
attenuated dipole, the quadpole (depth l_u, offset l_u / 2) and the Eq. 15 blend at gamma = 2 pi / 3 (quadpole and
multipole, 4 pairs) with the view depth in {1e-4, 1e-2, 1, 10, 1e4} l_u, so the blend's slab thickness l_u + h spans
the slab axis of the matrix. Values and gradients must be finite; float32 within the stated distance of float64.
The float64 values are computed with the traced argument checks (none may fire on the grid); the gradients and the
float32 values without them (:func:`jaxsss.validate.trusted_traces`): a check is a host callback, which keeps a program
out of JAX's persistent cache, and those programs would be compiled again in every run.

Stated float32 tolerances (relative to float64 where the float64 value exceeds 1e-30; measured maxima in brackets):
- oblique profile (both kernels): 2e-5 [5.2e-6];
- attenuated dipole: 1e-5 [1.2e-6];
- quadpole: 2e-3 where the quadpole exceeds 1e-3 of its dipole term [3.7e-4] -- far from the edge the mirror term
  cancels the dipole and float32 loses those digits;
- blend at 2 pi / 3: 5e-2 [1.8e-2]. The blend works from world coordinates: the view depth ``h`` is a difference of
  positions of size ``|x_o - source|``, so in float32 it carries an absolute error ~6e-8 |x_o - source|. The worst
  point has ``|x_o - source| = 10 l_d ~ 2e5 l_u`` and ``h = 0.01 l_u``. Keep float32 geometry local (positions
  relative to the source) where this matters.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.validate import trusted_traces
from jaxsss.profiles import (
    attenuated_dipole_profile,
    blended_exitance,
    dipole_exitance,
    oblique_profile,
    quadpole_exitance,
)

ALPHA = [1e-6, 1e-3, 0.5, 0.99, 1 - 1e-9]
SIGMA_T = [1e-4, 1e-2, 1.0, 1e2, 1e4]
ETA = [0.5, 1.0, 1.0001, 1.3, 2.5]
DIST_OVER_LD = [1e-3, 1.0, 10.0, 1e4]
H_OVER_LU = [1e-4, 1e-2, 1.0, 10.0, 1e4]
GAMMA = 2 * np.pi / 3


def grid(*axes):
    cols = [np.array(c) for c in zip(*itertools.product(*axes))]
    alpha, st = cols[0], cols[1]
    return np.stack([st * (1 - alpha), st * alpha, *cols[2:]], axis=-1)


def core(x):
    """[oblique sigma_t', oblique none, attenuated dipole, quadpole, its dipole term] at distance x[3] l_d."""
    m = Medium(x[..., 0], x[..., 1], x[..., 2])
    r = x[..., 3] * m.l_d
    l_u = m.l_u
    # Every argument in the grid's dtype (strict promotion: a Python float would become a float64 array).
    zero, theta = jnp.zeros_like(r), jnp.full_like(r, 0.4)
    return jnp.stack([
        oblique_profile(r, zero, m, theta),
        oblique_profile(r, zero, m, theta, kappa="none"),
        attenuated_dipole_profile(r, m),
        quadpole_exitance(r, zero, l_u, 0.5 * l_u, m),
        dipole_exitance(jnp.abs(r - 0.5 * l_u), l_u, m),
    ], axis=-1)


def blend(x):
    """Eq. 15 at gamma = 2 pi/3: source l_u below the top face, view point at in-plane distance x[3] l_d and view
    depth x[4] l_u; returns [blend, the view-plane dipole alone]."""
    m = Medium(x[0], x[1], x[2])
    l_u = m.l_u
    n_o = jnp.array([np.sin(GAMMA), 0.0, np.cos(GAMMA)], x.dtype)
    t = jnp.array([np.cos(GAMMA), 0.0, -np.sin(GAMMA)], x.dtype)
    src = jnp.stack([jnp.zeros_like(l_u), jnp.zeros_like(l_u), -l_u])
    h = x[4] * l_u
    x_o = src + h * n_o + x[3] * m.l_d * t
    v = blended_exitance(x_o, n_o, src, jnp.array([0.0, 0.0, 1.0], x.dtype), l_u, m, n_pairs=4)
    return jnp.stack([v, dipole_exitance(x[3] * m.l_d, h, m)])


@pytest.fixture(scope="module")
def core_inputs():
    return grid(ALPHA, SIGMA_T, ETA, DIST_OVER_LD)


@pytest.fixture(scope="module")
def blend_inputs():
    return grid(ALPHA, SIGMA_T, ETA, [0.0] + DIST_OVER_LD[:3], H_OVER_LU)


def _rel(v32, v64, resolved):
    return np.max(np.abs(v32[resolved] / v64[resolved] - 1))


def test_core_values_gradients_and_float32(core_inputs):
    x = jnp.asarray(core_inputs)
    v64 = np.asarray(jax.jit(core)(x))  # with the traced argument checks: none fires on the grid
    assert np.all(np.isfinite(v64)) and np.all(v64 >= 0)
    with trusted_traces():  # (module docstring)
        jac = jax.jit(jax.vmap(jax.jacfwd(core)))(x)
        v32 = jax.jit(core)(jnp.asarray(core_inputs, dtype=jnp.float32))
    assert bool(jnp.all(jnp.isfinite(jac))), np.argwhere(~np.isfinite(np.asarray(jac)))[:5]
    assert v32.dtype == jnp.float32
    v32 = np.asarray(v32, dtype=np.float64)
    assert np.all(np.isfinite(v32))
    for k, tol in enumerate([2e-5, 2e-5, 1e-5]):
        ok = v64[:, k] > 1e-30
        assert _rel(v32[:, k], v64[:, k], ok) < tol, k
    ok = (v64[:, 3] > 1e-30) & (v64[:, 3] > 1e-3 * v64[:, 4])
    assert _rel(v32[:, 3], v64[:, 3], ok) < 2e-3


def test_blend_values_gradients_and_float32(blend_inputs):
    x = jnp.asarray(blend_inputs)
    f = jax.jit(jax.vmap(blend))
    v64 = np.asarray(f(x))  # with the traced argument checks: none fires on the grid
    assert np.all(np.isfinite(v64))
    with trusted_traces():  # (module docstring)
        assert bool(jnp.all(jnp.isfinite(jax.jit(jax.vmap(jax.jacfwd(blend)))(x))))
        v32 = np.asarray(f(jnp.asarray(blend_inputs, dtype=jnp.float32)), dtype=np.float64)
    assert np.all(np.isfinite(v32))
    ok = np.abs(v64[:, 0]) > 1e-30
    assert _rel(v32[:, 0], v64[:, 0], ok) < 5e-2
