"""The dipole's hand-written Jacobian (fitting._dipole_jac) against jax.jacfwd of the registered model."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
from fitting import _kernel as K
from fitting._dipole_jac import dipole_value_and_jac
from fitting.models import model_profiles, resolve_model

R = np.concatenate([[0.0], np.geomspace(1e-3, 50.0, 40)])


@functools.lru_cache
def both(fresnel):
    """Jitted (eager op-by-op is slow): the hand-written value and Jacobian, and the model with jacfwd's."""

    def model(th, eta):
        return model_profiles(resolve_model("dipole"), jnp.asarray(R), jnp.exp(th[0]), jnp.exp(th[1]), eta, 1.0,
                              None, fresnel=fresnel)["R"]

    def run(th, eta):
        v, dla, dls = dipole_value_and_jac(jnp.asarray(R), jnp.exp(th[0]), jnp.exp(th[1]), eta, fresnel)
        return v, jnp.stack([dla, dls], 1), model(th, eta), jax.jacfwd(model)(th, eta)

    return jax.jit(run)


@pytest.mark.parametrize("sa, ss, eta, fresnel", [
    (0.032, 0.74, 1.3, "poly"),  # skin1 red
    (0.48, 1.01, 1.3, "exact"),  # skin1 blue
    (1e-4, 20.0, 1.5, "poly"),  # albedo ~1: long diffusion
    (5.0, 0.2, 1.0, "poly"),  # absorbing, index-matched
    (0.01, 1.0, 0.8, "exact"),  # eta < 1
])
def test_value_and_jacobian_match_the_model_and_jacfwd(sa, ss, eta, fresnel):
    v, J, want_v, want_j = both(fresnel)(jnp.log(jnp.array([sa, ss])), eta)
    # 1e-12: the same closed forms in a different order of float64 operations.
    np.testing.assert_allclose(v, want_v, rtol=1e-12, atol=0)
    scale = np.max(np.abs(want_j), axis=0)  # relative to each column's size (derivatives change sign)
    np.testing.assert_allclose(J / scale, want_j / scale, rtol=0, atol=1e-12)


@pytest.mark.parametrize("relative", [False, True])
def test_kernel_linearisation_matches_jacfwd_of_the_residuals(relative):
    """The fit's residual Jacobian (mask, weights, free scale) by hand equals jacfwd of its residuals."""
    rng = np.random.default_rng(0)
    r = np.linspace(0.1, 10.0, 30)
    y = np.asarray(fitting.entry_transmittance(1.3) * 0.01) * np.exp(-r)[None, :] * (1 + 0.1 * rng.random(30))
    mask = np.ones((1, 30), bool)
    mask[0, :4] = False
    cfg = K.Config("dipole", None, ("R",), relative, False, "levenberg_marquardt", 1e-10, 1e-10, 10, "poly")
    w, _ = K.weights(jnp.asarray(y), jnp.zeros_like(y), cfg)
    args = (jnp.asarray(r), jnp.asarray(y), w, jnp.asarray(mask), 1.3, 1.0, cfg)
    theta = jnp.log(jnp.array([0.05, 1.2] + ([3.0] if relative else [])))
    assert K._hand_jacobian(cfg)
    res, J, want_res, want_J = jax.jit(lambda t: (*K._linearise(t, args), K.residuals(t, args),
                                                  jax.jacfwd(lambda u: K.residuals(u, args))(t)))(theta)
    np.testing.assert_allclose(res, want_res, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(J, want_J, rtol=1e-11, atol=1e-13)
