"""The example scene renders; gradients against finite differences; recovering one layer's sigma_s from an image."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from jaxsss.layered import load_layered_scene, prepare_layered, prepare_reference, reference_radiance, render_layered
from jaxsss.layered.tangents import surface_frames

from ..gradcheck import assert_grad_matches_fd
from .conftest import VEINS, slab_spec

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "layered_veins.toml"


def test_example_scene_renders():
    scene, spec = load_layered_scene(EXAMPLE)
    assert len(scene.lights) == 3 and spec.stack.names == ("dermis", "blood", "organs")
    res = render_layered(scene, spec, samples=12, resolution=(40, 30))
    img = res.image
    assert img.shape == (30, 40, 3) and np.all(np.isfinite(img))
    hit = np.zeros(30 * 40, bool)
    hit[np.asarray(res.prepared.state.march.pixel)] = True
    ss = res.single_scattering.reshape(-1, 3)
    assert np.all(ss[~hit] == 0) and np.all(ss[hit] >= 0)
    assert np.mean(ss[hit].sum(axis=1) > 0) > 0.8  # lit almost everywhere with lights front, beneath, behind
    assert res.report["samples"] == 12 and res.report["n_shaded_points"] == int(hit.sum())


@pytest.fixture(scope="module")
def vein_slab(slab_scene):
    spec = slab_spec(VEINS, samples=12)
    prepared, _, info = prepare_layered(slab_scene, spec)
    return spec, prepared, info


def test_image_gradient_matches_finite_differences(vein_slab):
    spec, prepared, _ = vein_slab

    def f(x):  # blood sigma_s (R) and dermis sigma_t (G)
        s = spec.stack.replace(sigma_s=spec.stack.sigma_s.at[1, 0].set(x[0]),
                               sigma_t=spec.stack.sigma_t.at[0, 1].set(x[1]))
        return jnp.sum(prepared.image(s) ** 2) * 1e4

    assert_grad_matches_fd(f, jnp.array([6.0, 1.6]), rtol=1e-6)


def test_reference_gradient_matches_finite_differences(slab_scene, vein_slab):
    spec, prepared, info = vein_slab
    g = jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[: prepared.n_points], prepared.geom)
    frames = surface_frames(slab_scene.mesh, (False, False), spec.tile)
    ref = prepare_reference(info["geometry"], slab_scene.mesh, frames, prepared.boundaries, g, prepared.lights,
                            np.asarray(g.length), n_view=32, n_light=8)

    def f(x):
        s = spec.stack.replace(sigma_s=spec.stack.sigma_s.at[2, 2].set(x[0]), g=spec.stack.g.at[0, 0].set(x[1]))
        return jnp.sum(reference_radiance(s, ref)) * 1e2

    assert_grad_matches_fd(f, jnp.array([2.0, 0.25]), rtol=1e-6)


def test_recover_one_layer_sigma_s_from_a_rendered_image(vein_slab):
    spec, prepared, _ = vein_slab
    truth = jnp.array([6.0, 3.0, 2.0])  # blood, Table 1
    target = prepared.image(spec.stack)

    def residual(x, _):
        s = spec.stack.replace(sigma_s=spec.stack.sigma_s.at[1].set(x),
                               sigma_t=spec.stack.sigma_t.at[1].set(jnp.maximum(spec.stack.sigma_t[1], x)))
        return ((prepared.image(s) - target) * 1e3).reshape(-1)

    sol = optx.least_squares(residual, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12), jnp.array([4.0, 2.0, 1.5]),
                             max_steps=100)
    assert sol.result == optx.RESULTS.successful
    np.testing.assert_allclose(sol.value, truth, rtol=1e-6)
