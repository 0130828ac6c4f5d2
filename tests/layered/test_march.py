"""The march against the exact reference on a flat slab, convergence in N, no retracing."""

import equinox as eqx
import jax
import jax.monitoring
import numpy as np
import pytest

from jaxsss.layered import march, prepare_layered, prepare_reference, reference_radiance
from jaxsss.layered.march import reduced_intensity, sample_state
from jaxsss.layered.reference import exact_entry, light_path_lengths
from jaxsss.layered.tangents import surface_frames

from .conftest import CONSTANT, VEINS, slab_spec


_reduced = eqx.filter_jit(reduced_intensity)


def _unchunk(prepared):
    return jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:])[: prepared.n_points], prepared.geom)


@pytest.fixture(scope="module")
def constant_slab(slab_scene):
    spec = slab_spec(CONSTANT)
    prepared, sg, info = prepare_layered(slab_scene, spec)
    return spec, prepared, _unchunk(prepared), info


@pytest.mark.parametrize("frac", [0.05, 0.4, 0.95])
def test_reduced_intensity_equals_exact_on_a_flat_slab(slab_scene, constant_slab, frac):
    # Flat surface, constant layers: the tangent plane and the fitted plane are the surface (K' = K), and Eq. 12's
    # mean thickness is the thickness, so the planar path lengths are exact (to rounding).
    spec, prepared, g, info = constant_slab
    t = g.length * frac
    M, _, bm, _ = sample_state(g, prepared.boundaries, t)
    L_ri, w_in, path = _reduced(spec.stack.sigma_t, prepared.boundaries, g, prepared.lights, t, M, bm)
    frames = surface_frames(slab_scene.mesh, (False, False), spec.tile)
    entry = exact_entry(info["geometry"], slab_scene.mesh, frames, prepared.lights, np.asarray(M))
    exact = light_path_lengths(prepared.boundaries, entry, np.asarray(M), n_light=16)
    assert entry.has_entry.all() and entry.visible.all()
    np.testing.assert_allclose(np.asarray(path), exact, atol=1e-12)
    tau = np.einsum("qln,nc->qlc", exact, np.asarray(spec.stack.sigma_t))
    from jaxsss.layered.lighting import lights_at

    E = np.asarray(lights_at(prepared.lights, M)[1])
    np.testing.assert_allclose(np.asarray(L_ri), E * np.exp(-tau), rtol=1e-12)


def test_vein_slab_path_lengths_differ_from_exact(slab_scene):
    # Eq. 12 averages two thickness lookups: with veins it is an approximation (so the comparison above can fail).
    spec = slab_spec(VEINS)
    prepared, _, info = prepare_layered(slab_scene, spec)
    g = _unchunk(prepared)
    t = g.length * 0.8
    M, _, bm, _ = sample_state(g, prepared.boundaries, t)
    _, _, path = _reduced(spec.stack.sigma_t, prepared.boundaries, g, prepared.lights, t, M, bm)
    frames = surface_frames(slab_scene.mesh, (False, False), spec.tile)
    entry = exact_entry(info["geometry"], slab_scene.mesh, frames, prepared.lights, np.asarray(M))
    exact = light_path_lengths(prepared.boundaries, entry, np.asarray(M), n_light=128)
    assert np.abs(np.asarray(path) - exact).max() > 1e-3


def test_march_converges_to_reference_as_n_grows(slab_scene, constant_slab):
    spec, prepared, g, info = constant_slab
    frames = surface_frames(slab_scene.mesh, (False, False), spec.tile)
    ref = prepare_reference(info["geometry"], slab_scene.mesh, frames, prepared.boundaries, g, prepared.lights,
                            np.asarray(g.length), n_view=512, n_light=8)
    R = np.asarray(reference_radiance(spec.stack, ref))
    assert np.all(R > 0)
    errs = []
    for n in (10, 40, 160):
        A = np.asarray(march(spec.stack, prepared.boundaries, g, prepared.lights, n))
        errs.append(np.sqrt(np.mean((A - R) ** 2) / np.mean(R**2)))
    # Errors fall at least 2x per 4x samples (first order at the layer boundaries, second inside a layer); the
    # finest is within 0.5% (the reference's own quadrature error is ~1e-4).
    assert errs[0] > 2 * errs[1] > 4 * errs[2]
    assert errs[2] < 5e-3


def test_second_frame_does_not_recompile(slab_scene):
    spec = slab_spec(CONSTANT, samples=8)
    prepared, _, _ = prepare_layered(slab_scene, spec)
    events = []

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            events.append(event)

    jax.block_until_ready(prepared.image(spec.stack))
    other = jax.block_until_ready(spec.stack.with_layer_sigma_s(0, 1.7))  # (its eager ops compile on their own)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        jax.block_until_ready(prepared.image(other))
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert events == []
