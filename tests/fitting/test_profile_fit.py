"""Profile fits: recovery of noise-free synthetic data, calibrated errors on noisy data, identifiability warnings,
registries, batching, sharding (in a subprocess with two forced host devices), gradients w.r.t. the data, retracing.

Compilation dominates the run time, so the tests share a few static configurations: the fits pad the problem axis to
4, 8, ..., 64 problems and treat "standard errors given" as data, so every dipole fit of up to 4 problems (one profile
of 1-3 channels, a 2x2 batch, the CLI's single profile) reuses one compilation, and module-scoped fixtures share the
fits themselves."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import fitting
import jaxsss
from fitting import _kernel, profile_fit

ROOT = Path(__file__).resolve().parents[2]
R_GRID = np.geomspace(0.05, 20.0, 40)
SA = np.array([0.0021, 0.0041, 0.0071])  # marble (Jensen 2001), 1/mm
SS = np.array([2.19, 2.62, 3.00])
ETA = 1.5


def dipole_data(sa=SA, ss=SS, eta=ETA, r=R_GRID):
    m = jaxsss.Medium(sa, ss, eta)
    return np.asarray(fitting.entry_transmittance(eta) * jaxsss.dipole_profile(r[:, None], m))


def multipole_data(sa, ss, eta, d, r=R_GRID):
    m = jaxsss.Medium(sa, ss, eta)
    n = jaxsss.multipole_n_pairs(r[:, None], m, d, rtol=1e-13)
    R, T = jaxsss.multipole_profile(r[:, None], m, d, n_pairs=n)
    t = fitting.entry_transmittance(eta)
    return np.asarray(t * R), np.asarray(t * T)


@pytest.fixture(scope="module")
def marble_fit():
    """The well-posed reference fit (absolute marble, three channels) and the FitWarnings it raised."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fitting.fit_profile(R_GRID, dipole_data(), eta=ETA)
    return fit, [w for w in caught if issubclass(w.category, fitting.FitWarning)]


# --- 1. Noise-free recovery -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("relative", [False, True])
def test_dipole_noise_free_recovered_to_1e8(relative, marble_fit):
    if relative:
        fit = fitting.fit_profile(R_GRID, dipole_data() * 3.7, eta=ETA, relative=True)
    else:
        fit = marble_fit[0]
    assert fit.converged.all()
    # 1e-8: the target; the solver tolerance is 1e-10 on the log-parameters (Cauchy test).
    np.testing.assert_allclose(fit.sigma_a, SA, rtol=1e-8)
    np.testing.assert_allclose(fit.sigma_s_prime, SS, rtol=1e-8)
    if relative:
        np.testing.assert_allclose(fit.scale, 3.7, rtol=1e-8)
    assert np.all(fit.r_min >= fit.r_cut) and np.all(fit.r_cut > 0)


@pytest.mark.parametrize("relative", [False, True])
def test_multipole_noise_free_R_and_T_recovered_to_1e8(relative):
    sa, ss, d = np.array([0.01, 0.05]), np.array([1.0, 2.0]), 3.0
    R, T = multipole_data(sa, ss, 1.3, d)
    k = 5.0 if relative else 1.0
    fit = fitting.fit_profile(R_GRID, k * R, T=k * T, eta=1.3, model="multipole", thickness=d, relative=relative,
                              warn=False)
    assert fit.converged.all() and fit.outputs == ("R", "T")
    np.testing.assert_allclose(fit.sigma_a, sa, rtol=1e-8)
    np.testing.assert_allclose(fit.sigma_s_prime, ss, rtol=1e-8)


# --- 2. Noisy data: estimates within a few standard errors; standard errors calibrated ---------------------------
def test_noisy_fits_within_stderr_and_stderr_calibrated():
    n_rep = 60
    R = dipole_data()[:, 1]  # green marble channel
    se = 0.03 * R
    rng = np.random.default_rng(7)
    data = R + se * rng.standard_normal((n_rep, R.size))
    fit = fitting.fit_profiles(R_GRID, data, R_stderr=np.broadcast_to(se, data.shape), eta=ETA, warn=False)
    assert fit.shape == (n_rep,) and fit.converged.all()
    for name, truth in (("sigma_a", SA[1]), ("sigma_s_prime", SS[1])):
        est, err = np.asarray(getattr(fit, name)), np.asarray(getattr(fit, name + "_stderr"))
        z = (est - truth) / err
        assert np.all(np.abs(z) < 4.5), z  # a 4.5-sigma miss in 60 Gaussian draws has probability ~4e-4
        # The spread over the repeats against the median reported stderr: 30% covers the sampling error of a
        # standard deviation from 60 draws (~9% one sigma) plus the curvature of the model at 3% noise.
        ratio = np.std(est, ddof=1) / np.median(err)
        assert 0.7 < ratio < 1.3, (name, ratio)
    np.testing.assert_allclose(np.median(fit.reduced_chi2), 1.0, atol=0.2)


