"""TOML scene files: the examples load, every bad input names the file and the key, and paths resolve."""

import copy
import dataclasses
from pathlib import Path

import colour
import numpy as np
import pytest
import trimesh

import jaxsss
from jaxsss.render.scene import (
    RenderSettings,
    SceneError,
    load_scene,
    parse_scene,
    scene_with,
)

EXAMPLES = sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.toml"))

BASE = {
    "mesh": {"builtin": "sphere", "radius": 10.0, "subdivisions": 2},
    "material": {"name": "marble"},
    "light": [{"type": "point", "position": [0.0, -50.0, 100.0], "intensity": 1.0e4}],
    "camera": {"position": [0.0, -100.0, 20.0], "look_at": [0.0, 0.0, 0.0], "resolution": [64, 48]},
}


def _with(edit):
    data = copy.deepcopy(BASE)
    edit(data)
    return data


def _set(section, key, value):
    def edit(data):
        target = data[section][0] if isinstance(data[section], list) else data[section]
        target[key] = value

    return edit


def _replace(section, value):
    def edit(data):
        data[section] = value

    return edit


def _drop(section, key=None):
    def edit(data):
        if key is None:
            del data[section]
        else:
            del data[section][key]

    return edit


def _floor(**extra):
    return _replace("occluder", [{"builtin": "slab", **extra}])


def test_examples_exist():
    names = {p.stem for p in EXAMPLES}
    assert {"marble_teapot", "skin_sphere", "ketchup_torus", "milk_box_on_floor"} <= names


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_loads(path):
    scene = load_scene(path)
    assert scene.path == str(path)
    assert len(scene.mesh.faces) > 0 and scene.lights
    assert scene.material.medium.sigma_a.shape == (3,)
    assert scene.output.exposure > 0


def test_default_scene_is_the_marble_teapot():
    scene = load_scene(next(p for p in EXAMPLES if p.stem == "marble_teapot"))
    assert scene.material.name == "marble"
    assert float(scene.material.medium.eta) == jaxsss.material("marble").eta
    assert scene.mesh_description == "builtin teapot (size=60)"
    assert scene.mesh.extents[2] == pytest.approx(60.0)
    assert [light.kind for light in scene.lights] == ["point", "directional"]
    assert scene.camera.resolution == (512, 512) and scene.camera.spp == 1
    assert scene.render.eps == 0.05


def test_milk_box_on_floor_has_a_floor_under_the_box():
    scene = load_scene(next(p for p in EXAMPLES if p.stem == "milk_box_on_floor"))
    assert scene.material.name == "wholemilk"
    (floor,) = scene.occluders
    np.testing.assert_allclose(floor.albedo, [0.5, 0.5, 0.5])
    assert floor.mesh.bounds[1, 2] == pytest.approx(scene.mesh.bounds[0, 2])  # the box stands on the floor


def test_parse_values_and_defaults():
    scene = parse_scene(copy.deepcopy(BASE))
    assert scene.path is None
    assert scene.mesh_description == "builtin sphere (radius=10, subdivisions=2)"
    light = scene.lights[0]
    np.testing.assert_array_equal(light.intensity, [1.0e4] * 3)
    assert light.direction is None and light.position.shape == (3,)
    cam = scene.camera
    np.testing.assert_array_equal(cam.up, [0.0, 0.0, 1.0])
    assert (cam.fov_deg, cam.resolution, cam.spp) == (40.0, (64, 48), 1)
    assert scene.render == scene.render and isinstance(scene.render, RenderSettings)
    assert scene.render.method == "hierarchical" and scene.render.max_samples == 200_000
    np.testing.assert_array_equal(scene.output.background, np.zeros(3))
    assert scene.occluders == () and scene.environment is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.camera.fov_deg = 10.0
    with pytest.raises(ValueError):
        light.intensity[0] = 0.0  # read-only arrays


