"""fit_free_g: g, sigma_a and sigma_s' from near-source data of an external Monte Carlo code (MCML 1.2.2), the
warning when the data cannot carry g, and bad input named."""

import numpy as np
import pytest

from fitting import fit_free_g, read_mco
from tests.fitting.test_mco import shared_mcml_dir


@pytest.fixture(scope="module")
def run():
    return read_mco(shared_mcml_dir() / "halfspace_n10_g07.mco")


def test_free_g_recovers_an_mcml_half_space(run):
    layer = run.layers[0]
    fit = fit_free_g(run.to_profile(), eta=run.eta)
    assert fit.converged and fit.identifiable and not fit.warnings
    for est, se, true in ((fit.sigma_a, fit.sigma_a_stderr, layer.sigma_a),
                          (fit.sigma_s_prime, fit.sigma_s_prime_stderr, layer.sigma_s_prime)):
        assert abs(est - true) <= max(0.03 * true, 3 * se), (est, se, true)
    assert abs(fit.g - layer.g) <= 3 * fit.g_stderr, (fit.g, fit.g_stderr)
    assert 0.2 < fit.reduced_chi2 < 2.0
    # The covariance is the errors' source: a symmetric, positive semi-definite 3 x 3.
    np.testing.assert_allclose(np.sqrt(np.diag(fit.covariance)),
                               [fit.sigma_a_stderr, fit.sigma_s_prime_stderr, fit.g_stderr])
    assert np.all(np.linalg.eigvalsh(fit.covariance) >= -1e-15)


def test_far_field_data_do_not_fix_g(run):
    """Beyond a few transport lengths the profile carries g only through differences below the model's error: the
    fit must not report g as constrained (from 3.3 l_u its statistical error alone would say +-0.01)."""
    layer = run.layers[0]
    l_u = 1.0 / (layer.sigma_a + layer.sigma_s_prime)
    for r_min in (2.0 * l_u, 3.3 * l_u):
        fit = fit_free_g(run.to_profile(), eta=run.eta, r_min=r_min)
        assert not fit.identifiable, r_min
        assert len(fit.warnings) == 1 and "g is not constrained" in fit.warnings[0] and "l_u" in fit.warnings[0]


def test_bad_input_is_named(run):
    data = run.to_profile()
    with pytest.raises(ValueError, match="eta=1.8"):
        fit_free_g(data, eta=1.8)
    with pytest.raises(ValueError, match="same length"):
        fit_free_g(data.r, data.R[:-1], eta=1.0)
    with pytest.raises(ValueError, match="R_stderr"):
        fit_free_g(data.r, data.R, R_stderr=np.zeros_like(data.R), eta=1.0)
    with pytest.raises(ValueError, match="fewer than 4"):
        fit_free_g(data, eta=1.0, r_min=100.0)
    with pytest.raises(ValueError, match=r"fit_free_g\(r=-0.1\).*outside the allowed range \[0, inf\)"):
        fit_free_g(np.concatenate([[-0.1], data.r[1:]]), data.R, eta=1.0)
