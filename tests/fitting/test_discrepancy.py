"""fitting.discrepancy: the stated model error's modes, their validation, and a fit whose target the model misses at
the terminator only."""

import numpy as np
import pytest

from fitting import RENDER_MODEL_ERROR, ModelError, fit_image
from fitting.discrepancy import discrepancy_modes, light_key
from jaxsss.render import prepare
from tests.fitting.test_image_fit import TRUTH, _view


def test_a_number_is_the_level_and_bad_errors_are_named():
    assert ModelError.coerce(0.03) == ModelError(level=0.03)
    assert ModelError.coerce(RENDER_MODEL_ERROR) is RENDER_MODEL_ERROR
    assert RENDER_MODEL_ERROR.stated and not ModelError().stated and not ModelError(bands=((-0.1, 0.1, 0.0),)).stated
    for bad in (-0.01, 1.0, float("nan")):
        with pytest.raises(ValueError, match=r"fit_image\(model_error=.*\) is outside the allowed range \[0, 1\)"):
            ModelError.coerce(bad)
    with pytest.raises(TypeError, match=r"model_error='big'"):
        ModelError.coerce("big")
    with pytest.raises(ValueError, match=r"-1 <= lo < hi <= 1"):
        ModelError(bands=((0.2, 0.1, 0.05),))
    with pytest.raises(ValueError, match=r"outside \[0, 2\]"):
        ModelError(bands=((-0.1, 0.1, 3.0),))
    with pytest.raises(ValueError, match=r"\(lo, hi, error\)"):
        ModelError(bands=((-0.1, 0.1),))
    with pytest.raises(ValueError, match=r"level=1.5"):
        ModelError(level=1.5)


def test_modes_by_hand():
    # Two channels, three pixels: cosines to one light 0.5, 0.0 and NaN (an environment, or not fitted).
    model = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    cos = np.array([[0.5], [0.0], [np.nan]])
    modes, sigma = discrepancy_modes(model, 2, cos, ModelError(level=0.03, bands=((-0.1, 0.1, 0.08),
                                                                                 (0.3, 1.0, 0.02))))
    # Level: each channel's rows; bands: the pixel in the band, the lit pixel; NaN in none.
    expect = np.array([[1, 0, 0, 0, 1, 0], [0, 2, 0, 0, 0, 2], [3, 0, 3, 0, 0, 0], [0, 4, 0, 4, 0, 0],
                       [5, 0, 0, 0, 0, 0], [0, 6, 0, 0, 0, 0]], dtype=float)
    np.testing.assert_array_equal(modes, expect)
    np.testing.assert_array_equal(sigma, [0.03, 0.03, 0.08, 0.08, 0.02, 0.02])
    # A band with no pixel adds no mode; the top edge 1 is inside the last band.
    modes, sigma = discrepancy_modes(model, 2, np.array([[1.0], [0.0], [0.0]]), ModelError(bands=((0.5, 1.0, 0.1),
                                                                                                   (-1.0, -0.5, 0.1))))
    assert modes.shape == (6, 2) and np.count_nonzero(modes) == 2
    assert discrepancy_modes(model, 2, cos, ModelError())[0].shape == (6, 0)


def test_two_lights_have_their_own_bands_and_a_shared_light_is_one():
    model = np.ones(4)
    cos = np.array([[0.0, 0.9], [0.05, 0.0]])  # two pixels (two channels each), two lights
    modes, sigma = discrepancy_modes(model, 2, cos, ModelError(bands=((-0.1, 0.1, 0.1),)))
    assert modes.shape == (4, 4)  # light 0: both pixels (2 channels); light 1: pixel 1 (2 channels)
    a = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0})
    b = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0}, distance=2.0)
    c = _view({"type": "point", "position": [20.0, 5.0, 10.0], "intensity": 300.0})
    assert light_key(a.lights[0]) == light_key(b.lights[0]) != light_key(c.lights[0])


def test_an_error_at_the_terminator_is_covered_by_the_stated_bands():
    """A target the model misses by +12% in the terminator band only (1% pixel noise): the band is where the blur
    shows, so the fit moves l_d, and without a statement its standard errors miss the truth by several. With that
    band's error stated, they cover it; the estimate does not change."""
    from jaxsss.export.compare import pixel_light_cosines

    scene = _view({"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": 300.0})
    clean = np.asarray(prepare(scene, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(
        scene.material.medium))
    cos = pixel_light_cosines(scene)[1][..., 0]
    band = np.where(np.abs(np.nan_to_num(cos, nan=1.0)) < 0.1, 0.12, 0.0)[..., None]
    stderr = np.where(clean > 0, 0.01 * clean + 1e-12, 1.0)
    noisy = clean * (1.0 + band) + stderr * np.random.default_rng(3).standard_normal(clean.shape)
    target = np.where(clean > 0, np.clip(noisy, 0.0, None), 0.0)
    plain = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole")
    stated = fit_image(scene, target, target_stderr=stderr, max_pixels=None, bssrdf="dipole",
                       model_error=ModelError(bands=((-0.1, 0.1, 0.12),)))
    assert plain.converged and stated.converged
    np.testing.assert_allclose(np.asarray(stated.sigma_a), np.asarray(plain.sigma_a), rtol=1e-10)
    est = np.array([float(plain.sigma_a[0]), float(plain.sigma_s_prime[0])])
    se_plain = np.array([float(plain.sigma_a_stderr[0]), float(plain.sigma_s_prime_stderr[0])])
    se_stated = np.array([float(stated.sigma_a_stderr[0]), float(stated.sigma_s_prime_stderr[0])])
    assert np.any(np.abs(est - TRUTH) > 3 * se_plain), (est, se_plain)  # the premise
    assert np.all(np.abs(est - TRUTH) < 2 * se_stated), (est, se_stated)