# --- 3. Identifiability ---------------------------------------------------------------------------------------------
def test_relative_far_field_data_warn_that_only_sigma_tr_is_fixed():
    R = dipole_data()
    with pytest.warns(fitting.FitWarning, match="cannot separate"):
        fit = fitting.fit_profile(R_GRID, 2.0 * R, eta=ETA, relative=True, r_min=10.0)
    assert not np.asarray(fit.identifiable).all()
    assert "cannot separate" in str(fit) and fit.to_dict()["warnings"]
    # sigma_tr is still recovered.
    np.testing.assert_allclose(np.sqrt(3 * fit.sigma_a * (fit.sigma_a + fit.sigma_s_prime)),
                               np.sqrt(3 * SA * (SA + SS)), rtol=1e-6)


def test_well_posed_fit_does_not_warn(marble_fit):
    fit, fit_warnings = marble_fit
    assert np.asarray(fit.identifiable).all()
    assert not fit_warnings


def test_max_steps_reached_is_reported_not_raised():
    with pytest.warns(fitting.FitWarning, match="did not converge"):
        fit = fitting.fit_profile(R_GRID, dipole_data() * 1.3, eta=ETA, max_steps=1)
    assert not fit.converged.any()
    assert "maximum number of steps" in fit.messages()[0]
    assert "NOT CONVERGED" in str(fit)


# --- 4. Registries and bad input --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"model": "tripole"}, "valid names: 'dipole', 'multipole'"),
        ({"solver": "newton"}, "valid names: 'levenberg_marquardt', 'gauss_newton', 'dogleg'"),
        ({"model": "multipole"}, "needs thickness"),
        ({"thickness": 2.0}, "applies to slab models only"),
        ({"eta": -1.0}, r"eta=-1\) is outside the allowed range"),
        ({"r_min": 5.0, "r_max": 1.0}, "r_min must be below r_max"),
    ],
)
def test_bad_arguments_are_named(kwargs, match):
    kw = {"eta": ETA, **kwargs}
    with pytest.raises(ValueError, match=match):
        fitting.fit_profile(R_GRID, dipole_data(), **kw)


def test_bad_data_are_named():
    R = dipole_data()
    with pytest.raises(ValueError, match="not finite"):
        fitting.fit_profile(R_GRID, np.where(R > 0.1, np.nan, R), eta=ETA)
    with pytest.raises(ValueError, match="strictly increasing"):
        fitting.fit_profile(R_GRID[::-1], R, eta=ETA)
    with pytest.raises(ValueError, match="predicts R only, not T"):
        fitting.fit_profile(R_GRID, R, T=R, eta=ETA)
    with pytest.raises(ValueError, match="R_stderr=0"):
        fitting.fit_profile(R_GRID, R, R_stderr=0 * R, eta=ETA)


def test_registry_accepts_a_new_model_and_rejects_duplicates():
    with pytest.raises(ValueError, match="already registered"):
        fitting.register_model(fitting.FORWARD_MODELS["dipole"])
    assert set(fitting.FORWARD_MODELS) >= {"dipole", "multipole"}
    assert set(fitting.SOLVERS) == {"levenberg_marquardt", "gauss_newton", "dogleg"}


@pytest.mark.parametrize("solver", ["gauss_newton", "dogleg"])
def test_other_solvers_recover_the_same_parameters(solver):
    fit = fitting.fit_profile(R_GRID, dipole_data(), eta=ETA, solver=solver)
    assert fit.converged.all() and fit.solver == solver
    np.testing.assert_allclose(fit.sigma_a, SA, rtol=1e-8)


# --- 5. Batching, sharding, retracing -------------------------------------------------------------------------------
def test_batch_equals_loop_over_profiles():
    rng = np.random.default_rng(3)
    data = dipole_data()[None, :, :2] * (1.0 + 0.02 * rng.standard_normal((2, R_GRID.size, 2)))
    batch = fitting.fit_profiles(R_GRID, data, eta=ETA, warn=False)
    assert batch.shape == (2, 2)
    for b in range(2):
        single = fitting.fit_profile(R_GRID, data[b], eta=ETA, warn=False)
        for name in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "correlation"):
            # Same per-problem computation; only the vectorisation width differs.
            np.testing.assert_allclose(np.asarray(getattr(batch, name))[b], getattr(single, name), rtol=1e-9)