def test_lights_and_transform():
    data = _with(
        _replace(
            "light",
            [
                {"type": "directional", "direction": [0.0, 0.0, -2.0], "intensity": [1.0, 2.0, 3.0]},
                {"type": "spot", "position": [0, 0, 50], "direction": [0, 0, -1], "intensity": 5.0, "cone_deg": 30},
            ],
        )
    )
    data["mesh"].update(scale=2.0, translate=[1.0, 2.0, 3.0])
    data["render"] = {"shadows": True, "indirect": "off", "eps": 0.1}
    scene = parse_scene(data)
    directional, spot = scene.lights
    np.testing.assert_allclose(directional.direction, [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(directional.intensity, [1.0, 2.0, 3.0])
    assert directional.position is None
    assert (spot.kind, spot.cone_deg, spot.falloff_deg) == ("spot", 30.0, 0.0)
    np.testing.assert_allclose(scene.mesh.bounds, [[-19, -18, -17], [21, 22, 23]], atol=1e-9)
    assert scene.mesh_description.endswith("scale=2, translate=[1, 2, 3]")
    assert (scene.render.shadows, scene.render.indirect, scene.render.eps) == ("on", "off", 0.1)


@pytest.mark.parametrize(
    "material",
    [
        {"sigma_a": [0.0021, 0.0041, 0.0071], "sigma_s_prime": [2.19, 2.62, 3.00], "eta": 1.5},
        {"sigma_a": 0.01, "sigma_s_prime": 1.0},
        {"rd": [0.8, 0.6, 0.5], "ld": [5.0, 3.0, 2.0], "eta": 1.4, "g": 0.2},
        {"name": "Espresso"},  # a Narasimhan medium: no tabulated eta -> 1.3
    ],
)
def test_material_alternatives(material):
    scene = parse_scene(_with(_replace("material", material)))
    m = scene.material.medium
    assert m.sigma_a.shape == (3,) and m.sigma_s_prime.shape == (3,)
    assert float(m.eta) == material.get("eta", 1.3)
    if "rd" in material:
        rd, ld = jaxsss.to_rd_ld(m)
        np.testing.assert_allclose(rd, material["rd"], rtol=1e-6)
        np.testing.assert_allclose(ld, material["ld"], rtol=1e-6)
        assert float(m.g) == 0.2
    if "name" in material:
        assert scene.material.name == "espresso"


# (case id, edit of BASE, dotted key expected in the message, extra text expected)
ERROR_CASES = [
    ("unknown-top-key", _replace("lights", []), "lights", "allowed"),
    ("unknown-mesh-key", _set("mesh", "radiuss", 1.0), "mesh.radiuss", "allowed"),
    ("unknown-material-key", _set("material", "colour", 1.0), "material.colour", "allowed"),
    ("unknown-light-key", _set("light", "power", 1.0), "light[0].power", "allowed"),
    ("unknown-camera-key", _set("camera", "zoom", 1.0), "camera.zoom", "allowed"),
    ("unknown-render-key", _replace("render", {"quality": 1}), "render.quality", "allowed"),
    ("unknown-output-key", _replace("output", {"gamma": 2.2}), "output.gamma", "allowed"),
    ("unknown-occluder-key", _floor(colour=0.5), "occluder[0].colour", "allowed"),
    ("missing-mesh", _drop("mesh"), "mesh", "missing"),
    ("missing-material", _drop("material"), "material", "missing"),
    ("missing-camera", _drop("camera"), "camera", "missing"),
    ("missing-light", _drop("light"), "light", "at least one"),
    ("empty-light", _replace("light", []), "light", "at least one"),
    ("mesh-both", _set("mesh", "file", "x.ply"), "mesh", "exactly one"),
    ("mesh-neither", _replace("mesh", {"scale": 2.0}), "mesh", "exactly one"),
    ("unknown-builtin", _replace("mesh", {"builtin": "cube"}), "mesh.builtin", "teapot"),
    ("param-of-other-builtin", _set("mesh", "extents", [1, 2, 3]), "mesh.extents", "radius"),
    ("builtin-param-range", _set("mesh", "radius", -1.0), "mesh.radius", "(0, inf)"),
    ("builtin-param-type", _set("mesh", "subdivisions", 2.5), "mesh.subdivisions", "integer"),
    ("missing-mesh-file", _replace("mesh", {"file": "nothing.ply"}), "mesh.file", "does not exist"),
    ("not-watertight", _replace("mesh", {"builtin": "teapot", "require_watertight": True}), "mesh.require_watertight",
     "not watertight"),
    ("negative-scale", _set("mesh", "scale", -1.0), "mesh.scale", "(0, inf)"),
    ("rotate-length", _set("mesh", "rotate_deg", [0, 90]), "mesh.rotate_deg", "3 values"),
    ("negative-sigma-a", _replace("material", {"sigma_a": [-0.1, 0, 0], "sigma_s_prime": 1.0}), "material.sigma_a",
     "-0.1 (element 0) is outside the allowed range [0, inf)"),
    ("sigma-length", _replace("material", {"sigma_a": [0.1, 0.2], "sigma_s_prime": 1.0}), "material.sigma_a",
     "3 values"),
    ("sigma-type", _replace("material", {"sigma_a": "lots", "sigma_s_prime": 1.0}), "material.sigma_a",
     "not a number"),
    ("medium-zero", _replace("material", {"sigma_a": 0.0, "sigma_s_prime": 0.0}), "material", "absorb or scatter"),
    ("material-both", _set("material", "rd", 0.5), "material", "exactly one"),
    ("material-neither", _replace("material", {"eta": 1.3}), "material", "exactly one"),
    ("material-half", _replace("material", {"sigma_a": 0.1}), "material.sigma_s_prime", "go together"),
    ("unknown-material-name", _set("material", "name", "cheese"), "material.name", "marble"),
    ("rd-range", _replace("material", {"rd": 1.2, "ld": 1.0}), "material.rd", "(0, 1)"),
    ("ld-range", _replace("material", {"rd": 0.5, "ld": 0.0}), "material.ld", "(0, inf)"),
    ("eta-range", _set("material", "eta", 0.0), "material.eta", "(0, inf)"),
    ("g-range", _set("material", "g", 1.0), "material.g", "(-1, 1)"),
    ("roughness-range", _set("material", "specular_roughness", 0.0), "material.specular_roughness", "(0, 1]"),
    ("missing-texture", _set("material", "texture", "none.png"), "material.texture", "does not exist"),
    ("light-type", _set("light", "type", "area"), "light[0].type", "point, directional, spot"),
    ("light-no-type", _replace("light", [{"intensity": 1.0}]), "light[0].type", "missing"),
    ("light-missing-position", _replace("light", [{"type": "point", "intensity": 1.0}]), "light[0].position",
     "missing"),
    ("light-extra-key", _set("light", "direction", [0, 0, -1]), "light[0].direction", "not used by a point light"),
    ("light-negative", _set("light", "intensity", [1.0, -1.0, 1.0]), "light[0].intensity", "[0, inf)"),
    ("light-intensity-type", _set("light", "intensity", "bright"), "light[0].intensity", "not a number"),
    ("light-direction-zero", _replace("light", [{"type": "directional", "direction": [0, 0, 0], "intensity": 1.0}]),
     "light[0].direction", "zero vector"),
    ("spot-no-cone", _replace("light", [{"type": "spot", "position": [0, 0, 9], "direction": [0, 0, -1],
     "intensity": 1.0}]), "light[0].cone_deg", "missing"),
    ("spot-falloff", _replace("light", [{"type": "spot", "position": [0, 0, 9], "direction": [0, 0, -1],
     "intensity": 1.0, "cone_deg": 10.0, "falloff_deg": 20.0}]), "light[0].falloff_deg", "[0, 10]"),
    ("light-not-table", _replace("light", [1.0]), "light[0]", "table"),
    ("camera-missing-look-at", _drop("camera", "look_at"), "camera.look_at", "missing"),
    ("camera-position-length", _set("camera", "position", [0, 0]), "camera.position", "3 values"),
    ("camera-degenerate", _set("camera", "look_at", [0.0, -100.0, 20.0]), "camera.look_at", "equals"),
    ("camera-up-parallel", _set("camera", "up", [0.0, 5.0, -1.0]), "camera.up", "parallel"),
    ("camera-up-zero", _set("camera", "up", [0.0, 0.0, 0.0]), "camera.up", "zero"),
    ("fov-180", _set("camera", "fov_deg", 180.0), "camera.fov_deg", "(0, 180)"),
    ("fov-0", _set("camera", "fov_deg", 0), "camera.fov_deg", "(0, 180)"),
    ("resolution-zero", _set("camera", "resolution", [0, 10]), "camera.resolution", "[1, inf)"),
    ("resolution-float", _set("camera", "resolution", [64.0, 64]), "camera.resolution", "not an integer"),
    ("resolution-length", _set("camera", "resolution", [64]), "camera.resolution", "[width, height]"),
    ("spp-zero", _set("camera", "spp", 0), "camera.spp", "[1, inf)"),
    ("eps-zero", _replace("render", {"eps": 0.0}), "render.eps", "(0, inf)"),
    ("eps-bool", _replace("render", {"eps": True}), "render.eps", "not a number"),
    ("density-negative", _replace("render", {"density": -1.0}), "render.density", "(0, inf)"),
    ("method-unknown", _replace("render", {"method": "fast"}), "render.method", "hierarchical, direct"),
    ("switch-unknown", _replace("render", {"shadows": "maybe"}), "render.shadows", "auto, on, off"),
    ("max-samples", _replace("render", {"max_samples": 0}), "render.max_samples", "[1, inf)"),
    ("exposure", _replace("output", {"exposure": 0.0}), "output.exposure", "(0, inf)"),
    ("background", _replace("output", {"background": [0, -1, 0]}), "output.background", "[0, inf)"),
    ("occluder-albedo", _floor(albedo=1.5), "occluder[0].albedo", "[0, 1]"),
    ("occluder-no-mesh", _replace("occluder", [{"albedo": 0.5}]), "occluder[0]", "exactly one"),
    ("blocker-no-mesh", _replace("blocker", [{}]), "blocker[0]", "exactly one"),
    ("blocker-albedo", _replace("blocker", [{"builtin": "box", "albedo": 0.5}]), "blocker[0].albedo", "unknown key"),
    ("photons", _replace("render", {"photons": 0}), "render.photons", "[1, inf)"),
    ("environment-missing", _replace("environment", "sky.hdr"), "environment.file", "does not exist"),
    ("section-not-table", _replace("camera", [1, 2]), "camera", "table"),
]


@pytest.mark.parametrize("edit, key, text", [c[1:] for c in ERROR_CASES], ids=[c[0] for c in ERROR_CASES])
def test_errors_name_file_and_key(tmp_path, edit, key, text):
    path = str(tmp_path / "bad_scene.toml")
    with pytest.raises(SceneError) as info:
        parse_scene(_with(edit), path=path, base_dir=tmp_path)
    err = info.value
    assert str(err).startswith(f"{path}: [{key}] ")
    assert (err.path, err.key) == (path, key)
    assert text in str(err)


SCENE_TEXT = """
[mesh]
{mesh}

[material]
name = "marble"
{material}

[[light]]
type = "point"
position = [0.0, -50.0, 100.0]
intensity = 1.0e4

[camera]
position = [0.0, -100.0, 20.0]
look_at = [0.0, 0.0, 0.0]
"""


def _write(tmp_path, mesh='builtin = "sphere"\nsubdivisions = 1', material="", name="scene.toml"):
    path = tmp_path / name
    path.write_text(SCENE_TEXT.format(mesh=mesh, material=material))
    return path


def test_toml_syntax_error_names_file_and_line(tmp_path):
    path = _write(tmp_path, material="eta = [1.3,\n")
    with pytest.raises(SceneError, match=r"scene\.toml: TOML syntax error: .*line \d+") as info:
        load_scene(path)
    assert info.value.key is None


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="nope.toml"):
        load_scene(tmp_path / "nope.toml")


def test_unreadable_mesh_file(tmp_path):
    (tmp_path / "broken.ply").write_text("this is not a mesh\n")
    path = _write(tmp_path, mesh='file = "broken.ply"')
    with pytest.raises(SceneError, match=r"scene\.toml: \[mesh\.file\] .*broken\.ply"):
        load_scene(path)


@pytest.mark.parametrize("suffix", ["ply", "obj"])
def test_mesh_file_resolves_relative_to_the_scene(tmp_path, monkeypatch, suffix):
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=[1.0, 2.0, 3.0]).export(tmp_path / "meshes" / f"cube.{suffix}")
    path = _write(tmp_path, mesh=f'file = "meshes/cube.{suffix}"\nscale = 10.0\nrequire_watertight = true')
    monkeypatch.chdir(tmp_path / "meshes")  # the working directory must not matter
    scene = load_scene(path)
    np.testing.assert_allclose(scene.mesh.extents, [10.0, 20.0, 30.0])
    assert scene.mesh_description == f"file meshes/cube.{suffix}, scale=10"


