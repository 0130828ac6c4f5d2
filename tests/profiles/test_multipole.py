"""Tests of the multipole slab profile (photon-diffusion Eq. 12-13): the five kinds of DESIGN.md."""

from __future__ import annotations

import equinox as eqx
import iadpython
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import simpson

import jaxsss.profiles.multipole as multipole_module
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.medium import Medium
from jaxsss.profiles import dipole_profile
from jaxsss.profiles._sources import point_source_exitance, point_source_total
from jaxsss.profiles.multipole import multipole_depths, multipole_n_pairs, multipole_profile, multipole_totals
from jaxsss.reflectance import medium_total_diffuse_reflectance


@pytest.fixture(autouse=True)
def _strict_promotion():
    with jax.numpy_dtype_promotion("strict"):
        yield


def _medium(sigma_a, sigma_s_prime, eta, fresnel="poly"):
    return Medium(sigma_a=sigma_a, sigma_s_prime=sigma_s_prime, eta=eta, fresnel=fresnel)


# (sigma_a, sigma_s_prime, eta, thickness / l_u): moderate and weak absorption, index matched to strongly mismatched,
# thin (d ~ 1.5 l_u) to thick slabs.
SLABS = [
    (0.05, 1.0, 1.3, 1.5),
    (0.01, 2.0, 1.0, 4.0),
    (0.002, 1.5, 1.5, 10.0),
    (0.1, 0.9, 0.8, 2.0),
    (0.02, 1.0, 2.5, 30.0),
]


def _slab(case):
    sigma_a, sigma_s_prime, eta, d_over_lu = case
    m = _medium(sigma_a, sigma_s_prime, eta)
    return m, d_over_lu * float(m.l_u)


# --- 1. Reference values ------------------------------------------------------------------------------------------
# Simpson's rule in log r on 6001 points from 1e-7 l_u to 60 l_d + 40 L (the profile beyond is below e^-60 of its
# peak), with n_pairs converging the truncated totals to 1e-12: measured agreement 2e-14, tolerance 1e-12.
INTEGRAL_RTOL = 1e-12


@pytest.mark.parametrize("case", SLABS)
def test_plane_integral_equals_closed_form_totals(case):
    m, d = _slab(case)
    L = d + 2.0 * float(m.z_b)
    r_max = 60.0 / float(m.sigma_tr) + 40.0 * L
    r = np.geomspace(1e-7 * float(m.l_u), r_max, 6001)
    n = multipole_n_pairs(r, m, d, rtol=1e-12, floor=1e-4)
    R, T = multipole_profile(r, m, d, n_pairs=n)
    log_r = np.log(r)
    # Integral over the plane, d(area) = 2 pi r^2 d(log r); the disc inside r[0] adds pi r0^2 R(r0).
    R_int = simpson(2 * np.pi * r**2 * np.asarray(R), x=log_r) + np.pi * r[0] ** 2 * float(R[0])
    T_int = simpson(2 * np.pi * r**2 * np.asarray(T), x=log_r) + np.pi * r[0] ** 2 * float(T[0])
    R_tot, T_tot = multipole_totals(m, d)
    np.testing.assert_allclose(R_int, float(R_tot), rtol=INTEGRAL_RTOL)
    np.testing.assert_allclose(T_int, float(T_tot), rtol=INTEGRAL_RTOL)


@pytest.mark.parametrize("case", SLABS)
def test_closed_form_equals_sum_of_point_source_totals(case):
    # The geometric series against the explicit sum over 4001 sources: the neglected terms are below
    # exp(-2 n sigma_tr L) < 1e-30 here, so only summation round-off remains (tolerance 1e-13).
    m, d = _slab(case)
    z_r, z_v = multipole_depths(m, d, 2000)
    sigma_tr = m.sigma_tr
    R_sum = m.alpha_prime * jnp.sum(point_source_total(z_r, sigma_tr) - point_source_total(z_v, sigma_tr), axis=0)
    T_sum = m.alpha_prime * jnp.sum(
        point_source_total(d - z_r, sigma_tr) - point_source_total(d - z_v, sigma_tr), axis=0
    )
    R_tot, T_tot = multipole_totals(m, d)
    np.testing.assert_allclose(float(R_tot), float(R_sum), rtol=1e-13)
    np.testing.assert_allclose(float(T_tot), float(T_sum), rtol=1e-13)


