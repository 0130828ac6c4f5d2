"""The [layers] table: errors name the file and dotted key; the loader strips [layers] before parse_scene."""

import numpy as np
import pytest
from PIL import Image

from jaxsss.layered import load_layered_scene, parse_layers
from jaxsss.render.scene import SceneError

LAYER = {"sigma_s": [1.0, 2.0, 3.0], "sigma_t": [2.0, 2.5, 3.5], "g": 0.3, "phase": "hg"}
TEX = {"procedural": "constant", "thickness": [0.5]}


def test_explicit_layers_and_knobs():
    spec = parse_layers({"layer": [LAYER], "texture": TEX, "samples": 7, "tile": 3.0, "wrap": "uv",
                         "depth_max": 2.0, "clip_to_exit": False})
    assert spec.samples == 7 and spec.tile == (3.0, 3.0) and spec.wrap == (True, True)
    assert spec.effective_depth_max == 2.0 and not spec.clip_to_exit
    np.testing.assert_allclose(spec.stack.sigma_t, [[2.0, 2.5, 3.5]])


@pytest.mark.parametrize(
    "table, key, match",
    [
        ({"layer": [LAYER]}, "layers.texture", "missing"),
        ({"texture": TEX}, "layers", "exactly one of preset"),
        ({"preset": "fish", "layer": [LAYER], "texture": TEX}, "layers", "exactly one of preset"),
        ({"preset": "frog", "texture": TEX}, "layers.preset", "'frog' is not one of: fish"),
        ({"layer": [{**LAYER, "sigma_t": [0.5, 2.5, 3.5]}], "texture": TEX}, "layers.layer[0].sigma_t",
         r"0.5 \(element 0\) is below sigma_s = 1"),
        ({"layer": [{**LAYER, "g": 1.0}], "texture": TEX}, "layers.layer[0].g", r"outside the allowed range \(-1, 1\)"),
        ({"layer": [{**LAYER, "colour": 1}], "texture": TEX}, "layers.layer[0].colour", "unknown key"),
        ({"layer": [LAYER], "texture": TEX, "samples": 0}, "layers.samples", r"\[1, inf\)"),
        ({"layer": [LAYER], "texture": TEX, "plane_eps": 1.5}, "layers.plane_eps", r"\(0, 1\)"),
        ({"layer": [LAYER], "texture": TEX, "wrap": "w"}, "layers.wrap", "auto, none, u, v, uv"),
        ({"layer": [LAYER, LAYER], "texture": TEX}, "layers.texture.thickness", "not one number or 2 values"),
        ({"layer": [LAYER], "texture": {"procedural": "veins"}}, "layers.texture.thickness", "missing"),
        ({"layer": [LAYER], "texture": {"files": ["none.png"], "depth_scale_mm": 1.0}}, "layers.texture.files",
         "does not exist"),
        ({"layer": [LAYER], "texture": {**TEX, "files": "a.png"}}, "layers.texture", "exactly one of files"),
    ],
)
def test_errors_name_the_key(table, key, match):
    with pytest.raises(SceneError, match=match) as err:
        parse_layers(table, path="scene.toml")
    assert err.value.key == key and err.value.path == "scene.toml"


def test_png_texture_relative_to_scene_file(tmp_path):
    Image.fromarray(np.full((4, 4, 3), 128, np.uint8), "RGB").save(tmp_path / "t.png")
    spec = parse_layers({"preset": "fish", "texture": {"files": ["t.png"], "depth_scale_mm": [0.2, 0.4, 1.0]}},
                        base_dir=tmp_path)
    np.testing.assert_allclose(spec.texture.depth[0, 0], np.array([0.2, 0.4, 1.0]) * (1 - 128 / 255))


def test_loader_strips_layers_and_requires_them(tmp_path):
    body = """
[mesh]
builtin = "sphere"
[material]
sigma_a = 0.1
sigma_s_prime = 1.0
[[light]]
type = "point"
position = [0.0, -50.0, 0.0]
intensity = 100.0
[camera]
position = [0.0, -60.0, 0.0]
look_at = [0.0, 0.0, 0.0]
"""
    (tmp_path / "a.toml").write_text(body + '[layers]\npreset = "fish"\n[layers.texture]\nprocedural = "constant"\n'
                                     'thickness = [0.1, 0.2, 0.3]\n')
    scene, spec = load_layered_scene(tmp_path / "a.toml")
    assert spec.stack.n_layers == 3 and spec.texture.depth_max == pytest.approx(0.6)
    (tmp_path / "b.toml").write_text(body)
    with pytest.raises(SceneError, match=r"\[layers\] missing section"):
        load_layered_scene(tmp_path / "b.toml")
