"""The stability matrix of the physics core (DESIGN.md): stiff and extreme parameters, values and gradients finite,
float32 within a stated distance of float64.

Grid: alpha' in {1e-6, 1e-3, 0.5, 0.99, 1 - 1e-9} x sigma_t' in {1e-4, 1e-2, 1, 1e2, 1e4} /mm x
eta in {0.5, 1, 1.0001, 1.3, 2.5} x r in {0, 1e-3, 1, 10, 1e4} l_d; slabs add thickness in
{1e-4, 1e-2, 1, 10, 1e4} l_u (infinity is the dipole). Every model added to the core adds its rows here.
sigma_a = 0 (alpha' = 1, l_d infinite) has its own rows: every forward model of the fitting registry (dipole,
multipole, mc) with finite values and gradients that match one-sided differences, and Rd (value 1, d/d sigma_a
truly -inf).

Stated float32 tolerances (relative to float64, measured maxima in brackets):
- dipole profile: 1e-5 wherever the float64 value exceeds 1e-30 (float32 underflows below ~1e-38) [1.3e-6];
- Rd (Eq. 15): 1e-6 [1.5e-7];
- multipole R(r), T(r) (8 pairs): 5e-3 where the float64 value exceeds 1e-30 -- in thick slabs far from the axis
  the image pairs cancel and float32 loses digits there [3.8e-3]; closed-form totals 1e-3 [8.2e-4];
- Rd inversion: alpha' and 1 - alpha' within 1e-4 relative, for Rd in [1e-6, 1 - 1e-3] (in float32, Rd closer to 1
  than ~1e-3 is not resolvable: 1 - Rd has few bits left) [alpha' 2.5e-6, 1 - alpha' 2.7e-5].
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.profiles.dipole import dipole_profile
from jaxsss.profiles.multipole import multipole_profile, multipole_totals
from jaxsss.reflectance import invert_rd, medium_total_diffuse_reflectance
from jaxsss.reparam import from_rd_ld

ALPHA = [1e-6, 1e-3, 0.5, 0.99, 1 - 1e-9]
SIGMA_T = [1e-4, 1e-2, 1.0, 1e2, 1e4]
ETA = [0.5, 1.0, 1.0001, 1.3, 2.5]
R_OVER_LD = [0.0, 1e-3, 1.0, 10.0, 1e4]
D_OVER_LU = [1e-4, 1e-2, 1.0, 10.0, 1e4]


def grid(*axes):
    return tuple(np.array(c) for c in zip(*itertools.product(*axes)))


def medium_arrays(alpha, sigma_t, eta):
    # sigma_a = sigma_t' (1 - alpha') without forming 1 - alpha' from a rounded alpha'.
    return sigma_t * (1 - alpha), sigma_t * alpha, eta


def profile(x):
    """Dipole profile at r = x[3] l_d for the medium (x[0], x[1], x[2])."""
    m = Medium(x[..., 0], x[..., 1], x[..., 2])
    return dipole_profile(x[..., 3] * m.l_d, m)


def rd_of(x):
    return medium_total_diffuse_reflectance(Medium(x[..., 0], x[..., 1], x[..., 2]))


@pytest.fixture(scope="module")
def profile_inputs():
    alpha, st, eta, r = grid(ALPHA, SIGMA_T, ETA, R_OVER_LD)
    sa, ss, eta = medium_arrays(alpha, st, eta)
    return np.stack([sa, ss, eta, r], axis=-1)


def test_dipole_values_and_gradients_finite(profile_inputs):
    x = jnp.asarray(profile_inputs)
    R = profile(x)
    assert bool(jnp.all(jnp.isfinite(R))) and bool(jnp.all(R >= 0))
    # Gradients of R itself (not its log) in every parameter, at every grid point.
    grads = jax.vmap(jax.grad(profile))(x)
    assert bool(jnp.all(jnp.isfinite(grads))), np.argwhere(~np.isfinite(np.asarray(grads)))[:5]


def test_dipole_float32_within_stated_tolerance(profile_inputs):
    R64 = np.asarray(profile(jnp.asarray(profile_inputs)))
    R32 = profile(jnp.asarray(profile_inputs, dtype=jnp.float32))
    assert R32.dtype == jnp.float32
    R32 = np.asarray(R32, dtype=np.float64)
    assert np.all(np.isfinite(R32))
    resolved = R64 > 1e-30
    assert np.max(np.abs(R32[resolved] / R64[resolved] - 1)) < 1e-5


@pytest.fixture(scope="module")
def medium_inputs():
    alpha, st, eta = grid(ALPHA, SIGMA_T, ETA)
    return np.stack(medium_arrays(alpha, st, eta), axis=-1)


def test_rd_values_gradients_and_float32(medium_inputs):
    x = jnp.asarray(medium_inputs)
    Rd = rd_of(x)
    assert bool(jnp.all(jnp.isfinite(Rd))) and bool(jnp.all((Rd > 0) & (Rd < 1)))
    assert bool(jnp.all(jnp.isfinite(jax.vmap(jax.grad(rd_of))(x))))
    Rd32 = np.asarray(rd_of(jnp.asarray(medium_inputs, dtype=jnp.float32)), dtype=np.float64)
    assert np.max(np.abs(Rd32 / np.asarray(Rd) - 1)) < 1e-6


def test_inversion_and_reparam_round_trip_over_the_grid(medium_inputs):
    x = jnp.asarray(medium_inputs)
    m = Medium(x[:, 0], x[:, 1], x[:, 2])
    Rd, ld = rd_of(x), m.l_d
    rep = from_rd_ld(Rd, ld, x[:, 2])
    assert bool(jnp.all(rep.converged))
    # Recovers sigma_a and sigma_s' across 8 decades of sigma_t' and the stiff albedos.
    np.testing.assert_allclose(rep.medium.sigma_a, m.sigma_a, rtol=1e-9)
    np.testing.assert_allclose(rep.medium.sigma_s_prime, m.sigma_s_prime, rtol=1e-9)

    def recovered(y):
        r = from_rd_ld(y[0], y[1], y[2]).medium
        return r.sigma_a + r.sigma_s_prime

    grads = jax.vmap(jax.grad(recovered))(jnp.stack([Rd, ld, x[:, 2]], axis=-1))
    assert bool(jnp.all(jnp.isfinite(grads)))


def test_inversion_float32_within_stated_tolerance():
    Rd = np.concatenate([np.logspace(-6, -1, 11), np.linspace(0.1, 0.999, 11)])
    A = np.array([0.45, 1.0, 4.3])
    R, AA = np.meshgrid(Rd, A)
    inv64 = invert_rd(R, AA)
    inv32 = invert_rd(R.astype(np.float32), AA.astype(np.float32))
    assert inv32.alpha_prime.dtype == jnp.float32 and bool(jnp.all(inv32.converged))
    for name in ("alpha_prime", "one_minus_alpha_prime"):
        a64 = np.asarray(getattr(inv64, name))
        a32 = np.asarray(getattr(inv32, name), dtype=np.float64)
        assert np.max(np.abs(a32 / a64 - 1)) < 1e-4, name


def slab(x):
    """Multipole R(r), T(r) at r = x[4] l_d and both totals, for thickness x[3] l_u, as one vector."""
    m = Medium(x[..., 0], x[..., 1], x[..., 2])
    d = x[..., 3] * m.l_u
    R, T = multipole_profile(x[..., 4] * m.l_d, m, d, n_pairs=8)
    return jnp.stack([R, T, *multipole_totals(m, d)], axis=-1)


@pytest.fixture(scope="module")
def slab_inputs():
    alpha, st, eta, d, r = grid(ALPHA, SIGMA_T, ETA, D_OVER_LU, [0.0, 1.0])
    return np.stack([*medium_arrays(alpha, st, eta), d, r], axis=-1)


def test_multipole_values_gradients_and_float32(slab_inputs):
    x = jnp.asarray(slab_inputs)
    v64 = slab(x)
    assert bool(jnp.all(jnp.isfinite(v64)))
    assert bool(jnp.all(jnp.isfinite(jax.vmap(jax.jacfwd(slab))(x))))
    v32 = slab(jnp.asarray(slab_inputs, dtype=jnp.float32))
    assert v32.dtype == jnp.float32
    v32, v64 = np.asarray(v32, dtype=np.float64), np.asarray(v64)
    for k, tol in enumerate([5e-3, 5e-3, 1e-3, 1e-3]):
        resolved = np.abs(v64[:, k]) > 1e-30
        assert np.max(np.abs(v32[resolved, k] / v64[resolved, k] - 1)) < tol, ["R", "T", "R_total", "T_total"][k]


# --- Renderer terms (jaxsss.render.radiance): disc integral, exit radiance, single scattering -------------------------
def _render_terms(x):
    """Near-field disc integral at rho0 = x[3] l_u, diffuse exit radiance at cos 0.3, and the single-scattering
    radiance for light at 60 degrees seen at 30 degrees, for the medium (x[0], x[1], x[2])."""
    from jaxsss.render import radiance as rad

    m = Medium(x[..., 0], x[..., 1], x[..., 2])
    disc = rad.disc_integral(x[..., 3] * m.l_u, m)
    exit_l = rad.exit_radiance(m, jnp.ones((1, 1), x.dtype), jnp.full((1,), 0.3, x.dtype))[0, 0]
    n = jnp.array([[0.0, 0.0, 1.0]], x.dtype)
    eye = jnp.array([[0.5, 0.0, np.sqrt(0.75)]], x.dtype)
    light = jnp.array([[[-np.sqrt(0.75), 0.0, 0.5]]], x.dtype)
    single = rad.single_scattering(m, n, eye, light, jnp.ones((1, 1, 1), x.dtype))[0, 0]
    return jnp.stack([disc, exit_l, single])


def test_render_terms_values_gradients_and_float32(medium_inputs):
    rho = np.array([0.0, 1e-3, 1.0, 1e3])
    x = np.concatenate([np.c_[medium_inputs, np.full(len(medium_inputs), r)] for r in rho])
    terms = jax.jit(jax.vmap(_render_terms))
    v = terms(jnp.asarray(x))
    assert bool(jnp.all(jnp.isfinite(v))) and bool(jnp.all(v >= 0))
    # The disc integral never exceeds Rd (Eq. 15) and reaches it for a large disc.
    rd = np.asarray(rd_of(jnp.asarray(x[:, :3])))
    assert np.all(np.asarray(v[:, 0]) <= rd * (1 + 1e-12))
    large = x[:, 3] == 1e3
    big_disc = large & (np.asarray(Medium(x[:, 0], x[:, 1], x[:, 2]).l_d) < 1e2 * np.asarray(
        Medium(x[:, 0], x[:, 1], x[:, 2]).l_u))
    np.testing.assert_allclose(np.asarray(v[big_disc, 0]), rd[big_disc], rtol=1e-6)
    grads = jax.jit(jax.vmap(jax.jacfwd(_render_terms)))(jnp.asarray(x))
    assert bool(jnp.all(jnp.isfinite(grads))), np.argwhere(~np.isfinite(np.asarray(grads)))[:5]
    v32 = np.asarray(terms(jnp.asarray(x, dtype=jnp.float32)), dtype=np.float64)
    v64 = np.asarray(v)
    resolved = v64 > 1e-30
    assert np.max(np.abs(v32[resolved] / v64[resolved] - 1)) < 1e-4


def _current_terms(q, shape: bool = True):
    """The exit's current behind a dielectric boundary (jaxsss.render.dielectric_current) at ``q = (alpha', eta,
    mu_o)``: the amplitude at every distance node and (``shape``) the exit shape at the three incidence nodes."""
    from jaxsss.render.exit_current import current_amplitude, current_exit_distribution

    albedo = q[0][None]
    a = current_amplitude(albedo, q[1])[:, 0]
    if not shape:
        return a
    y = current_exit_distribution(q[2][None], (1.0, 0.5, 0.1), albedo, q[1])[0, :, 0]
    return jnp.concatenate([a, y])


def test_dielectric_current_values_gradients_and_float32():
    """alpha' over the grid (with 0 and 1), eta from just above 1 to 2.5 (beyond the table: held), exit cosines 0 to
    1: values and gradients finite; in float32 the amplitude within 1e-6 of float64 [1.7e-7] and the exit shape (the
    refracted exit distribution's Chandrasekhar H-function times the tabulated shape) within 1e-4 [3.1e-5], 1e-2 at a
    grazing exit (mu_o = 1e-6, where the Fresnel transmittance 1 - F cancels [7.3e-3]), where they exceed 1e-12."""
    x = np.stack(grid(ALPHA + [0.0, 1.0], [1.0001, 1.1, 1.35, 1.6, 2.5], [0.0, 1e-6, 0.5, 1.0]), axis=1)
    terms = jax.jit(jax.vmap(_current_terms))
    v = np.asarray(terms(jnp.asarray(x)))
    assert np.all(np.isfinite(v))
    grads = np.asarray(jax.jit(jax.vmap(jax.jacfwd(_current_terms)))(jnp.asarray(x)))
    assert np.all(np.isfinite(grads)), np.argwhere(~np.isfinite(grads))[:5]
    v32 = terms(jnp.asarray(x, dtype=jnp.float32))
    assert v32.dtype == jnp.float32
    error = np.abs(np.asarray(v32, dtype=np.float64) / np.where(np.abs(v) > 1e-12, v, 1.0) - 1.0)
    error = np.where(np.abs(v) > 1e-12, error, 0.0)
    n_a = len(np.asarray(_current_terms(jnp.asarray(x[0]), shape=False)))
    grazing = x[:, 2] == 1e-6
    assert np.max(error[:, :n_a]) < 1e-6, error[:, :n_a].max()
    assert np.max(error[~grazing, n_a:]) < 1e-4 and np.max(error[grazing, n_a:]) < 1e-2, error[:, n_a:].max()


# --- sigma_a = 0 (a non-absorbing medium, which Medium accepts) for every forward model of the fitting registry ---
# The models are evaluated exactly as fits evaluate them (fitting.models.model_profiles, per incident photon).
# Values and gradients in (sigma_a, sigma_s', eta) must be finite at sigma_a = 0, and d/d sigma_a must equal the
# one-sided derivative: the profiles depend on sigma_a through sigma_tr^2 = 3 sigma_a sigma_t' (finite derivative;
# profiles/_sources.py), with a sqrt(sigma_a)^3 next term, so one-sided differences at steps h and 4h are
# Richardson-extrapolated (2 D(h) - D(4h) cancels the sqrt(h) error term). Radii are in l_u (l_d is infinite).
# The multipole uses 8 pairs here (beyond 2 n L the truncated series' next terms are not small at step h); the
# slab avoids d = l_u, where at r = 0 the real source of the bottom face sits in the plane (a true singularity).
ZERO_R_OVER_LU = [0.0, 1e-3, 0.5, 3.0, 1e4]
ZERO_FD_R_OVER_LU = [0.5, 3.0]


def _zero_cases():
    """``(model, static, grid of (sigma_s', eta, d/l_u))`` for each fitting model (``d`` unused by half-spaces)."""
    from jaxsss.mc import available_white_tables

    g, n = available_white_tables()[-1]  # one table: the others differ only in the tabulated numbers
    return [
        ("dipole", None, grid(SIGMA_T, ETA, [1.0])),
        ("multipole", 8, grid(SIGMA_T, [1.0, 1.3, 2.5], [0.3, 3.0, 30.0])),
        ("mc", (g, n), grid(SIGMA_T, [n], [1.0])),
    ]


def _zero_model(name, static):
    """``f(q, r_lu) -> vector of R (and T)`` for ``q = (sigma_a, sigma_s', eta, d/l_u)``: the registry's model at
    radii ``r_lu l_u`` (and thickness ``d l_u``), as fits evaluate it."""
    from fitting.models import mc_table, model_profiles, resolve_model

    model = resolve_model(name)
    if name == "mc":
        mc_table(*static)

    def f(q, r_lu):
        l_u = 1.0 / (q[0] + q[1])
        thickness = q[3] * l_u if model.needs_thickness else None
        out = model_profiles(model, jnp.asarray(r_lu) * l_u, q[0], q[1], q[2], thickness, static)
        return jnp.concatenate([out[k] for k in model.outputs])

    return f


@pytest.mark.parametrize("case", _zero_cases(), ids=lambda c: f"{c[0]}-{c[1]}")
def test_fitting_models_at_sigma_a_zero(case):
    name, static, (ss, eta, d) = case
    f = _zero_model(name, static)
    q0 = jnp.asarray(np.stack([np.zeros_like(ss), ss, eta, d], axis=-1))
    r = jnp.asarray(ZERO_R_OVER_LU)
    # Forward mode: what the fits use (fitting/_kernel.py forms the Jacobian with jax.jacfwd). One compilation serves
    # the values and the Jacobian (the finite differences reuse it and ignore its Jacobian).
    both = jax.jit(jax.vmap(jax.jacfwd(lambda q, r_lu: (f(q, r_lu), f(q, r_lu)), has_aux=True), in_axes=(0, None)))

    def values(q, r_lu):
        return both(q, r_lu)[1]

    jac, v = both(q0, r)
    assert bool(jnp.all(jnp.isfinite(v))), v
    if name != "multipole":  # 8 image pairs at sigma_a = 0 leave a truncation error of either sign (~1e-10 here)
        assert bool(jnp.all(v >= 0)), v
    assert bool(jnp.all(jnp.isfinite(jac))), np.argwhere(~np.isfinite(np.asarray(jac)))[:5]
    # d/d sigma_a against one-sided differences D(h) at h, 4h, 16h: D = g + a sqrt(h) + b h + O(h^1.5), so
    # E(h) = 2 D(h) - D(4h) = g - 2 b h and (4 E(h) - E(4h)) / 3 = g + O(h^1.5).
    fd_at = np.isin(np.asarray(ZERO_R_OVER_LU), ZERO_FD_R_OVER_LU)
    fd_at = np.concatenate([fd_at] * (v.shape[-1] // len(ZERO_R_OVER_LU)))
    h = np.asarray(1e-9 * q0[:, 1:2])
    base = np.asarray(v)[:, fd_at]
    D = {k: (np.asarray(values(q0.at[:, 0].set(k * h[:, 0]), r))[:, fd_at] - base) / (k * h) for k in (1, 4, 16)}
    E1, E4 = 2 * D[1] - D[4], 2 * D[4] - D[16]
    fd = (4 * E1 - E4) / 3
    grad = np.asarray(jac)[:, fd_at, 0]
    # Compared in units of R / sigma_t' (the derivative's natural scale) per medium. The multipole's 8th image pair
    # lies ~16 L from the surface, where sigma_tr d at step 16h is ~0.04: its O(h^1.5) remainder reaches 5e-5.
    scale = np.max(np.abs(base), axis=-1, keepdims=True) / np.asarray(q0[:, 1:2])
    atol = 1e-4 if name == "multipole" else 1e-5
    np.testing.assert_allclose(grad / scale, fd / scale, rtol=1e-4, atol=atol)


def test_rd_at_sigma_a_zero_is_one_with_the_true_infinite_derivative():
    # Rd ~ 1 - (1 + 2A/3) sqrt(3 sigma_a / sigma_s'): d Rd / d sigma_a is -inf at 0 (said, not nan); the other
    # derivatives are finite (zero); in u = sqrt(3 (1 - alpha')) the derivative is finite: -(1 + 2A/3).
    from jaxsss.reflectance import total_diffuse_reflectance_u

    ss, eta = grid(SIGMA_T, ETA)
    x = jnp.asarray(np.stack([np.zeros_like(ss), ss, eta], axis=-1))
    assert bool(jnp.all(rd_of(x) == 1.0))
    g = np.asarray(jax.jit(jax.vmap(jax.grad(rd_of)))(x))
    # Zero up to rounding in alpha' = sigma_s' / sigma_t' (measured 5e-13 at sigma_s' = 1e-4 /mm).
    assert np.all(g[:, 0] == -np.inf) and np.all(np.abs(g[:, 1:]) <= 1e-12 / ss[:, None]), g
    # Forward mode in (sigma_s', eta) with sigma_a held fixed (a symbolic-zero tangent; an explicit zero tangent
    # would meet the infinite coefficient: 0 * inf, as documented in medium_total_diffuse_reflectance).
    fwd = jax.jit(jax.vmap(jax.jacfwd(lambda y: medium_total_diffuse_reflectance(Medium(0.0, y[0], y[1])))))
    assert np.all(np.abs(np.asarray(fwd(x[:, 1:]))) <= 1e-12 / ss[:, None])
    A = Medium(0.0, 1.0, jnp.asarray(ETA)).A
    np.testing.assert_allclose(jax.vmap(jax.grad(total_diffuse_reflectance_u))(jnp.zeros(len(ETA)), A),
                               -(1 + 2 * A / 3), rtol=1e-12)


def test_marched_kernels_curvature_correction_values_and_gradients():
    """The marched white kernel's orders >= 2 with transport's correction of the curvature ratio, from the light's side
    (``min(Q, 1)``, capped at 5 ``l_u``) and from behind (``max(Q, 1)``, capped at 3.3), for alpha' in {1e-6, 0.5, 0.99,
    1 - 1e-9} at sigma_t' 1 /mm, on pairs of spheres of 1e-3, 5 and 1e4 ``l_u`` (past the caps, at the near cap, nearly
    flat) at central angles 1e-3, 1 and 3 rad: every value finite and >= 0, the near part at most the far part at the
    smallest angle, and the gradients in sigma_a finite (at alpha' 1e-6 a central difference's)."""
    from jaxsss.render.bssrdf import white_kernel, white_tables
    from tests.render.kernel_calls import kernel_pair, kernel_sources

    mus, sources = white_tables(0.0, 1.0, True)
    k = len(mus)
    flux = jnp.ones((9, 4, k, 1)).at[:, 1:4].set(0.0)
    theta = np.tile([1e-3, 1.0, 3.0], 3)
    radius = np.repeat([1e-3, 5.0, 1e4], 3)
    x = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    p = np.tile([[0.0, 0.0, 1.0]], (9, 1))
    delta, normals = jnp.asarray(radius[:, None] * (x - p)), (jnp.asarray(x), jnp.asarray(p))

    def pairs(sigma_a, transport):
        medium = Medium(sigma_a=sigma_a, sigma_s_prime=1.0 - sigma_a, eta=1.0)
        kernel = white_kernel(medium, sources, mus, shift=True, curvature=True, first_order=True,
                              curvature_transport=transport)
        return kernel_pair(kernel, delta, kernel_sources(kernel, flux), normals)

    for alpha in (1e-6, 0.5, 0.99, 1 - 1e-9):
        sigma_a = jnp.array([1.0 - alpha])
        near, far = np.asarray(pairs(sigma_a, False)), np.asarray(pairs(sigma_a, True))
        assert np.all(np.isfinite(near)) and np.all(near >= 0) and np.all(np.isfinite(far)) and np.all(far >= 0), alpha
        assert np.all(near[3] <= far[3] * (1 + 1e-9)), (alpha, near[3], far[3])
        for transport in (False, True):
            grad = np.asarray(jax.jacfwd(lambda s: jnp.sum(pairs(s, transport)))(sigma_a))
            assert np.all(np.isfinite(grad)), (alpha, transport, grad)
            if alpha == 1e-6:  # where the profiles are ~1e-300 (the first order's rescaling was NaN here)
                h = 1e-9
                fd = (np.sum(pairs(sigma_a + h, transport)) - np.sum(pairs(sigma_a - h, transport))) / (2 * h)
                np.testing.assert_allclose(grad[0], fd, rtol=1e-4)
