"""LayerStack validation, the fish preset (Table 1) and the outer-layer medium."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.layered import FISH_TABLE1, LayerStack, layer_preset, outer_layer_medium


def test_fish_preset_is_table_1():
    s = layer_preset("fish")
    assert s.names == ("dermis", "blood", "organs")
    np.testing.assert_array_equal(s.sigma_s, [[2.0, 1.0, 1.0], [6.0, 3.0, 2.0], [1.0, 1.0, 2.0]])
    np.testing.assert_array_equal(s.sigma_t, [[2.6, 1.6, 1.6], [6.6, 3.6, 2.6], [1.5, 1.5, 2.5]])
    np.testing.assert_array_equal(s.g[:, 0], [0.25, 0.40, 0.80])
    assert s.phase == ("schlick",) * 3
    assert "Table 1" in FISH_TABLE1["citation"]


def test_broadcasting_of_scalars_and_per_layer_values():
    s = LayerStack.create([1.0, 2.0], [[1.5, 2.0, 3.0], [2.0, 2.5, 3.0]], g=[0.1, 0.2], phase=("hg", "schlick"))
    assert s.sigma_s.shape == (2, 3) and s.sigma_t.shape == (2, 3) and s.g.shape == (2, 1)
    np.testing.assert_allclose(s.sigma_a, [[0.5, 1.0, 2.0], [0.0, 0.5, 1.0]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sigma_s=[-1.0], sigma_t=[1.0]), r"LayerStack\(sigma_s=-1\).*\[0, inf\)"),
        (dict(sigma_s=[1.0], sigma_t=[0.5]), r"sigma_t.*below sigma_s"),
        (dict(sigma_s=[1.0], sigma_t=[2.0], g=1.0), r"LayerStack\(g=1\).*\(-1, 1\)"),
        (dict(sigma_s=[np.nan], sigma_t=[2.0]), r"sigma_s=nan"),
        (dict(sigma_s=[1.0], sigma_t=[2.0], g=0.95, phase="schlick"), r"'schlick' layer needs \|g\| < 0.9381"),
        (dict(sigma_s=[1.0], sigma_t=[np.inf]), r"sigma_t=inf"),
        (dict(sigma_s=[1.0], sigma_t=[2.0], phase="mie"), r"phase='mie'.*hg, schlick"),
        (dict(sigma_s=[1.0, 1.0], sigma_t=[2.0, 2.0], phase=("hg",)), r"1 names for 2 layers"),
    ],
)
def test_bad_input_names_argument_and_range(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LayerStack.create(**kwargs)


def test_with_layer_sigma_s_and_outer_medium():
    s = layer_preset("fish").with_layer_sigma_s(1, jnp.asarray(4.0))
    np.testing.assert_array_equal(s.sigma_s[1], [4.0, 4.0, 4.0])
    m = outer_layer_medium(layer_preset("fish"), eta=1.33)
    np.testing.assert_allclose(m.sigma_a, [0.6, 0.6, 0.6], rtol=1e-14)
    np.testing.assert_allclose(m.sigma_s_prime, [1.5, 0.75, 0.75], rtol=1e-14)
