"""The quarter-space Monte Carlo (right-angled edge): exact weight bookkeeping, the half-space limit, symmetry,
determinism and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxsss.mc import Stack, simulate
from jaxsss.mc.edge import simulate_edge

U = np.linspace(0.0, 6.0, 13)
Y = np.linspace(-3.0, 3.0, 13)


def run(photons, edge_distance, seed=1, **kw):
    return simulate_edge(0.05, 0.95, 0.0, 1.3, photons, edge_distance=edge_distance,
                         top_edges=(U + max(edge_distance - 3.0, 0.0), Y), side_edges=(U, Y), seed=seed, lanes=512,
                         **kw)


def test_weight_bookkeeping_is_exact_and_energy_is_conserved():
    res = run(4_000, 0.5, max_steps=10**6)
    # Every packet's weight ends in exactly one tally.
    assert res.weight_balance == pytest.approx(1.0, abs=1e-12)
    assert abs(res.roulette_balance) < 5e-3
    err = res.R_top_stderr + res.R_side_stderr + res.A_stderr
    assert abs(res.R_specular + res.R_top + res.R_side + res.A - 1.0) <= 3 * err + 5e-3
    assert res.R_side > 0.05  # a beam 0.5 mm from the edge loses much light through the side
    np.testing.assert_allclose(res.R_top_order.sum(), res.R_top, rtol=1e-12)
    # Histograms sum (within the grid) to no more than the totals, order by order.
    cell = np.outer(np.diff(U), np.diff(Y))
    assert np.all((res.side_hist * cell).sum(axis=(1, 2)) <= res.R_side_order + 1e-15)


def test_far_from_the_edge_is_the_half_space():
    # The side face 40 transport lengths away: R_top equals the half-space MC's R_diffuse within the joint error.
    far = run(20_000, 40.0, seed=2)
    half = simulate(Stack.half_space(0.05, 0.95, 0.0, 1.3), 20_000, seed=3, lanes=512)
    assert far.R_side < 1e-3
    assert abs(far.R_top - half.R_diffuse) <= 4 * math.hypot(far.R_top_stderr, half.R_diffuse_stderr)
    assert far.R_specular == pytest.approx(half.R_specular, rel=1e-14)


def test_side_histogram_is_even_in_y_and_deterministic():
    a = run(20_000, 1.0, seed=4)
    b = run(20_000, 1.0, seed=4)
    np.testing.assert_array_equal(a.side_hist, b.side_hist)
    # Mirror symmetry y -> -y of the side face's total exitance per y-strip, within 4 standard errors.
    cell = np.outer(np.diff(U), np.diff(Y))
    strip = (a.side_hist.sum(axis=0) * cell).sum(axis=0)
    strip_err = np.sqrt(((a.side_hist_stderr * cell) ** 2).sum(axis=(0, 1)))
    assert np.all(np.abs(strip - strip[::-1]) <= 4 * np.hypot(strip_err, strip_err[::-1]) + 1e-12)


@pytest.mark.parametrize("kw,match", [(dict(edge_distance=-1.0), r"simulate_edge\(edge_distance=-1\)"),
                                      (dict(photons=0), r"simulate_edge\(photons=0\)"),
                                      (dict(g=1.0), r"simulate_edge\(g=1\)")])
def test_bad_input(kw, match):
    args = dict(sigma_a=0.1, sigma_s=1.0, g=0.0, n=1.3, photons=10, edge_distance=1.0, top_edges=(U, Y),
                side_edges=(U, Y)) | kw
    with pytest.raises(ValueError, match=match):
        simulate_edge(**args)