def test_large_batches_in_chunks_equal_one_call(monkeypatch):
    """Batches above ``RUN_CHUNK`` problems run the starts and finish stages in chunks (the last padded); the chunks
    give the one call's answer. 30 single-channel profiles with the chunk set to 8 (4 chunks, one compilation)."""
    from fitting import profile_fit

    rng = np.random.default_rng(8)
    sa, ss = 0.01 * np.exp(rng.uniform(-1, 1, 30)), 2.0 * np.exp(rng.uniform(-1, 1, 30))
    data = np.moveaxis(dipole_data(sa, ss), 1, 0) * (1.0 + 0.02 * rng.standard_normal((30, R_GRID.size)))
    whole = fitting.fit_profiles(R_GRID, data, eta=ETA, warn=False)
    monkeypatch.setattr(profile_fit, "RUN_CHUNK", 8)
    chunked = fitting.fit_profiles(R_GRID, data, eta=ETA, warn=False)
    for name in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "suspect", "r_cut"):
        # The same per-problem computation; only the vectorisation width differs.
        np.testing.assert_allclose(np.asarray(getattr(chunked, name)), np.asarray(getattr(whole, name)), rtol=1e-9)


def test_exported_fit_is_written_and_reused(monkeypatch, tmp_path):
    """Start-up: the fused fit is serialised with jax.export; a new process (here: the in-memory table cleared) loads
    it instead of tracing, and gives the same fit, status included."""
    from jaxsss import _exported

    monkeypatch.setattr(_exported, "export_dir", lambda: tmp_path)
    monkeypatch.setattr(_exported, "_LOADED", {})
    first = fitting.fit_profile(R_GRID, dipole_data(), eta=ETA)
    files = list(tmp_path.glob("fit-*.bin"))
    assert len(files) == 1
    monkeypatch.setattr(_exported, "_LOADED", {})
    before = dict(_kernel.TRACES)
    again = fitting.fit_profile(R_GRID, dipole_data(), eta=ETA)
    assert _kernel.TRACES == before  # deserialised, not traced
    assert again.converged.all() and again.messages() == first.messages()
    np.testing.assert_array_equal(again.sigma_a, first.sigma_a)


def test_second_call_with_new_values_does_not_retrace(marble_fit):
    fitting.fit_profile(R_GRID, dipole_data(), eta=ETA)
    before = dict(_kernel.TRACES)
    fit = fitting.fit_profile(R_GRID, dipole_data(SA * 1.5, SS * 0.8), eta=ETA)
    assert _kernel.TRACES == before
    np.testing.assert_allclose(fit.sigma_a, SA * 1.5, rtol=1e-8)


def test_profiles_of_other_lengths_in_one_bucket_share_the_compiled_fit(marble_fit):
    # R_GRID's 40 radii and a 57-radius profile both pad to 64: no new trace, and the truth recovered.
    fitting.fit_profile(R_GRID, dipole_data(), eta=ETA)
    before = dict(_kernel.TRACES)
    r = np.geomspace(0.08, 15.0, 57)
    fit = fitting.fit_profile(r, dipole_data(SA * 1.5, SS * 0.8, r=r), eta=ETA)
    assert _kernel.TRACES == before
    np.testing.assert_allclose(fit.sigma_a, SA * 1.5, rtol=1e-8)
    assert np.all(np.asarray(fit.n_points) <= 57) and np.all(np.asarray(fit.r_max) <= 15.0)


def test_padding_the_radii_changes_no_result(monkeypatch):
    # The padded points (y = 0, se = -1) enter neither the starts, the solve nor the statistics.
    rng = np.random.default_rng(3)
    R = dipole_data()
    R = R * (1 + 0.02 * rng.standard_normal(R.shape))
    for relative in (False, True):
        kw = dict(eta=ETA, relative=relative, warn=False)
        kw.update({} if relative else dict(R_stderr=0.02 * R))
        padded = fitting.fit_profile(R_GRID, R, **kw)
        monkeypatch.setattr(profile_fit, "_radii_bucket", lambda n: n)
        exact = fitting.fit_profile(R_GRID, R, **kw)
        monkeypatch.undo()
        for name in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr", "reduced_chi2",
                     "n_points", "r_min", "r_max", "guess_sigma_a", "residual_autocorrelation"):
            np.testing.assert_allclose(getattr(padded, name), getattr(exact, name), rtol=1e-9, err_msg=name)


def shard_data():
    """4 single-channel profiles on R_GRID: 4 problems, the padded size of the other small dipole fits here (one
    compilation in this process) and a multiple of the subprocess's two devices."""
    sa = np.array([0.002, 0.004, 0.007, 0.01]); ss = np.array([2.0, 2.5, 3.0, 1.0])
    R = np.moveaxis(dipole_data(sa, ss, 1.3), 1, 0)
    return R * (1 + 0.01 * np.random.default_rng(0).standard_normal(R.shape))