@pytest.mark.parametrize("eta", [0.5, 1.0, 1.3, 2.5])
@pytest.mark.parametrize("d_over_lu", [1.0 + 1e-9, 1.5, 20.0, 1e6])
def test_non_absorbing_limit_conserves_energy(eta, d_over_lu):
    m = _medium(0.0, 1.7, eta)
    d = d_over_lu * float(m.l_u)
    L = d + 2.0 * float(m.z_b)
    R_tot, T_tot = multipole_totals(m, d)
    share = (float(m.l_u) + float(m.z_b)) / L
    np.testing.assert_allclose(float(R_tot), 1.0 - share, rtol=1e-14)
    np.testing.assert_allclose(float(T_tot), share, rtol=1e-14)
    np.testing.assert_allclose(float(R_tot + T_tot), 1.0, rtol=1e-15)


@pytest.mark.parametrize("sigma_tr_L", [1e-8, 0.0099, 0.0101, 0.5])
def test_sinh_ratio_branches_are_continuous(sigma_tr_L):
    # The series (sigma_tr L < 1e-2) and exponential branches of the totals against an mpmath-free float64
    # reference, sinh(s x)/sinh(s) evaluated directly (accurate here since s x > 1e-10), to 1e-13.
    s = sigma_tr_L
    x = np.array([-0.9, -0.3, 0.0, 0.2, 0.7, 1.0])
    got = multipole_module._sinh_ratio(jnp.asarray(x), 1.0, s * s)  # takes sigma_tr^2 (finite gradient at 0)
    with np.errstate(invalid="ignore"):
        ref = np.where(x == 0.0, 0.0, np.sinh(s * x) / np.sinh(s))
    np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-13, atol=1e-300)


# Exact slab transport (adding-doubling, iadpython) for g = 0, albedo 0.99, unit thickness, normal incidence.
# Normalisation: iadpython's UR1/UT1 are per *incident* flux and UR1 includes the specular reflection of the
# unscattered beam. We compare the diffuse reflectance UR1 - r_unscattered with (1 - R_s) R_total, and the total
# transmittance UT1 (the point source at depth l_u stands for the whole entering beam, ballistic part included) with
# (1 - R_s) T_total, where R_s is the normal-incidence Fresnel reflectance. Diffusion misses the anisotropy of the
# radiance near the boundaries: measured |relative error| <= 3.5% here, so the tolerance is 5%. The dipole, which has
# no bottom face, misses by more than 5% at b = 4 (checked below), so the test can tell the models apart.
IAD_RTOL = 0.05


@pytest.mark.parametrize("n", [1.0, 1.4])
@pytest.mark.parametrize("b", [4.0, 16.0])
def test_totals_against_adding_doubling(n, b):
    albedo, thickness = 0.99, 1.0
    m = _medium((1.0 - albedo) * b / thickness, albedo * b / thickness, n, fresnel="exact")
    R_tot, T_tot = multipole_totals(m, thickness)
    R_s = float(fresnel_reflectance(n, 1.0))
    sample = iadpython.Sample(a=albedo, b=b, g=0.0, n=n, quad_pts=16)
    UR1, UT1, _, _ = sample.rt()
    r_unscattered, _ = sample.unscattered_rt()
    np.testing.assert_allclose((1.0 - R_s) * float(R_tot), UR1 - r_unscattered, rtol=IAD_RTOL)
    np.testing.assert_allclose((1.0 - R_s) * float(T_tot), UT1, rtol=IAD_RTOL)
    if b == 4.0:
        R_dipole = (1.0 - R_s) * float(medium_total_diffuse_reflectance(m))
        assert abs(R_dipole / (UR1 - r_unscattered) - 1.0) > IAD_RTOL


