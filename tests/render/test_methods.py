"""The render-method registry (jaxsss.render.methods): every registered method renders through the one driver with
the one report schema, and its images are those rendered before the registry existed.

``data/reference_images.npz`` was rendered at commit e78a740 (before the refactor) with each method's own entry
point then (``render``, ``render_cached``, ``render_photon``, ``render_layered``): the marble teapot with
``max_samples = 4000`` at 24 x 18 (hierarchical, direct) and 64 x 48 (cached, ``a = 0.3``), the milk box on its
floor at 24 x 18, the photon blocker slab with 3000 photons and the layered veins sphere with 8 samples per ray.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxsss.render import (
    METHODS,
    REPORT_KEYS,
    STAGES,
    load_scene,
    method_names,
    prepare_method,
    render,
    resolve_method,
    scene_with,
)

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = Path(__file__).parent / "data" / "reference_images.npz"
RES = (24, 18)


def _scene(name: str, **render_settings):
    scene = load_scene(ROOT / "examples" / name)
    if render_settings:
        scene = scene_with(scene, render=dataclasses.replace(scene.render, **render_settings))
    return scene


# (reference key, method, scene file, [render] overrides, resolution, options)
CASES = [
    ("hierarchical", "hierarchical", "marble_teapot.toml", {"max_samples": 4000}, RES, {}),
    ("direct", "direct", "marble_teapot.toml", {"max_samples": 4000}, RES, {}),
    ("cached", "cached", "marble_teapot.toml", {"max_samples": 4000}, (64, 48), {"error_bound": 0.3}),
    ("hierarchical_occluder", "hierarchical", "milk_box_on_floor.toml", {"max_samples": 4000}, RES, {}),
    ("photon", "photon", "photon_blocker.toml", {}, RES, {"n_photons": 3000}),
    ("layered", "layered", "layered_veins.toml", {}, RES, {"samples": 8}),
]


def test_every_builtin_method_is_registered():
    assert set(method_names()) >= {"hierarchical", "direct", "cached", "photon", "layered"}
    for name in method_names():
        entry = METHODS[name]
        assert entry.name == name and entry.summary and callable(entry.prepare)


def test_unknown_method_and_option_are_named():
    with pytest.raises(ValueError, match="'nope' is not a render method; registered: hierarchical"):
        resolve_method("nope")
    scene = _scene("marble_teapot.toml", max_samples=500)
    with pytest.raises(ValueError, match="takes no option.*n_photons.*its options: eps"):
        prepare_method(scene, "hierarchical", resolution=(4, 3), n_photons=10)


@pytest.fixture(scope="module")
def results():
    out = {}
    for key, method, name, settings, res, options in CASES:
        out[key] = render(_scene(name, **settings), method, resolution=res, **options)
    return out


def test_the_registry_walk_covers_every_method(results):
    assert {r.report["method"] for r in results.values()} == set(method_names())


@pytest.mark.parametrize("key", [c[0] for c in CASES])
def test_report_schema(results, key):
    """One schema: the shared keys, the plan as a ScenePlan dict, the end-to-end time split by stage."""
    r = results[key].report
    for k in REPORT_KEYS:
        assert k in r, f"{key}: {k} missing from the report"
    assert r["method"] == results[key].prepared.method
    assert set(r["plan"]) >= {"method", "eps", "items"} and r["plan"]["items"]
    assert r["plan"]["method"] == r["method"]
    assert set(r["seconds"]) == set(STAGES) | {"other"}
    assert all(v >= 0 for v in r["seconds"].values())
    assert sum(r["seconds"].values()) == pytest.approx(r["seconds_total"], rel=1e-9)
    assert r["seconds"]["compile"] == r["timings"]["pass2_compile"] > 0
    h, w = results[key].image.shape[:2]
    assert r["resolution"] == [w, h] and r["image"]["finite"]


@pytest.mark.parametrize("key", [c[0] for c in CASES])
def test_images_unchanged_by_the_refactor(results, key):
    """Against the images rendered before the registry: equal to float rounding (summation order changed: pass 2
    is now one jitted call instead of chunks)."""
    ref = np.load(REFERENCE)[key]
    img = results[key].image
    assert img.shape == ref.shape
    np.testing.assert_allclose(img, ref, rtol=1e-9, atol=1e-12 * float(ref.max()))


@pytest.mark.parametrize("key", ["hierarchical", "photon", "layered"])
def test_image_is_a_jax_function_of_the_medium(results, key):
    """``Preparation.image`` is differentiable in the material: the gradient of the image sum along sigma_a agrees
    with a central difference (the registry's promise to fit_image)."""
    prep = results[key].prepared
    medium = resolve_method(results[key].report["method"]).params(_scene_of(key))
    grad = jax.grad(lambda m: prep.image(m).sum())(medium)
    h = 1e-6 * float(np.max(np.asarray(medium.sigma_a)))
    plus = dataclasses.replace if False else None  # noqa: F841 (medium is an equinox module: use tree_at)
    import equinox as eqx

    def at(delta):
        return float(prep.image(eqx.tree_at(lambda m: m.sigma_a, medium, medium.sigma_a + delta)).sum())

    fd = (at(h) - at(-h)) / (2 * h)
    assert float(np.sum(np.asarray(grad.sigma_a))) == pytest.approx(fd, rel=1e-5)


def _scene_of(key):
    for k, _, name, settings, _, _ in CASES:
        if k == key:
            return _scene(name, **settings)
    raise KeyError(key)