SHARD_SCRIPT = textwrap.dedent("""
    import json, os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    import jax, numpy as np, fitting
    from tests.fitting.test_profile_fit import R_GRID, shard_data
    assert len(jax.devices()) == 2, jax.devices()
    a = fitting.fit_profiles(R_GRID, shard_data(), eta=1.3, shard=True, warn=False)
    assert a.converged.all()
    keys = ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr")
    print(json.dumps({k: np.asarray(getattr(a, k)).tolist() for k in keys}))
""")


def test_sharded_over_two_host_devices_equals_unsharded():
    """The sharded fit (a subprocess with two forced host devices) equals this process's unsharded one (the same
    compiled fit as the other small dipole fits here, so only the sharded variant compiles in the subprocess)."""
    import json

    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", SHARD_SCRIPT], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    sharded = json.loads(proc.stdout.strip().splitlines()[-1])
    b = fitting.fit_profiles(R_GRID, shard_data(), eta=1.3, shard=False, warn=False)
    for k, v in sharded.items():
        np.testing.assert_allclose(v, getattr(b, k), rtol=1e-9)


# --- 6. Differentiable fits -----------------------------------------------------------------------------------------
def test_gradient_wrt_data_matches_finite_differences():
    """The implicit-function-theorem Jacobian against central differences of complete fits.

    Both hold the fit range fixed (a discrete choice): the differences refit with ``r_min`` set to the smallest radius
    the unperturbed fit used. The relative weights ``1 / data`` move with the data in both. The step is 1e-2 relative
    (within the data's 1% noise) with a 5-point stencil (truncation O(h^4)): smaller steps drown in the solver's
    termination noise (the Cauchy test stops within ~1e-11 of the optimum in the log-parameters; a 1e-5 step moves
    the optimum by only ~1e-7 near r = 1 mm, which gave 3e-4 relative scatter, and a 1e-3 step still 2e-6)."""
    rng = np.random.default_rng(5)
    data = dipole_data() * (1.0 + 0.01 * rng.standard_normal(dipole_data().shape))  # (N, 3)
    tight = {"rtol": 1e-12, "atol": 1e-12}  # tight solves keep the differences' termination noise small
    jac = fitting.fit_jacobian_wrt_data(R_GRID, data, eta=ETA, **tight)["R"]  # (3, 2, N): channels independent
    assert jac.shape == (3, 2, R_GRID.size)
    c = 2  # check the red channel; the perturbed copies ride in the three channel slots of a fit
    base = fitting.fit_profile(R_GRID, data, eta=ETA, warn=False, **tight)
    r_min = float(np.asarray(base.r_min)[c])
    idx = [int(np.argmin(np.abs(R_GRID - 1.0))), int(np.argmin(np.abs(R_GRID - 5.0))), R_GRID.size - 1]
    h = 1e-2 * data[idx, c]
    fits = {}
    for k in (-2, -1, 1, 2):
        cols = np.repeat(data[:, c : c + 1], 3, axis=1)
        cols[idx, [0, 1, 2]] += k * h
        f = fitting.fit_profile(R_GRID, cols, eta=ETA, r_min=r_min, warn=False, **tight)
        assert np.all(np.asarray(f.r_min) == r_min)
        fits[k] = np.stack([np.asarray(f.sigma_a), np.asarray(f.sigma_s_prime)])  # (2, 3)
    fd = (8 * (fits[1] - fits[-1]) - (fits[2] - fits[-2])) / (12 * h)  # (2, 3 points)
    # 1e-6: the stencil's truncation (~1e-8) plus the termination noise (~1e-7 at this step).
    np.testing.assert_allclose(jac[c][:, idx], fd, rtol=1e-6)
    # The other channels' Jacobians are finite and not identical to channel c's (the vmapped solves are independent).
    assert np.all(np.isfinite(jac)) and not np.allclose(jac[0], jac[c])


# --- 7. Result output -------------------------------------------------------------------------------------------------
def test_result_table_and_json(marble_fit):
    import json

    fit = marble_fit[0]
    d = json.loads(fit.to_json())
    for key in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr", "converged", "iterations",
                "seconds", "model", "r_min", "r_max", "range_reason", "correlation"):
        assert key in d
    assert len(d["sigma_a"]) == 3 and d["model"] == "dipole" and all(d["converged"])
    text = str(fit)
    assert "sigma_a [1/mm]" in text and "r >= l_u" in text and text.count("converged") >= 3
    pred = fit.predict(R_GRID)["R"]
    np.testing.assert_allclose(pred, dipole_data().T, rtol=1e-8)
