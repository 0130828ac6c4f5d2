"""Christensen-Burley fits to transport (jaxsss.export.burley)."""

import numpy as np
import pytest
from scipy.integrate import quad

from jaxsss.export.burley import burley_fit, burley_profile, searchlight_s
from jaxsss.mc.white import load_white_table, white_mc_profile
from jaxsss.medium import Medium

SKIN1 = (np.array([0.032, 0.17, 0.48]), np.array([0.74, 0.88, 1.01]))


def test_profile_integrates_to_albedo():
    for A, d in ((0.5, 1.0), (0.9, 0.2)):
        total, _ = quad(lambda r: 2 * np.pi * r * burley_profile(r, A, d), 0, np.inf)
        assert total == pytest.approx(A, rel=1e-10)
    # Christensen and Burley 2015: s(A) = 1.85 - A + 7 |A - 0.8|^3.
    assert searchlight_s(0.8) == pytest.approx(1.05)
    assert searchlight_s(0.0) == pytest.approx(1.85 + 7 * 0.512)


@pytest.fixture(scope="module")
def skin1_fit():
    return burley_fit(Medium(*SKIN1, 1.0, None))


def test_skin1_fit_matches_transport_energy(skin1_fit):
    """A is the transport profile's total diffuse reflectance, checked against the table's own plane integral; the
    fitted shape is within 10% (relative L2 of the energy density) for g = 0."""
    fit = skin1_fit
    table = load_white_table(0.0, 1.0)
    r = np.geomspace(1e-5, 80.0, 400)  # wider than the fit's grid, trapezoid rule; the fit's shapes (no recompile)
    for c in range(3):
        R = np.asarray(white_mc_profile(r[:, None], SKIN1[0][c:c + 1], SKIN1[1][c:c + 1], table))[:, 0]
        assert fit.A[c] == pytest.approx(np.trapezoid(2 * np.pi * r * R, r), rel=5e-3)
    assert np.all(np.diff(fit.A) < 0)  # more absorption, lower albedo
    assert np.all(fit.error_l2 < 0.1) and np.all(fit.error_l2 > 0.01)  # a real, measured model error
    np.testing.assert_allclose(fit.mfp, fit.d * searchlight_s(fit.A))


def test_similarity_scaling(skin1_fit):
    """Scaling sigma_a and sigma_s' by k scales every length by 1/k and leaves A and the errors unchanged."""
    k = 2.5
    fit = burley_fit(Medium(k * SKIN1[0], k * SKIN1[1], 1.0, None))
    np.testing.assert_allclose(fit.A, skin1_fit.A, rtol=1e-4)
    np.testing.assert_allclose(fit.d, skin1_fit.d / k, rtol=1e-3)
    np.testing.assert_allclose(fit.error_l2, skin1_fit.error_l2, rtol=1e-2, atol=1e-4)


def test_unsupported_medium_names_the_tables():
    with pytest.raises(ValueError, match=r"g=0.5, n=1.2.*available: \(g=0, n=1\)"):
        burley_fit(Medium(*SKIN1, 1.2, 0.5))
