"""The x-y exit histogram split by scattering order (R_xy_order), added for the photon-diffusion comparisons."""

import numpy as np

from jaxsss.mc import Stack, simulate


def test_xy_histogram_by_order_sums_to_the_total_and_matches_the_radial_split():
    edges = np.linspace(-30.0, 30.0, 61)
    res = simulate(Stack.half_space(0.05, 2.0, 0.0, 1.33), 6_000, seed=5, lanes=1024, angle_deg=45.0,
                   xy_edges=edges)
    assert res.R_xy_order.shape == (3, 60, 60)
    np.testing.assert_allclose(res.R_xy_order.sum(axis=0), res.R_xy, rtol=1e-12, atol=1e-300)
    cell = np.outer(np.diff(edges), np.diff(edges))
    inside = (res.R_xy_order * cell).sum(axis=(1, 2))
    # Every order's light inside the grid is at most its total, and nearly all of it (the grid spans 60 l_u).
    assert np.all(inside <= res.R_order + 1e-15)
    assert inside[2] > 0.97 * res.R_order[2] and inside[1] > 0.999 * res.R_order[1]
    # Single scattering leaves near the entry point; multiple scattering spreads further.
    xc = 0.5 * (edges[1:] + edges[:-1])
    r2 = xc[:, None] ** 2 + xc[None, :] ** 2
    spread = [(res.R_xy_order[k] * cell * r2).sum() / inside[k] for k in (1, 2)]
    assert spread[0] < spread[1]
    assert np.all(res.R_xy_order_stderr >= 0)
