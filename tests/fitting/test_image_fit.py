"""fit_image's views and uncertainties: several (scene, image) pairs in one fit, standard errors that cover the truth
under known noise, an honest "not identifiable" where the image cannot fix l_d, and bad input named.

Targets here are jaxsss's own renders plus known noise: these tests check the fit's bookkeeping (stacking views,
weights, the covariance), not the model; the model is judged against path-traced references in tests/export.
"""

import numpy as np
import pytest

import fitting
import jaxsss
from fitting import fit_image
from jaxsss.render import parse_scene, prepare
from tests.render.test_renderer import _scene_dict

MATERIAL = {"sigma_a": 0.08, "sigma_s_prime": 1.5, "eta": 1.3}
TRUTH = np.array([0.08, 1.5])


def _view(light, resolution=24, distance=1.0, **kwargs):
    # At 24 x 24 a pixel is 0.58 mm on the sphere and l_d = 1.62 mm spans 2.8 pixels: the blur is resolved.
    d = _scene_dict(material=MATERIAL, lights=[light], camera={"position": [0.0, -30.0 * distance, 10.0 * distance],
                    "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0, "resolution": [resolution, resolution]}, **kwargs)
    return parse_scene(d, path="<test>")


def _target(scene, rel_noise, seed):
    # The dipole (cheap to compile; these tests check the fit's statistics, not the kernel).
    clean = np.asarray(prepare(scene, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(
        scene.material.medium))
    stderr = np.where(clean > 0, rel_noise * clean + 1e-12, 1.0)
    noisy = np.clip(clean + stderr * np.random.default_rng(seed).standard_normal(clean.shape), 0.0, None)
    return np.where(clean > 0, noisy, 0.0), stderr


@pytest.fixture(scope="module")
def two_views():
    scenes = [_view({"type": "directional", "direction": [0.6, 0.3, -1.0], "intensity": 1.0}),
              _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0})]
    pairs = [_target(s, 0.02, seed) for seed, s in enumerate(scenes)]
    return scenes, [p[0] for p in pairs], [p[1] for p in pairs]


def test_two_views_recover_truth_within_their_standard_errors(two_views):
    scenes, targets, stderrs = two_views
    fit = fit_image(scenes, targets, target_stderr=stderrs, max_pixels=None, bssrdf="dipole")
    assert fit.converged, fit.message
    assert fit.n_views == 2 and fit.n_pixels == sum(int((t.sum(-1) > 0).sum()) for t in targets)
    est = np.array([float(fit.sigma_a[0]), float(fit.sigma_s_prime[0])])
    se = np.array([float(fit.sigma_a_stderr[0]), float(fit.sigma_s_prime_stderr[0])])
    assert np.all(np.abs(est - TRUTH) < 4 * se), (est, se)
    assert np.all(se / TRUTH < 0.1), se / TRUTH  # 2% pixel noise on ~400 pixels pins both coefficients
    assert bool(fit.identifiable[0]) and not fit.warnings
    # Independent pixel noise: the cluster-robust standard errors are the model-based ones, up to their own noise.
    assert np.all(np.asarray(fit.stderr_inflation) < 1.6), fit.stderr_inflation
    # (Rd, l_d) and their errors follow from the same covariance.
    assert 0 < float(fit.rd_stderr[0]) < 0.05 * float(fit.rd[0])
    d = fit.to_dict()
    assert d["n_views"] == 2 and len(d["sigma_a_stderr"]) == 3


def test_uniformly_lit_slab_fixes_rd_but_not_l_d():
    """Far from its edges, a slab under uniform light shows only Rd: the fit must say l_d is not constrained."""
    scene = parse_scene(_scene_dict(
        mesh={"builtin": "slab", "width": 60.0, "depth": 60.0, "thickness": 10.0}, material=MATERIAL,
        lights=[{"type": "directional", "direction": [0.0, 0.0, -1.0], "intensity": 1.0}],
        camera={"position": [0.0, 0.0, 200.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_deg": 2.0,
                "resolution": [6, 6]},
        render_opts={"density": 0.5, "single_scattering": "off"}), path="<test>")
    target, stderr = _target(scene, 0.01, 3)
    fit = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole")
    channels = fit.sigma_a.shape[0]  # the scalar material is rendered in every channel of the image
    assert not np.any(fit.identifiable)
    assert len(fit.warnings) == channels and all(f"channel {k}:" in w and "Rd =" in w for k, w in enumerate(fit.warnings))
    # Rd itself is pinned to about the noise over the patch, whatever the fit did with l_d.
    true_rd = np.asarray(jaxsss.medium_total_diffuse_reflectance(scene.material.medium))
    assert np.all(np.abs(np.asarray(fit.rd) - true_rd) < 4 * np.asarray(fit.rd_stderr) + 1e-3 * true_rd)
    assert np.all(np.asarray(fit.rd_stderr) < 0.02 * true_rd)


def test_pixel_footprint_of_a_view():
    scene = _view({"type": "directional", "direction": [0.6, 0.3, -1.0], "intensity": 1.0})
    d = np.hypot(30.0, 10.0)  # the sphere is centred at the origin
    np.testing.assert_allclose(fitting.pixel_footprint(scene), 2 * d * np.tan(np.radians(12.5)) / 24, rtol=1e-9)


def test_an_unresolved_blur_is_not_identifiable_whatever_the_standard_errors():
    """The same sphere from 3x as far at 12 x 12: l_d (1.6 mm) spans 0.5 pixels. Self-consistent data still pin
    both coefficients to a few percent (the model is exact here), but against real transport such a split follows
    the model's error (docs/benchmarks.md): the fit must report Rd only."""
    scene = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0}, resolution=12, distance=3.0)
    target, stderr = _target(scene, 0.01, 5)
    fit = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole")
    assert fit.converged, fit.message
    pixels = np.asarray(fit.ld) / fitting.pixel_footprint(scene)
    assert np.all(pixels < fitting.RESOLVED_LD_PIXELS), pixels
    assert not np.any(fit.identifiable)
    blur = [w for w in fit.warnings if w.startswith("channel")]
    assert all("does not resolve" not in w and "do not resolve the blur" in w and "Rd =" in w for w in blur)
    assert len(blur) == fit.sigma_a.shape[0]
    # The sphere covers a few pixels: too few of the view's blocks for cluster-robust standard errors, and it says so.
    assert [w for w in fit.warnings if not w.startswith("channel")] == [w for w in fit.warnings if "blocks" in w]
    assert len(fit.warnings) == len(blur) + 1 and np.isnan(np.asarray(fit.stderr_inflation)).all()


