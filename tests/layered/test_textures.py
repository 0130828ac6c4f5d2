"""Subsurface textures: PNG depth scale, stacking, procedural generators, layer bottoms."""

import numpy as np
import pytest
from PIL import Image

from jaxsss.layered import SubsurfaceTexture, constant_texture, load_texture_png, procedural_texture, vein_texture


def test_constant_texture_stacks_thicknesses():
    t = constant_texture([0.2, 0.3, 1.0], size=3)
    np.testing.assert_allclose(t.depth[1, 2], [0.2, 0.5, 1.5])
    assert t.depth_max == pytest.approx(1.5)


def test_png_brighter_is_thinner_with_documented_scale(tmp_path):
    rgba = np.zeros((2, 3, 4), dtype=np.uint8)
    rgba[..., 0] = 255  # white: at the surface
    rgba[..., 1] = 0  # black: depth_scale deep
    rgba[..., 2] = 51  # 0.2 -> 0.8 * scale
    rgba[0, 0, 3] = 204
    Image.fromarray(rgba, "RGBA").save(tmp_path / "t.png")
    tex = load_texture_png(tmp_path / "t.png", [1.0, 2.0, 0.5, 1.0])
    assert tex.depth.shape == (2, 3, 4)
    np.testing.assert_allclose(tex.depth[0, 0], [0.0, 2.0, 0.5 * (1 - 51 / 255), 1 - 204 / 255], rtol=1e-14)
    # Running maximum: a channel shallower than the one above means the layer is absent there.
    np.testing.assert_allclose(tex.boundaries[0, 0], [0.0, 2.0, 2.0, 2.0])


def test_png_files_stack_in_order_and_must_match(tmp_path):
    Image.fromarray(np.full((4, 4, 4), 255, np.uint8), "RGBA").save(tmp_path / "a.png")
    Image.fromarray(np.zeros((4, 4), np.uint8), "L").save(tmp_path / "b.png")
    Image.fromarray(np.zeros((5, 4), np.uint8), "L").save(tmp_path / "c.png")
    tex = load_texture_png([tmp_path / "a.png", tmp_path / "b.png"], 1.5)
    assert tex.n_layers == 5
    np.testing.assert_allclose(tex.depth[0, 0], [0, 0, 0, 0, 1.5])
    with pytest.raises(ValueError, match="c.png.*must match"):
        load_texture_png([tmp_path / "a.png", tmp_path / "c.png"], 1.0)
    with pytest.raises(ValueError, match=r"depth_scale_mm=.*\(0, inf\)"):
        load_texture_png(tmp_path / "a.png", 0.0)
    with pytest.raises(FileNotFoundError, match="nope.png"):
        load_texture_png(tmp_path / "nope.png", 1.0)


def test_veins_are_deterministic_bounded_and_tile():
    a = vein_texture(size=64, thickness=[0.1, 0.2, 0.5], vein_depth=0.4, seed=1)
    b = vein_texture(size=64, thickness=[0.1, 0.2, 0.5], vein_depth=0.4, seed=1)
    np.testing.assert_array_equal(a.depth, b.depth)
    blood = a.depth[..., 1] - a.depth[..., 0]
    assert blood.min() == pytest.approx(0.2) and blood.max() == pytest.approx(0.6)
    assert 0.01 < np.mean(blood > 0.2 + 1e-9) < 0.6  # veins cover part of the texture
    np.testing.assert_allclose(a.depth[..., 0], 0.1)
    # Seamless: the jump across the wrap-around edge is no larger than the largest jump inside.
    inside = np.abs(np.diff(blood, axis=1)).max()
    assert np.abs(blood[:, 0] - blood[:, -1]).max() <= inside + 1e-12


def test_procedural_registry_errors():
    with pytest.raises(ValueError, match="constant, veins, blobs"):
        procedural_texture("marble")
    with pytest.raises(ValueError, match="unknown parameter.*colour"):
        procedural_texture("blobs", thickness=[1.0], colour=2)
    blobs = procedural_texture("blobs", thickness=[0.1, 0.1], blob_layer=0, blob_depth=0.3, size=32)
    assert blobs.depth[..., 0].max() <= 0.4 + 1e-12 and blobs.depth[..., 0].min() >= 0.1


def test_bad_texture_array():
    with pytest.raises(ValueError, match=r"depth=-1.*\[0, inf\)"):
        SubsurfaceTexture(np.full((2, 2, 1), -1.0))
    with pytest.raises(ValueError, match="shape"):
        SubsurfaceTexture(np.zeros((2, 2)))
