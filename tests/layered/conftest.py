"""Shared small scenes for the layered tests (module-scoped: geometry once)."""

import pytest

from jaxsss.layered import parse_layers
from jaxsss.render.scene import parse_scene

SLAB = {
    "mesh": {"builtin": "slab", "width": 200.0, "depth": 200.0, "thickness": 20.0},
    "material": {"sigma_a": 0.1, "sigma_s_prime": 1.0},
    "light": [
        {"type": "point", "position": [30.0, -40.0, 60.0], "intensity": 1e4},
        {"type": "directional", "direction": [-1.0, 0.3, -1.0], "intensity": 2.0},
    ],
    "camera": {"position": [0.0, -60.0, 80.0], "look_at": [0.0, 0.0, 10.0], "fov_deg": 10.0, "resolution": [5, 4]},
}


def slab_spec(texture: dict, **knobs):
    return parse_layers({"preset": "fish", "tile": [10.0, 10.0], "texture": texture, **knobs}, path="<test>")


@pytest.fixture(scope="session")
def slab_scene():
    return parse_scene(SLAB)


CONSTANT = {"procedural": "constant", "thickness": [0.3, 0.4, 1.0]}
VEINS = {"procedural": "veins", "thickness": [0.3, 0.2, 1.0], "vein_depth": 0.5, "size": 64, "seed": 2}
