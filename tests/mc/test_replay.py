"""Replay (perturbation) Monte Carlo: reweighting vs direct absorbing runs of the engine, bookkeeping, gradients, ESS."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc import Layer, Stack, simulate
from jaxsss.mc.replay import SIDE_CAP, SIDE_R, SIDE_T, photon_weights, rebin, record, replay
from tests.gradcheck import assert_grad_matches_fd

EDGES = np.linspace(0.0, 1.0, 11)
N = 40_000
# One-layer slab (MCML's slab03mm geometry) and a two-layer slab with different n, g and thickness per layer.
SLAB = Stack.slab(0.0, 20.0, 0.9, 1.33, 0.3)
TWO = Stack([Layer(0.0, 10.0, 0.8, 1.4, 0.1), Layer(0.0, 5.0, 0.5, 1.33, 0.3)], n_above=1.0, n_below=1.2)
KW = dict(r_edges=EDGES, batch_size=N, lanes=512)


@pytest.fixture(scope="module")
def samples():
    return {"slab": record(SLAB, N, seed=1, **KW), "two": record(TWO, N, seed=2, **KW)}


def _ssp(stack):
    return jnp.asarray(stack.sigma_s * (1.0 - stack.g))


def test_replay_matches_absorbing_simulation(samples):
    """Reweighted totals and profiles of the two-layer slab, away from the reference in both layers, equal a direct
    absorbing run of jaxsss.mc.simulate (independent seed) within 4 combined standard errors (a 4-sigma bound: ~1e-4
    false-failure chance per compared value). The one-layer slab is checked against MCML in tests/fitting."""
    base, sigma_a = TWO, [0.5, 0.05]
    ssp = _ssp(base) * jnp.asarray([0.95, 1.05])
    est = replay(samples["two"], jnp.asarray(sigma_a), ssp)
    layers = [Layer(sa, float(s) / (1.0 - g), g, n, d) for sa, s, g, n, d in
              zip(sigma_a, ssp, np.asarray(base.g), np.asarray(base.n), np.asarray(base.thickness))]
    direct = simulate(Stack(layers, base.n_above, base.n_below), N, seed=7, r_edges=EDGES, lanes=512)
    for mine, err, ref, ref_err in ((est.R, est.R_stderr, direct.R_diffuse, direct.R_diffuse_stderr),
                                    (est.T, est.T_stderr, direct.T, direct.T_stderr)):
        assert abs(float(mine) - ref) < 4.0 * math.hypot(float(err), ref_err), (float(mine), ref)
    for name in ("R_r", "T_r"):
        mine, err = np.asarray(getattr(est, name)), np.asarray(getattr(est, name + "_stderr"))
        ref, ref_err = getattr(direct, name), getattr(direct, name + "_stderr")
        z = (mine - ref) / np.hypot(err, ref_err)
        assert np.all(np.abs(z) < 4.0), (name, z)


def test_weight_bookkeeping(samples):
    """Every photon is recorded once; without absorption and at the reference, R + T + cap + specular = 1 exactly;
    the per-layer path lengths and scattering counts are consistent with the geometry."""
    s = samples["two"]
    side = np.asarray(s.side)
    assert side.shape == (N,) and set(np.unique(side)) <= {SIDE_R, SIDE_T, SIDE_CAP}
    assert s.capped == 0
    est = replay(s, jnp.zeros(2), _ssp(TWO))
    np.testing.assert_allclose(float(est.R + est.T + est.cap_bound) + float(s.R_specular), 1.0, rtol=1e-12)
    np.testing.assert_allclose(float(s.R_specular), float(fresnel_reflectance(1.4, 1.0)), rtol=1e-12)
    k, L = np.asarray(s.scatterings), np.asarray(s.path)
    assert np.all(k == np.round(k)) and np.all(k >= 0) and np.all(L >= 0)
    # A photon that scattered in layer 2 has crossed layer 1 at least twice when it leaves through the top.
    deep_R = (side == SIDE_R) & (k[:, 1] > 0)
    assert np.all(L[deep_R, 0] >= 2 * 0.1 - 1e-12)
    # Unscattered transmitted photons went straight down: path = thickness per layer, radius 0, first bin.
    straight = (side == SIDE_T) & (k.sum(axis=1) == 0)
    assert straight.sum() > 0
    np.testing.assert_allclose(L[straight], np.broadcast_to([0.1, 0.3], L[straight].shape), rtol=1e-12)
    assert np.all(np.asarray(s.radius)[straight] == 0.0) and np.all(np.asarray(s.bin)[straight] == 0)
    # Profiles integrate to the totals on the grid (rebinning keeps the sums).
    area = np.pi * np.diff(EDGES**2)
    inside = float(np.sum(np.asarray(est.R_r) * area))
    assert inside <= float(est.R) + 1e-15
    coarse = replay(rebin(s, EDGES[::5]), jnp.zeros(2), _ssp(TWO))
    np.testing.assert_allclose(np.sum(np.asarray(coarse.R_r) * np.pi * np.diff(EDGES[::5] ** 2)), inside, rtol=1e-12)


def test_unscattered_transmittance_closed_form(samples):
    """The replayed unscattered transmittance of the slab, at coefficients other than the reference, matches the
    closed form with all-or-none Fresnel bounces, (1 - R)^2 e^-tau / (1 - R^2 e^-2 tau), within 4 standard errors
    (binomial: the reference run's unscattered count)."""
    s = samples["slab"]
    sa, ssp = 0.5, 1.5
    tau = (sa + ssp / (1.0 - 0.9)) * 0.3
    Rf = float(fresnel_reflectance(1.33, 1.0))
    exact = (1.0 - Rf) ** 2 * math.exp(-tau) / (1.0 - Rf**2 * math.exp(-2.0 * tau))
    est = float(replay(s, jnp.asarray([sa]), jnp.asarray([ssp])).T_unscattered)
    # Standard error: the reference run's unscattered fraction p has binomial error sqrt(p (1 - p) / N); the weight
    # ratio of these photons is one number, so the relative errors agree.
    p = float(np.mean((np.asarray(s.side) == SIDE_T) & (np.asarray(s.scatterings).sum(axis=1) == 0)))
    assert abs(est - exact) < 4.0 * exact * math.sqrt((1.0 - p) / (p * N))


def test_gradient_matches_finite_differences(samples):
    """d/d(sigma_a, sigma_s') of a mix of profile bins and totals (two layers): reverse and forward mode against
    central differences (the replayed sample is fixed, so the function is smooth)."""
    s = samples["two"]

    def f(x):
        e = replay(s, x[:2], x[2:])
        return e.R_r[3] + 2.0 * e.T + e.R_r[0] * e.T_r[1]

    assert_grad_matches_fd(f, np.array([0.4, 0.05, 2.1, 2.4]), rtol=1e-6)


def test_ess(samples):
    """ess_fraction is 1 at the reference, falls monotonically as sigma_s' moves away either way, and ESS never
    exceeds the number of detected photons; absorption alone leaves ess_fraction at 1."""
    s = samples["slab"]
    ssp0 = float(_ssp(SLAB)[0])
    at = lambda sa, f: replay(s, jnp.asarray([sa]), jnp.asarray([ssp0 * f]))  # noqa: E731
    np.testing.assert_allclose(float(at(0.0, 1.0).ess_fraction), 1.0, rtol=1e-12)
    np.testing.assert_allclose(float(at(1.0, 1.0).ess_fraction), 1.0, rtol=1e-12)
    up = [float(at(0.1, f).ess_fraction) for f in (1.0, 1.05, 1.2, 1.5)]
    down = [float(at(0.1, f).ess_fraction) for f in (1.0, 0.95, 0.8, 0.6)]
    assert np.all(np.diff(up) < 0) and np.all(np.diff(down) < 0), (up, down)
    assert up[-1] < 0.5
    assert float(at(0.1, 1.3).ess) <= float(np.sum(np.asarray(s.side) != SIDE_CAP))


def test_cap_bound():
    """A half-space without absorption: walks capped at max_path are recorded, and cap_bound is their replayed
    weight: w0 per capped photon at sigma_a = 0, at most w0 exp(-sigma_a max_path) with absorption."""
    s = record(Stack.half_space(0.0, 10.0, 0.0, 1.0), N, max_path=3.0, **KW)  # the slab's compiled walk
    capped = s.capped
    assert capped > 0
    w0 = float(s.w0)
    np.testing.assert_allclose(float(replay(s, jnp.zeros(1), jnp.full(1, 10.0)).cap_bound), capped * w0 / N,
                               rtol=1e-12)
    bound = float(replay(s, jnp.full(1, 0.5), jnp.full(1, 10.0)).cap_bound)
    assert 0.0 < bound <= capped * w0 * math.exp(-0.5 * 3.0) / N * (1.0 + 1e-12)
    np.testing.assert_allclose(np.asarray(s.path)[np.asarray(s.side) == SIDE_CAP].sum(axis=1), 3.0, atol=1.0)


def test_photon_weights_formula(samples):
    """The per-photon weight is w0 prod (mus/mus0)^k exp(-(mus + mua - mus0) L), checked on a few photons in NumPy."""
    s = samples["two"]
    sa, ssp = np.array([0.2, 0.07]), np.array([2.5, 2.2])
    w, _ = photon_weights(s, jnp.asarray(sa), jnp.asarray(ssp))
    mus, mus0 = ssp / (1.0 - np.asarray(TWO.g)), np.asarray(TWO.sigma_s)
    k, L = np.asarray(s.scatterings)[:50], np.asarray(s.path)[:50]
    ref = float(s.w0) * np.prod((mus / mus0) ** k * np.exp(-(mus + sa - mus0) * L), axis=1)
    np.testing.assert_allclose(np.asarray(w)[:50], ref, rtol=1e-10)


@pytest.mark.parametrize("kwargs,match", [
    (dict(stack=Stack.slab(0.1, 0.0, 0.0, 1.0, 1.0)), r"sigma_s\[0\]=0"),
    (dict(photons=1), r"photons=1"),
    (dict(r_edges=[0.0, 1.0, 1.0]), r"r_edges"),
    (dict(max_path=-1.0), r"max_path=-1"),
    (dict(stack="slab"), r"stack="),
])
def test_record_rejects_bad_input(kwargs, match):
    args = dict(stack=SLAB, photons=16, r_edges=EDGES) | kwargs
    with pytest.raises(ValueError, match=match):
        record(args.pop("stack"), args.pop("photons"), **args)


def test_replay_rejects_bad_input(samples):
    s = samples["two"]
    with pytest.raises(ValueError, match=r"sigma_a=array of shape \(1,\)"):
        replay(s, jnp.zeros(1), jnp.ones(2))
    with pytest.raises(ValueError, match=r"sigma_a=\[-0.1, 0.0\]\) is outside the allowed range \[0, inf\)"):
        replay(s, jnp.asarray([-0.1, 0.0]), jnp.ones(2))
    with pytest.raises(ValueError, match=r"sigma_s_prime=\[1.0, 0.0\]\) is outside the allowed range \(0, inf\)"):
        replay(s, jnp.zeros(2), jnp.asarray([1.0, 0.0]))
    with pytest.raises(ValueError, match=r"sigma_a=\[nan, 0.0\]"):
        replay(s, jnp.asarray([np.nan, 0.0]), jnp.ones(2))
