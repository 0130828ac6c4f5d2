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
    assert all("does not resolve" not in w and "do not resolve the blur" in w and "Rd =" in w for w in fit.warnings)
    assert len(fit.warnings) == fit.sigma_a.shape[0]


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
