"""The pbrt-v4 export (jaxsss.export.pbrt): the numbers and units written, parsed back from the file."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from jaxsss.export import ExportError
from jaxsss.export import pbrt
from jaxsss.render import load_scene, parse_scene, scene_with
from jaxsss.render.scene import Blocker

REFERENCES = Path(__file__).parent / "references"


def _params(line: str) -> dict:
    """``"type name" [ values ]`` pairs of one pbrt statement -> {name: list of floats or strings}."""
    out = {}
    for kind, name, body in re.findall(r'"(\w+) (\w+)" \[ ([^\]]*) \]', line):
        out[name] = [v.strip('"') for v in body.split()] if kind in ("string", "bool") else [float(v) for v in
                                                                                              body.split()]
    return out


def _statement(text: str, start: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith(start)]
    assert len(lines) == 1, (start, lines)
    return lines[0]


def test_subsurface_material_units(tmp_path):
    """sigma_a and sigma_s = sigma_s' / (1 - g) in 1/mm with scale 1 (the geometry is in mm), g and eta as given."""
    scene = load_scene(REFERENCES / "g09_sphere.toml")
    path = pbrt.write_scene(scene, tmp_path, spp=64)
    text = path.read_text()
    assert "# units: lengths in mm; sigma_a, sigma_s in 1/mm (scale 1)" in text
    mat = _params(_statement(text, 'Material "subsurface"'))
    np.testing.assert_allclose(mat["sigma_a"], [0.05, 0.1, 0.2], rtol=1e-15)
    np.testing.assert_allclose(mat["sigma_s"], np.full(3, 1.0 / (1.0 - 0.9)), rtol=1e-15)
    assert mat["g"] == [pytest.approx(0.9)] and mat["eta"] == [1.0] and mat["scale"] == [1.0]
    assert mat["remaproughness"] == ["false"] and mat["roughness"] == [0.0]
    shape = _params(_statement(text, 'Shape "plymesh"'))
    assert (tmp_path / shape["filename"][0]).is_file()
    assert _params(_statement(text, "Sampler"))["pixelsamples"] == [64.0]


def test_camera_and_lights(tmp_path):
    scene = parse_scene({
        "mesh": {"builtin": "sphere", "radius": 10.0},
        "material": {"name": "marble", "specular_roughness": 0.2},
        "light": [{"type": "point", "position": [1.0, 2.0, 3.0], "intensity": [1.0, 2.0, 3.0]},
                  {"type": "directional", "direction": [0.0, 0.0, -2.0], "intensity": 0.5},
                  {"type": "spot", "position": [0.0, -50.0, 0.0], "direction": [0.0, 1.0, 0.0], "intensity": 7.0,
                   "cone_deg": 20.0, "falloff_deg": 4.0}],
        "camera": {"position": [0.0, -100.0, 10.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 30.0,
                   "resolution": [40, 80]},
        "occluder": [{"builtin": "slab", "width": 100.0, "depth": 100.0, "thickness": 2.0,
                      "translate": [0.0, 0.0, -12.0], "albedo": 0.3}],
    })
    text = pbrt.write_scene(scene, tmp_path).read_text()
    lines = text.splitlines()
    # The handedness flip comes before the LookAt, and both before the camera.
    i_scale, i_look, i_cam = (next(i for i, ln in enumerate(lines) if ln.startswith(s))
                              for s in ("Scale -1 1 1", "LookAt", "Camera"))
    assert i_scale < i_look < i_cam
    np.testing.assert_allclose([float(v) for v in lines[i_look].split()[1:]],
                               [0, -100, 10, 0, 0, 0, 0, 0, 1], atol=1e-12)
    # Portrait image: pbrt's fov is the horizontal one (the shorter axis).
    fov = _params(lines[i_cam])["fov"][0]
    assert math.tan(math.radians(fov) / 2) == pytest.approx(math.tan(math.radians(15.0)) * 40 / 80, rel=1e-12)
    assert pbrt.pbrt_fov(30.0, 80, 40) == 30.0
    film = _params(_statement(text, "Film"))
    assert film["xresolution"] == [40.0] and film["yresolution"] == [80.0]
    point = _params(_statement(text, 'LightSource "point"'))
    assert point["from"] == [1.0, 2.0, 3.0] and point["I"] == [1.0, 2.0, 3.0]
    distant = _params(_statement(text, 'LightSource "distant"'))
    assert distant["to"] == [0.0, 0.0, -1.0] and distant["L"] == [0.5] * 3  # irradiance W/mm^2
    spot = _params(_statement(text, 'LightSource "spot"'))
    assert spot["coneangle"] == [20.0] and spot["conedelta"] == [4.0] and spot["to"] == [0.0, -49.0, 0.0]
    assert _params(_statement(text, 'Material "subsurface"'))["roughness"] == [0.2]
    assert _params(_statement(text, 'Material "diffuse"'))["reflectance"] == [0.3] * 3
    assert (tmp_path / "occluder_0.ply").is_file()


def test_refuses_blockers(tmp_path):
    scene = load_scene(REFERENCES / "skin1_sphere.toml")
    with pytest.raises(ExportError, match=r"^\[blocker\[0\]\] blockers .* cannot be exported to pbrt-v4"):
        pbrt.write_scene(scene_with(scene, blockers=(Blocker(scene.mesh, "x"),)), tmp_path)
    assert not (tmp_path / "scene.pbrt").exists()


def test_refuses_spectral_media():
    """The exporters write RGB: a 4-channel medium is refused, naming the key."""
    import dataclasses

    from jaxsss.export.support import medium_arrays
    from jaxsss.medium import Medium

    with pytest.raises(ExportError, match=r"^\[material.sigma_a\] has 4 channels"):
        medium_arrays(Medium(np.full(4, 0.1), np.full(4, 1.0), 1.3, None))
    scene = load_scene(REFERENCES / "skin1_sphere.toml")
    m = medium_arrays(dataclasses.replace(scene.material.medium, sigma_a=np.asarray(0.1)))
    np.testing.assert_array_equal(m["sigma_a"], [0.1, 0.1, 0.1])
    assert m["g"] == 0.0 and m["eta"] == 1.0