def test_bad_views_are_named(two_views):
    scenes, targets, _ = two_views
    with pytest.raises(ValueError, match=r"1 images for 2 scenes"):
        fit_image(scenes, targets[:1])
    with pytest.raises(ValueError, match=r"empty sequence"):
        fit_image([], [])
    other = parse_scene({**_scene_dict(material={**MATERIAL, "eta": 1.4})}, path="<test>")
    with pytest.raises(ValueError, match=r"scene\[1\]\): eta"):
        fit_image([scenes[0], other], [targets[0], targets[0]])
    with pytest.raises(ValueError, match="target_stderr"):
        fit_image(scenes[0], targets[0], target_stderr=np.zeros_like(targets[0]))
    for bad in (-0.01, 1.0, float("nan")):
        with pytest.raises(ValueError, match=r"model_error=.*\[0, 1\)"):
            fit_image(scenes[0], targets[0], model_error=bad)


def test_per_channel_jacobian_equals_the_full_one(two_views):
    """The solve's Jacobian comes from two tangent passes (``_channel_residuals``): it must equal ``jax.jacfwd`` of
    the plain residuals, entry for entry, on a three-channel material (every method's fit checks it again at its
    solution: ``_channel_coupling``, asserted in test_renderer, test_cache and test_methods)."""
    import jax
    import jax.numpy as jnp

    from fitting.image_fit import _channel_residuals, _stacked_residuals
    from jaxsss.render import prepare_method

    scene = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0}, resolution=8)
    target = np.asarray(prepare(scene, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(
        scene.material.medium))
    mask = target.sum(-1) > 0
    prepared = prepare_method(scene, "hierarchical", pixel_mask=mask, fit=True, bssrdf="dipole").state
    medium = scene.material.medium
    views = ((prepared, jnp.asarray(target), jnp.ones_like(jnp.asarray(target)), jnp.asarray(mask)),)
    args = (views, medium.eta, medium.g, medium.fresnel)
    theta = jnp.log(jnp.array([0.05, 0.1, 0.2, 1.0, 1.5, 2.0]))
    full = np.asarray(jax.jacfwd(_stacked_residuals)(theta, args))
    packed = np.asarray(jax.jacfwd(_channel_residuals)(theta, args))
    assert np.abs(full[:, :3]).max() > 0 and np.abs(full[:, 3:]).max() > 0
    np.testing.assert_allclose(packed, full, rtol=1e-12, atol=1e-14 * np.abs(full).max())
    assert fitting.image_fit._channel_coupling(full) < 1e-12


def test_channel_coupling_is_measured():
    from fitting.image_fit import _channel_coupling

    own = np.zeros((6, 6))  # rows: channels 0, 1, 2, 0, 1, 2; columns: log sigma_a 0-2, log sigma_s' 0-2
    for i in range(6):
        own[i, i % 3], own[i, 3 + i % 3] = 2.0, -1.0
    assert _channel_coupling(own) == 0.0
    coupled = own.copy()
    coupled[0, 1] = 0.5
    assert _channel_coupling(coupled) == pytest.approx(0.25)


def test_cluster_covariance_of_noise_and_of_a_smooth_misfit():
    """A linear least-squares problem on a 40 x 40 one-channel image, its two regressors smooth (1 and x): with
    independent residuals the block (cluster-robust) standard errors are the model-based ones up to the noise of 16
    blocks; with a residual that is smooth and varies across the image, they are several times larger."""
    from fitting.image_fit import MIN_BLOCKS, _blocks, _cluster_covariance

    h = w = 40
    target = np.zeros((h, w, 1))
    blocks = _blocks([(None, target, None, None)], 1)
    assert blocks.shape == (h * w,) and len(np.unique(blocks)) == 16
    y, x = np.mgrid[0:h, 0:w] / h
    jac = np.stack([np.ones(h * w), x.reshape(-1)], axis=1)
    model_se = np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)))  # unit noise
    fitted = np.ones(h * w, dtype=bool)

    def cluster_se(res):
        res = res - jac @ np.linalg.lstsq(jac, res, rcond=None)[0]  # at the solution: J^T r = 0
        cov, k = _cluster_covariance(jac, res, np.linalg.pinv(jac.T @ jac), blocks, fitted)
        assert k == 16
        return np.sqrt(np.diag(cov))

    ratios = np.array([cluster_se(np.random.default_rng(s).standard_normal(h * w)) / model_se for s in range(20)])
    assert 0.8 < np.median(ratios) < 1.2 and ratios.max() < 2.0
    smooth = (np.sin(6.0 * x) * np.cos(5.0 * y)).reshape(-1)
    noisy = smooth + 0.1 * np.random.default_rng(0).standard_normal(h * w)
    resid = noisy - jac @ np.linalg.lstsq(jac, noisy, rcond=None)[0]
    model = np.sqrt(resid @ resid / (h * w - 2)) * model_se
    assert np.all(cluster_se(noisy) > 3.0 * model)
    # Too few blocks with fitted rows: not estimated.
    few = np.isin(blocks, [0, 1])
    assert _cluster_covariance(jac, np.ones(h * w), np.eye(2), blocks, few) == (None, 2) and MIN_BLOCKS > 2


