"""The layered method's plan (jaxsss.layered.plan): the outer layer's diffusion term is kept or left out with a
reason, and forced by ``[layers].diffusion``; the scene plan of the other methods names the ray march."""

import pytest

from jaxsss.layered.plan import DIFFUSION_MIN_OPTICAL_DEPTH, layered_plan
from jaxsss.render import make_plan, parse_scene
from jaxsss.render.scene import SceneError
from tests.layered.conftest import SLAB, slab_spec


def _scene(material=None, layers=None):
    data = {**SLAB, "material": material or SLAB["material"]}
    if layers is not None:
        data["layers"] = layers
    return parse_scene(data)


def _decide(thickness, material=None, **knobs):
    spec = slab_spec({"procedural": "constant", "thickness": [thickness, 0.2, 1.0]}, **knobs)
    return layered_plan(_scene(material), spec, samples=7)


def test_thin_outer_layer_leaves_diffusion_out():
    # sigma_t' = 1.1 / mm: 0.3 mm is 0.33 reduced mean free paths.
    diffusion, items = _decide(0.3)
    assert not diffusion
    assert [i.name for i in items] == ["ray marching", "outer-layer diffusion"]
    assert "7 samples per view ray" in items[0].reason and "0.33 reduced mean free paths" in items[1].reason


def test_thick_outer_layer_keeps_diffusion():
    diffusion, items = _decide(1.2 * DIFFUSION_MIN_OPTICAL_DEPTH / 1.1)
    assert diffusion and items[1].included and "hierarchical dipole" in items[1].reason


def test_negligible_reflectance_leaves_diffusion_out():
    diffusion, items = _decide(5.0, material={"sigma_a": 10.0, "sigma_s_prime": 1e-4})
    assert not diffusion and "Rd < tolerance" in items[1].reason


@pytest.mark.parametrize("value, expect", [("on", True), ("off", False), (True, True), (False, False)])
def test_diffusion_forced(value, expect):
    diffusion, items = _decide(0.3 if expect else 5.0, diffusion=value)
    assert diffusion is expect and "forced" in items[1].reason


def test_bad_diffusion_value_names_the_key():
    with pytest.raises(SceneError, match="layers.diffusion"):
        slab_spec({"procedural": "constant", "thickness": [0.3, 0.2, 1.0]}, diffusion="sometimes")


def test_scene_plan_names_the_ray_march():
    plain = {i.name: i for i in make_plan(_scene()).items}["ray marching"]
    assert not plain.included and "no [layers]" in plain.reason
    layers = {"preset": "fish", "texture": {"procedural": "constant", "thickness": [0.3, 0.2, 1.0]}}
    layered = {i.name: i for i in make_plan(_scene(layers=layers)).items}["ray marching"]
    assert not layered.included and "--method layered" in layered.reason