def test_host_mirror_matches_point_source_exitance():
    z = np.array([-3.0, -1e-3, 0.0, 2e-3, 5.0])[:, None]
    r = np.array([0.0, 1e-4, 0.7, 40.0])
    np.testing.assert_allclose(
        multipole_module._np_exitance(z, r, 0.3), np.asarray(point_source_exitance(z, r, 0.3)), rtol=1e-15, atol=0
    )


# --- 2. Shapes ----------------------------------------------------------------------------------------------------
def test_scalar_channel_and_batched_shapes_agree():
    sigma_a = np.array([0.003, 0.02, 0.1])
    sigma_s_prime = np.array([2.0, 1.3, 0.8])
    eta, d = 1.4, np.array([2.0, 3.0, 5.0])
    r = np.array([0.0, 0.3, 2.0, 9.0])
    m3 = _medium(sigma_a, sigma_s_prime, eta)
    n = 64
    R_b, T_b = multipole_profile(r[:, None], m3, d, n_pairs=n)
    assert R_b.shape == T_b.shape == (4, 3)
    R_c, T_c = multipole_profile(r[1], m3, d, n_pairs=n)
    assert R_c.shape == (3,)
    Rt_b, Tt_b = multipole_totals(m3, d)
    assert Rt_b.shape == (3,)
    for c in range(3):
        mc = _medium(sigma_a[c], sigma_s_prime[c], eta)
        Rt, Tt = multipole_totals(mc, d[c])
        assert np.shape(Rt) == ()
        np.testing.assert_allclose([Rt, Tt], [Rt_b[c], Tt_b[c]], rtol=1e-15)
        np.testing.assert_allclose([R_c[c], T_c[c]], [R_b[1, c], T_b[1, c]], rtol=1e-15)
        for k, rk in enumerate(r):
            R, T = multipole_profile(rk, mc, d[c], n_pairs=n)
            assert R.shape == ()
            np.testing.assert_allclose([R, T], [R_b[k, c], T_b[k, c]], rtol=1e-14)
    z_r, z_v = multipole_depths(m3, d, 5)
    assert z_r.shape == z_v.shape == (11, 3)
    np.testing.assert_allclose(z_r[5], m3.l_u, rtol=1e-15)
    np.testing.assert_allclose(z_v[5], -(m3.l_u + 2 * m3.z_b), rtol=1e-15)


def test_accumulating_kernel_matches_explicit_sum_over_depths():
    # The kernel adds one pair per iteration; the reference materialises every source from multipole_depths.
    m, d = _slab(SLABS[1])
    r = np.linspace(0.0, 5.0, 7)
    z_r, z_v = (np.asarray(z) for z in multipole_depths(m, d, 40))
    sig, alpha = float(m.sigma_tr), float(m.alpha_prime)
    E = lambda z: np.asarray(point_source_exitance(z[:, None], r, sig))  # noqa: E731
    R_ref = alpha * np.sum(E(z_r) - E(z_v), axis=0)
    T_ref = alpha * np.sum(E(d - z_r) - E(d - z_v), axis=0)
    R, T = multipole_profile(r, m, d, n_pairs=40)
    np.testing.assert_allclose(R, R_ref, rtol=1e-13)
    np.testing.assert_allclose(T, T_ref, rtol=1e-13)


# --- 3. Bad and extreme input -------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
@pytest.mark.parametrize("fn", ["profile", "totals", "depths", "n_pairs"])
def test_bad_thickness_names_the_argument(bad, fn):
    m = _medium(0.01, 1.0, 1.3)
    call = {
        "profile": lambda: multipole_profile(1.0, m, bad, n_pairs=4),
        "totals": lambda: multipole_totals(m, bad),
        "depths": lambda: multipole_depths(m, bad, 4),
        "n_pairs": lambda: multipole_n_pairs(1.0, m, bad),
    }[fn]
    with pytest.raises(ValueError, match="thickness=") as err:
        call()
    if bad == np.inf:
        assert "dipole_profile" in str(err.value)