def test_a_smooth_model_error_widens_the_standard_errors():
    """A target that the model misses by a smooth 8% tilt across the sphere, with 1% pixel noise: weighted by the
    noise alone, the standard errors would claim the tilted answer to a fraction of a percent. The tilt pulls the fit
    differently on the two sides of the sphere, and the cluster-robust standard errors grow to cover the truth."""
    scene = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0})
    clean = np.asarray(prepare(scene, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(
        scene.material.medium))
    x = np.linspace(-1.0, 1.0, clean.shape[1])[None, :, None]
    stderr = np.where(clean > 0, 0.01 * clean + 1e-12, 1.0)
    noisy = clean * (1.0 + 0.08 * x) + stderr * np.random.default_rng(11).standard_normal(clean.shape)
    target = np.where(clean > 0, np.clip(noisy, 0.0, None), 0.0)
    fit = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole")
    assert fit.converged, fit.message
    inflation = np.asarray(fit.stderr_inflation)
    est = np.array([float(fit.sigma_a[0]), float(fit.sigma_s_prime[0])])
    se = np.array([float(fit.sigma_a_stderr[0]), float(fit.sigma_s_prime_stderr[0])])
    naive = se / inflation[[0, 3]]
    assert np.all(np.abs(est - TRUTH) > 3 * naive), (est, naive)  # the premise: independent-pixel errors lie
    # The blocks see the part of the misfit that varies across the object (here ~3.1-3.5x the model-based errors,
    # which brings the errors from 11-16 to 3-5 standard errors); what the parameters absorb uniformly, no residual
    # can show (docs/benchmarks.md, "fit_image from path-traced images").
    assert np.all(inflation > 2.5), inflation
    assert fit.to_dict()["stderr_inflation"] == pytest.approx(inflation.tolist())


def test_a_uniform_brightness_error_is_covered_by_the_stated_model_error():
    """A target 3% brighter than the model everywhere (1% pixel noise): the parameters absorb it alike over the image,
    so neither the residuals nor the blocks can show it, and the fit lands many of its standard errors from the truth.
    Stating the renderer's accuracy, ``model_error=0.03`` (RENDER_MODEL_ERROR's level: the white kernels' brightness
    against Mitsuba), adds that error's effect on the estimates and covers the truth; ``Rd``, which the brightness
    sets, gets about 3% of its own (the stated terminator bands: tests/fitting/test_discrepancy.py)."""
    from fitting.image_fit import RENDER_MODEL_ERROR

    scene = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0})
    clean = np.asarray(prepare(scene, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(
        scene.material.medium))
    stderr = np.where(clean > 0, 0.01 * clean + 1e-12, 1.0)
    noisy = 1.03 * clean + stderr * np.random.default_rng(5).standard_normal(clean.shape)
    target = np.where(clean > 0, np.clip(noisy, 0.0, None), 0.0)
    plain = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole")
    stated = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole",
                       model_error=RENDER_MODEL_ERROR.level)
    assert plain.converged and stated.converged
    np.testing.assert_allclose(np.asarray(stated.sigma_a), np.asarray(plain.sigma_a), rtol=1e-10)  # same estimate
    est = np.array([float(plain.sigma_a[0]), float(plain.sigma_s_prime[0])])
    se_plain = np.array([float(plain.sigma_a_stderr[0]), float(plain.sigma_s_prime_stderr[0])])
    se_stated = np.array([float(stated.sigma_a_stderr[0]), float(stated.sigma_s_prime_stderr[0])])
    assert np.any(np.abs(est - TRUTH) > 3 * se_plain), (est, se_plain)  # the premise
    assert np.all(np.abs(est - TRUTH) < 2 * se_stated), (est, se_stated)
    rd = float(stated.rd[0])
    assert 0.02 * rd < float(stated.rd_stderr[0]) < 0.05 * rd, (float(stated.rd_stderr[0]), rd)


