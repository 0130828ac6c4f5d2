"""The white Monte Carlo forward model ``mc`` in the fitting registry: exact recovery of its own profiles, recovery
of a Monte Carlo simulated measurement, and the errors for (g, eta) outside the white-MC family.

Every fit here is at one off-grid (g, n) = (0.5, 1.35) of the family (between its nodes on both axes) and at most four
problems, so they share one compilation (the white-MC model is a large graph); one test checks that another (g, n)
shares it too."""

import numpy as np
import pytest

import fitting
from jaxsss.mc import Stack, simulate, white_family_profile

G, N = 0.5, 1.35
R_GRID = np.geomspace(0.02, 30.0, 100)  # 100 radii: padded to 128, as the other mc fits of the suite (one compilation)


@pytest.fixture(scope="module")
def noise_free_fit():
    # Channel 0: albedo ~0.98; channel 1: sigma_a / sigma_s' = 1e-3 (the family holds down to sigma_a = 0: the
    # single-pair tables' validity limit, 2e-3 for g = 0, is gone).
    sa, ss = np.array([0.02, 0.001]), np.array([1.0, 1.0])
    R = np.asarray(white_family_profile(R_GRID[:, None], sa, ss, G, N))
    fit = fitting.fit_profile(R_GRID, R, eta=N, model="mc", g=G)
    return fit, sa, ss


def test_noise_free_profile_recovered_to_1e6(noise_free_fit):
    fit, sa, ss = noise_free_fit
    assert fit.converged.all()
    # 1e-6 (the brief's target): the profile is the model itself, so only the solver's tolerance (1e-10) remains.
    np.testing.assert_allclose(fit.sigma_a, sa, rtol=1e-6)
    np.testing.assert_allclose(fit.sigma_s_prime, ss, rtol=1e-6)


def test_another_g_and_eta_reuse_the_compiled_fit(noise_free_fit):
    """The table block of ``(g, n)`` is a runtime argument of the compiled fit (``ForwardModel.operands``): a fit at
    another ``(g, n)`` with the same shapes traces nothing (each compilation costs ~20 s on this machine) and recovers
    its own truth."""
    from fitting import _kernel

    _, sa, ss = noise_free_fit
    g, n = 0.85, 1.47  # another block of nodes on both axes
    R = np.asarray(white_family_profile(R_GRID[:, None], sa, ss, g, n))
    before = dict(_kernel.TRACES)
    fit = fitting.fit_profile(R_GRID, R, eta=n, model="mc", g=g)
    assert _kernel.TRACES == before
    assert fit.static == (g, n) and fit.converged.all()
    np.testing.assert_allclose(fit.sigma_a, sa, rtol=1e-6)
    np.testing.assert_allclose(fit.sigma_s_prime, ss, rtol=1e-6)


def test_default_range_and_validity_are_recorded(noise_free_fit):
    fit, sa, ss = noise_free_fit
    assert "0.1 l_u" in fit.range_reason
    np.testing.assert_allclose(fit.r_cut, 0.1 / (fit.guess_sigma_a + fit.guess_sigma_s_prime), rtol=1e-12)
    assert fit.static == (G, N)
    assert not fit.model_warnings and not fit.warnings
    assert fit.to_dict()["g"] == G and fit.to_dict()["model"] == "mc"


def test_mc_does_not_apply_the_entry_transmittance(noise_free_fit):
    """The model is the family itself (per incident photon); the diffusion models multiply by 1 - F(eta, 1)."""
    fit, sa, ss = noise_free_fit
    pred = fit.predict(R_GRID)["R"]
    np.testing.assert_allclose(pred, np.asarray(white_family_profile(R_GRID, sa[:, None], ss[:, None], G, N)),
                               rtol=1e-5)


def test_monte_carlo_measurement_recovered():
    """1e5 photons of the engine at the off-grid (g, n), albedo 0.8, 100 equal bins to 6 mm (~6 l_d): as many radii
    as the noise-free fit's, so the two share one compiled fit (the white-MC model is a large graph).

    Tolerance: 4 standard errors (the fit's own, from the data's per-bin errors) plus 1% for the model's systematic
    error: the nodes' Monte Carlo noise, their interpolation, the pathlength discretisation, and the curvature of R
    within the data's bins (a bin average is fitted as a point value)."""
    sa, ss = 0.25, 1.0
    edges = np.linspace(0.0, 6.0, len(R_GRID) + 1)
    res = simulate(Stack.half_space(sa, ss / (1 - G), G, N), 100_000, seed=3, r_edges=edges, progress=False)
    fit = fitting.fit_profile(res.r_centres, res.R_r, R_stderr=res.R_r_stderr, eta=N, model="mc", g=G)
    assert fit.converged.all() and not fit.warnings
    assert "first radius left out" in fit.range_reason  # the bin holding the source
    assert float(fit.r_min) > res.r_centres[0]
    for est, se, truth in ((fit.sigma_a, fit.sigma_a_stderr, sa), (fit.sigma_s_prime, fit.sigma_s_prime_stderr, ss)):
        assert abs(float(est) - truth) <= 4 * float(se) + 0.01 * truth, (float(est), float(se), truth)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(model="mc", g=0.97), r"g=0.97 is outside the white Monte Carlo family's range \[0, 0.95\]"),
        (dict(model="mc", g=0.5, eta=1.7), r"eta=1.7 is outside the white Monte Carlo family's range \[1, 1.6\]"),
        (dict(model="mc", g=0.5, eta=0.9), r"eta=0.9 is outside the white Monte Carlo family's range \[1, 1.6\]"),
        (dict(model="mc"), r"needs g=\.\.\..*g in \[0, 0.95\]"),
        (dict(model="mc", g=0.0, free_eta=True), "free_eta"),
        (dict(model="dipole", g=0.0), r"g=0.0\) applies to the transport model only"),
        (dict(model="mc", g=1.0), r"outside the allowed range \(-1, 1\)"),
    ],
)
def test_outside_the_family_and_bad_g_are_named(kwargs, match):
    R = np.exp(-R_GRID)
    with pytest.raises(ValueError, match=match):
        fitting.fit_profile(R_GRID, R, **({"eta": N} | kwargs))


def test_mc_is_registered():
    assert "mc" in fitting.FORWARD_MODELS and fitting.FORWARD_MODELS["mc"].outputs == ("R",)
