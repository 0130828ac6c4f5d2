"""Layer lookup against hand-built textures (Algorithm 1's FindLayer and LayerThickness)."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.layered.localise import find_layer, layer_thickness, texture_lookup, texture_offset

# A 2 x 3 texture, two layers; row 0 is the top of the image (v near 1).
B = np.array(
    [
        [[0.1, 0.5], [0.2, 0.6], [0.3, 0.7]],
        [[1.1, 1.5], [1.2, 1.6], [1.3, 1.7]],
    ]
)


def _uv_of_texel(row, col):
    h, w = B.shape[:2]
    return jnp.array([(col + 0.5) / w, 1.0 - (row + 0.5) / h])


@pytest.mark.parametrize("row, col", [(0, 0), (0, 2), (1, 1), (1, 2)])
def test_lookup_at_texel_centres_is_exact(row, col):
    out = texture_lookup(jnp.asarray(B), _uv_of_texel(row, col))
    np.testing.assert_allclose(out, B[row, col], atol=1e-15)


def test_lookup_is_bilinear_and_wraps():
    b = jnp.asarray(B)
    mid = (_uv_of_texel(0, 0) + _uv_of_texel(1, 1)) / 2
    np.testing.assert_allclose(texture_lookup(b, mid), B[:2, :2].mean(axis=(0, 1)), atol=1e-15)
    # Wrap-around: u and v shifted by whole texture widths read the same texel; between the last and the first
    # column the lookup blends them.
    np.testing.assert_allclose(texture_lookup(b, _uv_of_texel(1, 2) + jnp.array([3.0, -2.0])), B[1, 2], atol=1e-14)
    edge = jnp.array([1.0, 1.0 - 0.5 / 2])  # u = 1: halfway between column 2 and column 0 (wrapped), row 0
    np.testing.assert_allclose(texture_lookup(b, edge), (B[0, 2] + B[0, 0]) / 2, atol=1e-14)


def test_find_layer_against_hand_built_bounds():
    bounds = jnp.array([0.2, 0.5, 0.5, 1.0])  # layer 2 is absent (zero thickness)
    depth = jnp.array([-0.1, 0.0, 0.19, 0.2, 0.49, 0.5, 0.99, 1.0, 5.0])
    np.testing.assert_array_equal(find_layer(depth, bounds), [0, 0, 0, 1, 1, 3, 3, 4, 4])
    np.testing.assert_allclose(layer_thickness(bounds), [0.2, 0.3, 0.0, 0.5])


def test_layer_at_a_point_below_the_surface_matches_the_texel():
    # A point below P whose tangent-space offset lands on texel (1, 0); its depth puts it in layer 1 there.
    T = jnp.array([1.0 / 30.0, 0.0, 0.0])  # 30 mm per texture width
    Bv = jnp.array([0.0, 1.0 / 20.0, 0.0])
    uv_p = _uv_of_texel(0, 0)
    d = jnp.array([0.0, -10.0, -1.3])  # 10 mm down in v = one texel row lower; 1.3 mm deep
    uv_m = texture_offset(uv_p, T, Bv, d)
    np.testing.assert_allclose(uv_m, _uv_of_texel(1, 0), atol=1e-15)
    bounds = texture_lookup(jnp.asarray(B), uv_m)
    assert int(find_layer(jnp.asarray(1.3), bounds)) == 1