def test_the_fits_medium_adds_no_host_callback():
    """The fit builds its medium from ``exp`` of its log-parameters (valid by construction), without traced checks: a
    host callback would keep the compiled residuals and solve out of JAX's persistent compilation cache (measured on
    the skin1 sphere: a warm process compiled the fit in 17 s with them, 6 s without). Concrete values are still
    checked."""
    import jax

    from fitting.image_fit import _medium

    theta = np.log(np.array([0.08, 0.1, 1.5, 1.2]))
    text = jax.jit(lambda th: _medium(th, 1.3, 0.2, "poly").D).lower(theta).as_text()
    assert "callback" not in text
    with pytest.raises(ValueError, match="eta"):
        _medium(theta, -1.0, None, "poly")


def test_a_new_process_loads_the_fits_programs_instead_of_tracing(two_views, monkeypatch, tmp_path):
    """Start-up: fit_image's residual and solve programs are serialised with jax.export (jaxsss._exported); a new
    process (here: the in-memory table cleared) loads them without tracing the render, and gives the same fit."""
    from fitting import image_fit
    from jaxsss import _exported

    monkeypatch.setattr(_exported, "export_dir", lambda: tmp_path)
    monkeypatch.setattr(_exported, "_LOADED", {})
    scenes, targets, stderrs = two_views
    first = fit_image(scenes[1], targets[1], target_stderr=stderrs[1], max_pixels=64, bssrdf="dipole")
    assert sorted(p.name.rsplit("-", 1)[0] for p in tmp_path.glob("*.bin")) == ["image-residuals", "image-solve"]
    monkeypatch.setattr(_exported, "_LOADED", {})
    traces = []
    stacked = image_fit._stacked_residuals
    monkeypatch.setattr(image_fit, "_stacked_residuals", lambda theta, args: traces.append(1) or stacked(theta, args))
    again = fit_image(scenes[1], targets[1], target_stderr=stderrs[1], max_pixels=64, bssrdf="dipole")
    assert not traces  # deserialised, not traced
    assert again.converged and again.message == first.message and int(again.n_steps) == int(first.n_steps)
    for name in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr"):
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
    # Other solver settings are another program (they are in the key), not the stored one.
    fit_image(scenes[1], targets[1], target_stderr=stderrs[1], max_pixels=64, bssrdf="dipole", rtol=1e-5)
    assert len(list(tmp_path.glob("image-solve-*.bin"))) == 2