def test_bad_r_and_n_pairs():
    m = _medium(0.01, 1.0, 1.3)
    with pytest.raises(ValueError, match=r"multipole_profile\(r=-1\)"):
        multipole_profile(-1.0, m, 2.0, n_pairs=4)
    with pytest.raises(ValueError, match="n_pairs=-1"):
        multipole_profile(1.0, m, 2.0, n_pairs=-1)
    with pytest.raises(TypeError, match="n_pairs=2.5"):
        multipole_profile(1.0, m, 2.0, n_pairs=2.5)


def test_traced_call_without_n_pairs_is_a_clear_error():
    m = _medium(0.01, 1.0, 1.3)
    with pytest.raises(ValueError, match="pass a static n_pairs"):
        jax.jit(lambda r: multipole_profile(r, m, 2.0))(1.0)
    with pytest.raises(ValueError, match="pass a static n_pairs"):
        jax.grad(lambda d: multipole_profile(1.0, m, d)[0])(2.0)
    # With n_pairs the same transformations work.
    assert np.isfinite(jax.grad(lambda d: multipole_profile(1.0, m, d, n_pairs=8)[1])(2.0))


def test_max_pairs_reached_is_reported():
    m0 = _medium(0.0, 1.0, 1.3)
    # Without absorption the totals criterion is skipped (no finite n meets it); the pointwise one still caps.
    with pytest.raises(ValueError, match="profile R"):
        multipole_n_pairs(1.0, m0, 2.0, max_pairs=64)
    # Far field of a thin, nearly non-absorbing slab (sigma_tr r ~ 0.2): r / L ~ 550 pairs are not enough (it takes
    # 65536 at rtol 1e-8).
    m = _medium(1e-9, 1.0, 1.3)
    with pytest.raises(ValueError, match="far-field radii"):
        multipole_n_pairs(3000.0, m, 2.0, max_pairs=256, check_totals=False)
    # Without absorption the profile itself converges (algebraically) near the axis.
    n0 = multipole_n_pairs([0.0, 1.0], m0, 2.0, rtol=1e-6)
    assert n0 <= 4096 and n0 == multipole_n_pairs([0.0, 1.0], m0, 2.0, rtol=1e-6, check_totals=False)


def _all_values(p, r, n_pairs=32):
    """R(r), T(r), R_total, T_total as one vector, a function of p = (sigma_a, sigma_s', eta, d)."""
    m = _medium(p[0], p[1], p[2])
    R, T = multipole_profile(r, m, p[3], n_pairs=n_pairs)
    R_tot, T_tot = multipole_totals(m, p[3])
    return jnp.concatenate([R, T, jnp.stack([R_tot, T_tot])])


def _with_aux(p, r):
    y = _all_values(p, r)
    return y, y


# One compilation each (compiling is the slow part of this file): Jacobian and values together.
_jacfwd = jax.jit(jax.jacfwd(_with_aux, has_aux=True))
_jacrev = jax.jit(jax.jacrev(_with_aux, has_aux=True))


def _values(p, r):
    return _jacrev(p, r)[1]


@pytest.mark.parametrize("d_over_lu", [1e-4, 1e6])
@pytest.mark.parametrize("sigma_a", [1e-9, 0.05, 5.0])
def test_thin_and_huge_slabs_are_finite_with_finite_gradients(d_over_lu, sigma_a):
    r = jnp.array([0.0, 0.5, 30.0])
    p = jnp.array([sigma_a, 1.0, 1.3, d_over_lu / (sigma_a + 1.0)])
    for jacobian in (_jacrev, _jacfwd):
        J, y = jacobian(p, r)
        assert np.all(np.isfinite(y)) and np.all(np.isfinite(J))


