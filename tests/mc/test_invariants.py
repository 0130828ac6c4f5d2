"""Physical invariants, bookkeeping, determinism, layering, similarity, the step cap, compilation and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

import jaxsss.mc.engine as engine
from jaxsss.mc import Layer, MCResult, Stack, simulate

LANES = 1024


def test_weight_bookkeeping_is_exact():
    # Every packet's weight ends in exactly one tally, so R_s + R_d + T + A + roulette + cap = 1 to rounding.
    stacks = [Stack.slab(0.3, 2.0, 0.8, 1.4, 0.7), Stack.half_space(0.01, 1.0, 0.0, 1.5),
              Stack([Layer(0.1, 3.0, 0.9, 1.37, 0.2), Layer(0.02, 1.0, 0.0, 1.5, 1.0), Layer(0.0, 0.0, 0.0, 1.0, 0.5)],
                    n_above=1.0, n_below=1.33)]
    for stack in stacks:
        res = simulate(stack, 5_000, seed=1, lanes=LANES, angle_deg=25.0)
        assert res.weight_balance == pytest.approx(1.0, abs=1e-12)
        # The roulette is fair: its net weight is zero in expectation (a loose bound: it is a tiny tally).
        assert abs(res.roulette_balance) < 5e-3
        # R + T + A = 1 within the errors (roulette fluctuations included).
        err = res.R_diffuse_stderr + res.T_stderr + res.A_stderr
        assert abs(res.R_total + res.T + res.A - 1.0) <= 3 * err + 1e-3
        assert res.A_layer.shape == (stack.num_layers,)
        assert res.A_layer.sum() == pytest.approx(res.A, rel=1e-12)
    assert res.A_layer[2] == 0.0  # the clear bottom layer absorbs nothing


def test_determinism():
    stack = Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0)
    kw = dict(lanes=LANES, r_edges=np.linspace(0.0, 3.0, 7))
    a = simulate(stack, 3_000, seed=11, **kw)
    b = simulate(stack, 3_000, seed=11, **kw)
    c = simulate(stack, 3_000, seed=12, **kw)
    assert a.R_diffuse == b.R_diffuse and a.T == b.T and a.A == b.A
    np.testing.assert_array_equal(a.R_r, b.R_r)
    assert a.R_diffuse != c.R_diffuse
    assert not np.array_equal(a.R_r, c.R_r)


def test_batches_are_independent_streams():
    # Several batches: same expectation as one, and the batches differ from one another (else the error would lie).
    stack = Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0)
    res = simulate(stack, 20_000, seed=2, lanes=LANES, batch_size=4_000, progress=False)
    assert res.batches == 5
    assert abs(res.R_diffuse - 0.09739) <= 3 * res.R_diffuse_stderr + 1e-3


def test_two_identical_layers_equal_the_slab():
    one = simulate(Stack.slab(0.2, 3.0, 0.6, 1.4, 2.0), 20_000, seed=3, lanes=LANES)
    two = simulate(Stack([Layer(0.2, 3.0, 0.6, 1.4, 0.5), Layer(0.2, 3.0, 0.6, 1.4, 1.5)]), 20_000, seed=4,
                   lanes=LANES)
    for key in ("R_diffuse", "T", "A"):
        err = math.hypot(getattr(one, key + "_stderr"), getattr(two, key + "_stderr"))
        assert abs(getattr(one, key) - getattr(two, key)) <= 3 * err + 1e-3, key
    assert one.R_specular == two.R_specular


def test_similarity_relation_far_from_the_source():
    # g = 0.9 with sigma_s against g = 0 with sigma_s' = (1 - g) sigma_s, alpha' = 0.99, l' = 1 / sigma_t' = 0.99 mm.
    # Measured (40k photons each) ratio R_aniso / R_iso by r: 0.47 (r < 0.2 mm), 1.25 (2-3 mm), 1.12 (4.5-7 mm),
    # 1.10 (7-10 mm), 1.02 +- 0.04 (10-15 mm): the relation holds only beyond ~10 transport mean free paths (the
    # isotropic medium's stronger low-order reflection near the source takes energy from its far field). So the
    # far band is 10-16 mm, tolerance 3 standard errors plus 5% for the relation's residual there.
    sigma_a, sigma_s_prime, g = 0.01, 1.0, 0.9
    edges = np.array([0.0, 0.2, 10.0, 16.0])
    aniso = simulate(Stack.half_space(sigma_a, sigma_s_prime / (1 - g), g, 1.0), 30_000, seed=5, lanes=LANES,
                     r_edges=edges)
    iso = simulate(Stack.half_space(sigma_a, sigma_s_prime, 0.0, 1.0), 30_000, seed=6, lanes=LANES, r_edges=edges)
    far = 2
    err = math.hypot(aniso.R_r_stderr[far], iso.R_r_stderr[far])
    assert abs(aniso.R_r[far] - iso.R_r[far]) <= 3 * err + 0.05 * iso.R_r[far], (aniso.R_r[far], iso.R_r[far], err)
    # The test can fail: near the source (r < 0.2 mm) the forward-peaked medium reflects about half as much.
    err0 = math.hypot(aniso.R_r_stderr[0], iso.R_r_stderr[0])
    assert iso.R_r[0] - aniso.R_r[0] > 5 * err0 + 0.05 * iso.R_r[0]


def test_step_cap_is_reported():
    res = simulate(Stack.half_space(0.001, 1.0, 0.0, 1.0), 2_000, seed=1, lanes=LANES, max_steps=5)
    assert res.step_cap_hits > 0 and res.step_cap_weight > 0
    assert res.weight_balance == pytest.approx(1.0, abs=1e-12)
    ok = simulate(Stack.half_space(0.001, 1.0, 0.0, 1.0), 200, seed=1, lanes=LANES)
    assert ok.step_cap_hits == 0 and ok.step_cap_weight == 0.0


def test_oblique_xy_histogram_and_order_split():
    edges = np.linspace(-20.0, 20.0, 41)
    res = simulate(Stack.half_space(0.05, 2.0, 0.0, 1.33), 10_000, seed=2, lanes=LANES, angle_deg=60.0,
                   xy_edges=edges, r_edges=np.linspace(0.0, 20.0, 11))
    cell = np.outer(np.diff(edges), np.diff(edges))
    inside = np.sum(res.R_xy * cell)
    assert inside <= res.R_diffuse + 1e-15 and inside > 0.98 * res.R_diffuse
    # The oblique beam travels towards +x: its light re-emerges shifted that way, and the histogram is symmetric in y.
    xc = 0.5 * (edges[1:] + edges[:-1])
    mean_x = np.sum(res.R_xy * cell * xc[:, None]) / inside
    mean_y = np.sum(res.R_xy * cell * xc[None, :]) / inside
    assert mean_x > 0.05 and abs(mean_y) < 0.05
    assert res.R_order.sum() == pytest.approx(res.R_diffuse, rel=1e-12)
    np.testing.assert_allclose(res.R_r_order.sum(axis=0), res.R_r, rtol=1e-12)
    assert res.mean_exit_radius > 0 and res.mean_exit_radius_stderr > 0


def test_pathlength_resolved_reflectance_sums_to_the_profile():
    r_edges = np.linspace(0.0, 5.0, 6)
    p_edges = np.concatenate([[0.0], np.geomspace(1e-3, 1e5, 40)])
    res = simulate(Stack.slab(0.0, 1.0, 0.0, 1.0, 3.0), 5_000, seed=3, lanes=LANES, r_edges=r_edges,
                   pathlength_edges=p_edges)
    assert res.R_r_path.shape == (5, 40)
    # All pathlengths fall in [0, 1e5): summing over L gives R(r).
    np.testing.assert_allclose(res.R_r_path.sum(axis=1), res.R_r, rtol=1e-12)
    assert res.R_r_path_stderr.shape == res.R_r_path.shape and np.all(res.R_r_path_stderr >= 0)
    assert res.A == 0.0 and res.weight_balance == pytest.approx(1.0, abs=1e-12)


def test_kernel_compiles_once_per_structure():
    engine._COMPILED.clear()
    first = simulate(Stack.slab(0.1, 1.0, 0.5, 1.3, 1.0), 500, seed=1, lanes=LANES)
    again = simulate(Stack.slab(0.3, 2.0, 0.1, 1.5, 3.0), 700, seed=2, lanes=LANES, angle_deg=40.0)
    assert first.compile_seconds > 0 and again.compile_seconds == 0.0
    assert len(engine._COMPILED) == 1
    assert isinstance(again, MCResult)


@pytest.mark.parametrize(
    ("build", "fragment"),
    [
        (lambda: Layer(-0.1, 1.0), "Layer(sigma_a=-0.1) is outside the allowed range [0, inf)"),
        (lambda: Layer(0.1, -1.0), "Layer(sigma_s=-1) is outside the allowed range [0, inf)"),
        (lambda: Layer(0.1, 1.0, g=1.0), "Layer(g=1) is outside the allowed range (-1, 1)"),
        (lambda: Layer(0.1, 1.0, g=-1.5), "Layer(g=-1.5) is outside the allowed range (-1, 1)"),
        (lambda: Layer(0.1, 1.0, n=0.0), "Layer(n=0) is outside the allowed range (0, inf)"),
        (lambda: Layer(0.1, 1.0, n=float("nan")), "Layer(n=nan)"),
        (lambda: Stack.slab(0.1, 1.0, 0.0, 1.0, 0.0), "thickness=0) is outside the allowed range (0, inf)"),
        (lambda: Stack.slab(0.1, 1.0, 0.0, 1.0, -2.0), "thickness=-2) is outside the allowed range (0, inf)"),
        (lambda: Stack([Layer(0.1, 1.0), Layer(0.1, 1.0, thickness=1.0)]), "only the last layer"),
        (lambda: Stack([]), "non-empty"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 0), "simulate(photons=0) is outside the allowed range [1, inf)"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 2.5), "simulate(photons=2.5) must be an integer"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 10, r_edges=[0.0, 2.0, 1.0]), "not strictly increasing"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 10, r_edges=[-1.0, 2.0]), "simulate(r_edges=-1)"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 10, angle_deg=90.0), "simulate(angle_deg=90) is outside"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 10, pathlength_edges=[0.0, 1.0]), "needs r_edges"),
        (lambda: simulate(Stack.slab(0.1, 1.0), 10, seed=-1), "simulate(seed=-1)"),
    ],
)
def test_bad_input_names_argument_value_and_range(build, fragment):
    with pytest.raises(ValueError) as info:
        build()
    assert fragment in str(info.value)