def test_the_start_takes_rd_between_the_grids_nodes():
    """The start grid's ``Rd`` nodes are coarse (0.2, 0.5, 0.8, 0.95); with the residuals interpolated in ``Rd`` per
    ``l_d`` candidate the start lands in the true basin. A sphere's brightness grows with ``l_d`` (light flows round
    it: the sky-lit skin1 sphere's red is 17% brighter at twice its ``l_d``, 11-14% darker at 0.1-0.3 of it), so on the
    grid alone a short ``l_d`` offsets a high ``Rd``: there the start was ``(0.5, 0.3 mm)`` for a truth of ``(0.41, 3.67
    mm)``, and the solve ended on the short-``l_d`` plateau (docs/benchmarks.md, "fit_image from the sky-lit skin1
    sphere"). Here a model image with that gain and a terminator blurred over ``l_d``; channel 0 has that truth,
    channel 1 a grid node."""
    from fitting.image_fit import LD_CANDIDATES_MM, RD_CANDIDATES, _grid_start

    eta = 1.4
    x = np.linspace(-4.0, 40.0, 60)[:, None]  # mm from the terminator

    def image(theta):
        rd, ld = (np.asarray(v) for v in jaxsss.to_rd_ld(jaxsss.Medium(np.exp(theta[:2]), np.exp(theta[2:]), eta)))
        return rd * 0.5 * (1.0 + np.tanh(x / ld)) * (0.86 + 0.14 * (ld / 3.67) ** 1.2)

    truth = jaxsss.from_rd_ld(np.array([0.41, 0.5]), np.array([3.67, 1.0]), eta).medium
    target = image(np.log(np.concatenate([np.asarray(truth.sigma_a), np.asarray(truth.sigma_s_prime)])))
    costs = []

    def residuals(theta, args):
        r = (image(np.asarray(theta)) - target) / target.mean(axis=0)
        costs.append(np.sum(r**2, axis=0))
        return r.reshape(-1)

    sa, ss = _grid_start(residuals, None, eta, 2)
    assert len(costs) == len(RD_CANDIDATES) * len(LD_CANDIDATES_MM)  # no more image evaluations than the grid's
    # The grid's own best for channel 0 is the wrong l_d (what the start took before).
    assert np.tile(LD_CANDIDATES_MM, len(RD_CANDIDATES))[int(np.argmin(np.array(costs)[:, 0]))] != 3.0
    rd, ld = (np.asarray(v) for v in jaxsss.to_rd_ld(jaxsss.Medium(sa, ss, eta)))
    np.testing.assert_allclose(ld, [3.0, 1.0], rtol=1e-6)  # the l_d candidates next to the truth
    np.testing.assert_allclose(rd, [0.41, 0.5], atol=0.015)