def test_thin_slab_documented_behaviour():
    # d < l_u: the real source lies below the bottom face (module docstring). Without absorption
    # R_total + T_total = 0 with R_total = (d + z_b - l_u)/L; T_total jumps by -alpha' as d falls through l_u;
    # T(r) can take either sign.
    m = _medium(0.0, 1.0, 1.0)
    d = 0.2 * float(m.l_u)
    L = d + 2 * float(m.z_b)
    R_tot, T_tot = multipole_totals(m, d)
    np.testing.assert_allclose(float(R_tot), (d + float(m.z_b) - float(m.l_u)) / L, rtol=1e-13)
    np.testing.assert_allclose(float(R_tot + T_tot), 0.0, atol=1e-15)
    m = _medium(0.05, 1.0, 1.3)
    l_u = float(m.l_u)
    T_below = float(multipole_totals(m, l_u * (1 - 1e-12))[1])
    T_above = float(multipole_totals(m, l_u * (1 + 1e-12))[1])
    np.testing.assert_allclose(T_below - T_above, -float(m.alpha_prime), rtol=1e-9)
    _, T0 = multipole_profile(0.0, m, 0.5 * l_u, n_pairs=64)
    assert float(T0) < 0.0


# --- 4. Physical invariants ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("eta", [0.5, 1.0, 1.3, 2.5])
@pytest.mark.parametrize("sigma_a", [1e-3, 0.1])
def test_thick_slab_limit_is_the_dipole(eta, sigma_a):
    # At d = 100 l_d + 10 l_u the first image pairs are damped by exp(-2 sigma_tr L) < e^-200: the multipole equals
    # the dipole to round-off (1e-13 relative) out to r = 20 l_d, and T vanishes.
    m = _medium(sigma_a, 1.0, eta)
    d = 100.0 * float(m.l_d) + 10.0 * float(m.l_u)
    r = np.concatenate([[0.0], np.geomspace(1e-3, 20.0, 25) * float(m.l_d)])
    R, T = multipole_profile(r, m, d)
    np.testing.assert_allclose(np.asarray(R), np.asarray(dipole_profile(r, m)), rtol=1e-13)
    assert float(jnp.max(T)) < 1e-40
    R_tot, T_tot = multipole_totals(m, d)
    np.testing.assert_allclose(float(R_tot), float(medium_total_diffuse_reflectance(m)), rtol=1e-13)
    assert float(T_tot) < 1e-40


GRID = [(sa, eta, dl) for sa in (1e-6, 1e-2, 0.5, 5.0) for eta in (0.5, 1.0, 1.4) for dl in (1.0, 1.3, 4.0, 50.0)]


@pytest.mark.parametrize("sigma_a, eta, d_over_lu", GRID)
def test_nonnegative_decreasing_and_bounded(sigma_a, eta, d_over_lu):
    m = _medium(sigma_a, 1.0, eta)
    d = d_over_lu * float(m.l_u)
    r = np.concatenate([[0.0], np.geomspace(1e-3, 10.0, 60)]) * float(m.l_u)
    R, T = multipole_profile(r, m, d, rtol=1e-6)
    R, T = np.asarray(R), np.asarray(T)
    # Round-off of the image sum is about 1e-16 of the peak: allow that much.
    tol_R, tol_T = 1e-14 * R[0], 1e-14 * max(T.max(), 1e-300)
    assert np.all(R >= -tol_R) and np.all(T >= -tol_T)
    assert np.all(np.diff(R) <= tol_R)
    R_tot, T_tot = (float(x) for x in multipole_totals(m, d))
    assert 0.0 <= R_tot <= 1.0 and 0.0 <= T_tot <= 1.0 and R_tot + T_tot <= 1.0 + 1e-15