def test_texture_is_decoded_to_linear(tmp_path):
    from PIL import Image

    pixels = np.zeros((3, 4, 3), dtype=np.uint8)
    pixels[0, 0] = [128, 64, 255]
    pixels[2, 3] = [10, 200, 30]
    Image.fromarray(pixels, mode="RGB").save(tmp_path / "skin.png")
    scene = load_scene(_write(tmp_path, material='texture = "skin.png"\nspecular_roughness = 0.3'))
    tex = scene.material.texture
    assert tex.shape == (3, 4, 3) and tex.dtype == np.float64
    np.testing.assert_allclose(tex[0, 0], colour.cctf_decoding(np.array([128, 64, 255]) / 255.0, function="sRGB"))
    np.testing.assert_allclose(tex[2, 3], colour.cctf_decoding(np.array([10, 200, 30]) / 255.0, function="sRGB"))
    assert tex[0, 0, 0] == pytest.approx(0.2158605, rel=1e-6)  # sRGB 128 -> linear
    assert scene.material.texture_path == str(tmp_path / "skin.png")
    assert scene.material.specular_roughness == 0.3


def test_environment_path_is_resolved(tmp_path):
    import imagecodecs

    (tmp_path / "sky.hdr").write_bytes(imagecodecs.rgbe_encode(np.ones((2, 4, 3), np.float32)))
    scene = parse_scene(_with(_replace("environment", "sky.hdr")), base_dir=tmp_path)
    assert scene.environment == str(tmp_path / "sky.hdr")
    assert scene.lights[-1].kind == "environment" and scene.lights[-1].environment.path == scene.environment
    (tmp_path / "bad.hdr").write_bytes(b"#?RADIANCE\n")
    with pytest.raises(SceneError, match="could not be read") as err:
        parse_scene(_with(_replace("environment", "bad.hdr")), base_dir=tmp_path)
    assert err.value.key == "environment.file"


def test_blockers_are_parsed_and_noted_by_the_plan():
    from jaxsss.render.plan import make_plan

    scene = parse_scene(_with(_replace("blocker", [{"builtin": "box", "extents": [2.0, 3.0, 4.0]}])))
    assert len(scene.blockers) == 1 and scene.blockers[0].description == "builtin box (extents=[2, 3, 4])"
    np.testing.assert_allclose(scene.blockers[0].mesh.extents, [2.0, 3.0, 4.0])
    item = {i.name: i for i in make_plan(scene).items}["blockers"]
    assert not item.included and "--method photon" in item.reason
    assert parse_scene(BASE).blockers == () and "blockers" not in {i.name for i in make_plan(parse_scene(BASE)).items}
    assert parse_scene(_with(_replace("render", {"photons": 1234}))).render.photons == 1234


def test_scene_with():
    scene = parse_scene(copy.deepcopy(BASE))
    faster = scene_with(scene, render=RenderSettings(eps=0.2))
    assert faster.render.eps == 0.2 and faster.mesh is scene.mesh and scene.render.eps is None  # None: the plan's
    with pytest.raises(ValueError, match="valid: path, mesh"):
        scene_with(scene, renderer=None)
