"""The direction tally of the diffuse reflectance (simulate(exit_mu_edges=...), R_mu_phi)."""

import math

import numpy as np
import pytest

from jaxsss.mc import Stack, simulate
from jaxsss.render.bssrdf import exit_distribution

EDGES = np.linspace(0.0, 1.0, 11)
CENTRES, WIDTH = 0.5 * (EDGES[1:] + EDGES[:-1]), np.diff(EDGES)


def _run(g, albedo, mu_i, photons=40_000, **kw):
    return simulate(Stack.half_space((1.0 - albedo) / albedo, 1.0 / (1.0 - g), g, 1.0), photons, seed=4,
                    angle_deg=math.degrees(math.acos(mu_i)), exit_mu_edges=EDGES, **kw)


def test_isotropic_half_space_reflects_chandrasekhars_distribution_with_no_azimuth():
    """Against exact transport: an isotropic, index-matched half-space lit at mu_i 0.3 reflects with Chandrasekhar's
    X(mu_o | mu_i) (every order; within 4 standard errors per bin) and no azimuthal dependence (every harmonic within
    4.5 standard errors of 0)."""
    res = _run(0.0, 0.9, 0.3)
    h, err = res.R_mu_phi, res.R_mu_phi_stderr
    assert h.shape == err.shape == (10, 9)
    np.testing.assert_allclose(h[:, 0].sum(), res.R_diffuse, rtol=1e-12)
    scale = 2.0 * res.R_diffuse * CENTRES * WIDTH
    x0, x0_err = h[:, 0] / scale, err[:, 0] / scale
    exact = np.asarray(exit_distribution(CENTRES, np.array([0.3]), np.array([0.9])))[:, 0, 0]
    # Bin averages against centre values: X is smooth (curvature error < 0.5%) except in the grazing bin.
    assert np.all(np.abs(x0 - exact)[1:] <= 4.0 * x0_err[1:] + 0.005 * exact[1:]), (x0, exact)
    assert np.all(np.abs(h[:, 1:]) <= 4.5 * err[:, 1:]), h[:, 1:] / err[:, 1:]


def test_forward_scattering_leaves_forward_and_grazing():
    """g = 0.9 at grazing incidence: the first harmonic is positive in every bin (more light leaves along the beam's
    azimuth than against it) and the radiance at grazing exit exceeds the isotropic equivalent's, while the total
    stays within 10% of it (physical invariant of the similarity relation for totals, not directions)."""
    res = _run(0.9, 0.95, 0.1, photons=20_000)
    h = res.R_mu_phi
    assert np.all(h[:, 1] > 0.0)
    scale = 2.0 * res.R_diffuse * CENTRES * WIDTH
    iso = np.asarray(exit_distribution(CENTRES, np.array([0.1]), np.array([0.95])))[:, 0, 0]
    assert h[0, 0] / scale[0] > 2.0 * iso[0] and h[-1, 0] / scale[-1] < 0.8 * iso[-1]
    iso_total = _run(0.0, 0.95, 0.1, photons=20_000).R_diffuse
    assert abs(res.R_diffuse / iso_total - 1.0) < 0.1


@pytest.mark.parametrize("kw, match", [({"exit_mu_edges": [0.0, 1.5]}, "exit_mu_edges"),
                                       ({"exit_mu_edges": [0.5, 0.2]}, "exit_mu_edges"),
                                       ({"exit_mu_edges": EDGES, "exit_harmonics": 0}, "exit_harmonics")])
def test_bad_direction_tally_arguments_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        simulate(Stack.half_space(0.1, 1.0, 0.0, 1.0), 10, **kw)