# --- 5. Autodiff --------------------------------------------------------------------------------------------------
def _central_differences(f, p, rel_step=1e-3):
    """Five-point central differences (truncation error ~ rel_step^4), one column per parameter."""
    p = np.asarray(p, dtype=np.float64)
    cols = []
    for k in range(p.size):
        h = rel_step * abs(p[k])
        e = np.zeros_like(p)
        e[k] = h
        f_ = lambda q: np.asarray(f(jnp.asarray(q)))  # noqa: E731
        cols.append((8 * (f_(p + e) - f_(p - e)) - (f_(p + 2 * e) - f_(p - 2 * e))) / (12 * h))
    return np.stack(cols, axis=-1)


# (sigma_a, sigma_s_prime, eta, d): ordinary, weak absorption with sigma_tr L ~ 0.008, just below the series switch
# (stiff), strong mismatch, and a thin slab with d just above l_u. eta = 1 itself is avoided: the "poly" F_dr fit
# switches formula there and its derivative jumps (jaxsss.fresnel), so central differences straddle a kink.
# The last entry is the relative step of the differences.
GRAD_POINTS = [
    (0.02, 1.1, 1.3, 3.0, 1e-3),
    (2.0e-6, 1.0, 1.05, 2.0, 1e-3),
    (0.3, 2.0, 2.5, 1.5, 1e-3),
    (0.05, 1.0, 1.4, 1.01, 1e-4),
]


@pytest.mark.parametrize("point", GRAD_POINTS)
def test_gradients_match_central_differences(point):
    r = jnp.array([0.0, 0.4, 2.5])
    p = jnp.asarray(point[:4])
    fd = _central_differences(lambda q: _values(q, r), p, rel_step=point[4])
    # Five-point differences: truncation ~(h / scale)^4, where the scale is d - l_u = 0.058 mm at the thin point (so
    # h = 1e-4 relative there, 1e-3 elsewhere); round-off eps |f| / (h |f'|) is largest at the weakly absorbing
    # point, where d ln R / d ln sigma_a ~ 2e-6, giving ~1e-7. Tolerance 1e-6, with an
    # absolute floor of 1e-8 of the largest derivative for entries that nearly vanish.
    atol = 1e-8 * np.abs(fd).max()
    np.testing.assert_allclose(np.asarray(_jacfwd(p, r)[0]), fd, rtol=1e-6, atol=atol)
    np.testing.assert_allclose(np.asarray(_jacrev(p, r)[0]), fd, rtol=1e-6, atol=atol)


def test_second_call_does_not_retrace(monkeypatch):
    r = np.linspace(0.0, 3.0, 5)
    # The kernel, as multipole_profile calls it eagerly: new values, same shapes and n_pairs -> no new trace.
    kernel = eqx.filter_jit(eqx.debug.assert_max_traces(multipole_module._profile_sums, max_traces=1))
    monkeypatch.setattr(multipole_module, "_profile_kernel", kernel)
    for sigma_a, d in [(0.01, 2.0), (0.03, 2.5), (0.2, 7.0)]:
        multipole_profile(r, _medium(sigma_a, 1.0, 1.3), d, n_pairs=16)
    # A user's jit around it, with n_pairs fixed (the inner kernel is traced once per outer trace: restore it).
    monkeypatch.undo()
    user = eqx.filter_jit(
        eqx.debug.assert_max_traces(lambda r, m, d: multipole_profile(r, m, d, n_pairs=16), max_traces=1)
    )
    for sigma_a, d in [(0.01, 2.0), (0.03, 2.5)]:
        user(jnp.asarray(r), _medium(sigma_a, 1.0, 1.3), jnp.asarray(d))
    # And the totals.
    totals = eqx.filter_jit(eqx.debug.assert_max_traces(multipole_totals, max_traces=1))
    for sigma_a, d in [(0.01, 2.0), (0.03, 2.5)]:
        totals(_medium(sigma_a, 1.0, 1.3), jnp.asarray(d))
