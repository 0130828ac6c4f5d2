"""The renderer end to end on small scenes: energy against the closed-form Rd, hierarchical -> direct as eps -> 0,
the plan's shortcuts within tolerance, shapes, and gradients of the image in the material."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.render import make_plan, parse_scene, prepare, render
from jaxsss.render.radiance import F_dt_external
from tests.gradcheck import assert_grad_matches_fd


def _scene_dict(mesh=None, *, material=None, lights=None, camera=None, render_opts=None, occluders=None):
    data = {
        "mesh": mesh or {"builtin": "sphere", "radius": 5.0, "subdivisions": 4},
        "material": material or {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0], "eta": 1.3},
        "light": lights or [{"type": "directional", "direction": [0.3, 0.2, -1.0], "intensity": 1.0},
                            {"type": "point", "position": [-20.0, 5.0, 10.0], "intensity": [300.0, 250.0, 200.0]}],
        "camera": camera or {"position": [0.0, -30.0, 10.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                             "resolution": [24, 24]},
        "render": {"density": 0.5, **(render_opts or {})},
    }
    if occluders:
        data["occluder"] = occluders
    return data


def _scene(*args, **kwargs):
    return parse_scene(_scene_dict(*args, **kwargs), path="<test>")


@pytest.fixture(scope="module")
def sphere():
    return _scene()


def test_flat_slab_under_uniform_light_gives_closed_form_rd():
    # A slab 15 l_d wide under uniform normal irradiance E = 1: far from its edges M_o = F_t(1) E Rd (Eq. 15), and
    # the radiance seen from above is F_t(1) M_o / (pi F_dt,ext). At the paper's density, stratified samples and the
    # near-field split keep the pixel-to-pixel scatter near 0.6% (8-17% with plain point sums of Poisson-disk
    # samples); the mean over the patch is within 0.1%.
    scene = _scene(
        mesh={"builtin": "slab", "width": 60.0, "depth": 60.0, "thickness": 10.0},
        material={"sigma_a": 0.01, "sigma_s_prime": 2.0, "eta": 1.3},
        lights=[{"type": "directional", "direction": [0.0, 0.0, -1.0], "intensity": 1.0}],
        camera={"position": [0.0, 0.0, 200.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_deg": 2.0,
                "resolution": [8, 8]},
        render_opts={"density": 1.0, "eps": 0.01, "single_scattering": "off"},
    )
    medium = scene.material.medium
    f_t = 1.0 - float(jaxsss.fresnel_reflectance(1.3, 1.0))
    m_o = f_t * np.asarray(jaxsss.medium_total_diffuse_reflectance(medium))[0]
    expect = f_t * m_o / (np.pi * float(F_dt_external(1.3)))
    for method in ("hierarchical", "direct"):
        img = render(scene, method=method, bssrdf="dipole").image[..., 0]  # Eq. 15 is the dipole's
        assert abs(img.mean() / expect - 1) < 0.005, (method, img.mean() / expect)
        assert img.std() / img.mean() < 0.015, (method, img.std() / img.mean())


def test_hierarchical_converges_to_direct(sphere):
    direct = render(sphere, method="direct", bssrdf="dipole").image
    errors = []
    for eps in (2.0, 0.5, 0.05, 1e-6):
        img = render(sphere, method="hierarchical", eps=eps, bssrdf="dipole").image
        lit = direct > 0
        errors.append(float(np.sqrt(np.mean(((img - direct)[lit] / direct[lit]) ** 2))))
    assert errors[-1] < 1e-10, errors
    assert errors[0] > errors[1] > errors[2] >= errors[3], errors
    assert errors[2] < 1e-3, errors


def test_report_and_shapes(sphere):
    res = render(sphere, resolution=(20, 12), bssrdf="dipole")  # the report's shape, not the kernel
    assert res.image.shape == (12, 20, 3)
    assert np.isfinite(res.image).all() and (res.image >= 0).all()
    r = res.report
    for key in ("seconds_total", "timings", "n_samples", "interactions_per_point_mean", "interactions_per_point_max",
                "plan", "image"):
        assert key in r
    assert {"pass1_irradiance", "camera_rays", "octree", "interactions", "pass2_compile", "pass2_sum"} <= set(
        r["timings"])
    assert r["n_shaded_points"] > 0 and r["interactions_per_point_max"] >= r["interactions_per_point_mean"]
    assert res.image[0, 0].sum() == 0  # the corner misses the sphere: background


def test_plan_decisions():
    sphere_plan = make_plan(_scene())
    assert not sphere_plan.shadows and not sphere_plan.indirect  # convex and alone
    teapot = _scene(mesh={"builtin": "teapot", "size": 20.0, "resolution": 6})
    assert make_plan(teapot).shadows  # not convex: it can shadow itself
    floor = {"builtin": "slab", "width": 60.0, "depth": 60.0, "thickness": 1.0, "translate": [0.0, 0.0, -6.0]}
    with_floor = make_plan(_scene(occluders=[floor]))
    assert with_floor.shadows and with_floor.indirect
    grey = make_plan(_scene(material={"sigma_a": 0.01, "sigma_s_prime": 2.0}))
    assert grey.shared_channel
    assert not make_plan(_scene()).shared_channel
    text = sphere_plan.explain()
    assert "shadow rays" in text and "single scattering" in text and len(text.splitlines()) == len(sphere_plan.items)
    forced = make_plan(_scene(render_opts={"shadows": "on", "single_scattering": "off"}))
    assert forced.shadows and not forced.single_scattering


def test_leaving_terms_out_stays_within_tolerance():
    # Cut-off radius and single scattering: the plan's image differs from the full one by less than the tolerance.
    tol = 0.05
    material = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0], "eta": 1.3, "g": 0.95}
    scene = _scene(mesh={"builtin": "sphere", "radius": 15.0, "subdivisions": 4}, material=material,
                   camera={"position": [0.0, -70.0, 20.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 30.0,
                           "resolution": [20, 20]},
                   render_opts={"tolerance": tol, "density": 0.3, "eps": 0.01})
    plan = make_plan(scene)
    assert plan.r_cut is not None and not plan.single_scattering, plan.explain()
    planned = render(scene).image
    full_scene = _scene(mesh={"builtin": "sphere", "radius": 15.0, "subdivisions": 4}, material=material,
                        camera={"position": [0.0, -70.0, 20.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 30.0,
                                "resolution": [20, 20]},
                        render_opts={"tolerance": tol, "density": 0.3, "eps": 0.01, "single_scattering": "on"})
    prepared, _, _ = prepare(full_scene, cutoff=False)
    full = np.asarray(prepared.image(full_scene.material.medium))
    # The tolerance is relative to the image's peak, per channel.
    assert np.max(np.abs(planned - full) / full.max(axis=(0, 1))) < tol


def test_image_gradient_matches_finite_differences(sphere):
    prepared, _, _ = prepare(sphere, resolution=(8, 8), share_channels=False, bssrdf="dipole")

    def loss(theta):
        medium = jaxsss.Medium(jnp.exp(theta[:3]), jnp.exp(theta[3:]), 1.3)
        return jnp.sum(prepared.image(medium) ** 2)

    theta = jnp.log(jnp.array([0.05, 0.1, 0.2, 1.05, 1.5, 2.0]))
    assert_grad_matches_fd(loss, theta, rtol=1e-5)


def test_fit_image_recovers_material(sphere):
    from fitting import fit_image

    truth = sphere.material.medium
    # A noise-free target from the same geometry (and no material-dependent shortcuts: no cut-off radius).
    target = np.asarray(prepare(sphere, cutoff=False, share_channels=False, bssrdf="dipole")[0].image(truth))
    fit = fit_image(sphere, target, max_pixels=None, bssrdf="dipole")
    assert fit.converged, fit.message
    assert not any("couples the channels" in w for w in fit.warnings), fit.warnings  # the per-channel Jacobian
    np.testing.assert_allclose(fit.sigma_a, truth.sigma_a, rtol=1e-3)
    np.testing.assert_allclose(fit.sigma_s_prime, truth.sigma_s_prime, rtol=1e-3)


def test_texture_scales_the_irradiance_samples(tmp_path):
    import colour
    from PIL import Image

    Image.fromarray(np.full((8, 8, 3), 188, dtype=np.uint8)).save(tmp_path / "grey.png")
    base = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0], "eta": 1.3}
    plain = _scene(material=base)
    textured = parse_scene({**_scene_dict(), "material": {**base, "texture": "grey.png"}}, path="<test>",
                           base_dir=tmp_path)
    medium = plain.material.medium
    a = np.asarray(prepare(plain, resolution=(8, 8), bssrdf="dipole")[0].exitance(medium))
    b = np.asarray(prepare(textured, resolution=(8, 8), bssrdf="dipole")[0].exitance(medium))
    np.testing.assert_allclose(b, a * float(colour.cctf_decoding(188 / 255, function="sRGB")), rtol=1e-12)


def test_indirect_bounce_off_a_floor_adds_light():
    floor = {"builtin": "slab", "width": 80.0, "depth": 80.0, "thickness": 1.0, "translate": [0.0, 0.0, -6.0],
             "albedo": 0.8}
    lights = [{"type": "directional", "direction": [0.0, 0.3, -1.0], "intensity": 1.0}]
    on = _scene(lights=lights, occluders=[floor])
    off = _scene(lights=lights, occluders=[floor], render_opts={"indirect": "off"})
    assert make_plan(on).indirect and not make_plan(off).indirect
    medium = on.material.medium
    m_on = np.asarray(prepare(on, resolution=(12, 12))[0].sample_flux(medium))
    m_off = np.asarray(prepare(off, resolution=(12, 12))[0].sample_flux(medium))
    assert m_on.sum() > 1.05 * m_off.sum()  # the floor lights the sphere's underside
    assert np.all(m_on >= m_off - 1e-15)


def test_light_bounced_off_the_object_itself_enters_with_its_diffuse_albedo():
    """A concave object (the open teapot) lights itself: pass 1 traces what each sample sees of the object's own lit
    surface, and the material's diffuse albedo ``rho = F_dt,ext Rd`` turns that into indirect irradiance (one bounce,
    ``Prepared.indirect_irradiance``). It is differentiable in the material, zero for a convex object, and off when
    ``[render].indirect = "off"``."""
    from jaxsss.reflectance import medium_total_diffuse_reflectance

    teapot = {"builtin": "teapot", "size": 20.0, "resolution": 6}
    lights = [{"type": "point", "position": [-30.0, -20.0, 30.0], "intensity": [300.0, 250.0, 200.0]}]
    on = prepare(_scene(mesh=teapot, lights=lights), resolution=(8, 8), bssrdf="dipole")[0]
    off = prepare(_scene(mesh=teapot, lights=lights, render_opts={"indirect": "off"}), resolution=(8, 8),
                  bssrdf="dipole")[0]
    assert on.self_indirect is not None and off.self_indirect is None and on.indirect is None
    own = np.asarray(on.self_indirect)
    assert own.shape == (on.areas.shape[0], 3) and np.all(own >= 0.0)
    assert 0.05 < np.mean(own.sum(-1) > 0) < 0.95  # the inside of the spout and body see the lit surface; the lid not
    medium = jaxsss.Medium(jnp.array([0.002, 0.004, 0.007]), jnp.array([2.2, 2.6, 3.0]), 1.3)  # marble-like
    rho = np.asarray(F_dt_external(medium.eta) * medium_total_diffuse_reflectance(medium))
    assert np.all((0.5 < rho) & (rho < 1.0))
    np.testing.assert_allclose(np.asarray(on.indirect_irradiance(medium)), rho * own, rtol=1e-12)
    # The same samples (same seed) with and without the bounce: only light is added.
    flux_on, flux_off = np.asarray(on.sample_flux(medium)), np.asarray(off.sample_flux(medium))
    assert np.all(flux_on >= flux_off - 1e-15) and flux_on.sum() > flux_off.sum()

    def total(theta):
        m = jaxsss.Medium(jnp.exp(theta[:3]), jnp.exp(theta[3:]), 1.3)
        return jnp.sum(on.sample_flux(m) - off.sample_flux(m))

    assert_grad_matches_fd(total, jnp.log(jnp.array([0.002, 0.004, 0.007, 2.2, 2.6, 3.0])), rtol=1e-5)


def test_prepare_compiles_nothing_for_a_new_resolution():
    """Geometry is host work: once a scene has been prepared, preparing it at another resolution (new shapes for
    the shaded points, their pair lists and view chords) runs no JAX compilation. Eager JAX compiles each operation, and ``jnp.asarray`` of each host array,
    anew for every new shape (17-30 ms each): before ``jaxsss._config.to_device`` and the cut test's NumPy hat
    weights that was 0.6 of the skin1 sphere's 1.0 s of ``prepare`` at a new resolution."""
    import dataclasses
    from pathlib import Path

    import jax.monitoring

    from jaxsss.render import load_scene, scene_with

    scene = load_scene(Path(__file__).resolve().parents[1] / "export" / "references" / "skin1_sphere.toml")

    def at(resolution):
        return scene_with(scene, camera=dataclasses.replace(scene.camera, resolution=resolution),
                          render=dataclasses.replace(scene.render, density=0.3))

    _, plan, _ = prepare(at((12, 12)))
    assert plan.bssrdf == "white-oblique"  # the white kernel's geometry: view chords and the cut's test
    events = []

    def listen(event, duration, **_):
        if event.startswith("/jax/core/compile/"):
            events.append(event)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        prepare(at((16, 14)))
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert events == []


def test_lights_behind_take_the_kernel_with_a_node_at_three_quarters():
    """An index-matched object lit from behind sums its light with the oblique nodes ``LIGHTS_BEHIND_MUS`` (0.75
    added: the light that crosses the object, docs/path_tracer.md); a front-lit one keeps ``KERNEL_MUS``."""
    from jaxsss.render import load_scene
    from jaxsss.render.bssrdf import KERNEL_MUS, LIGHTS_BEHIND_MUS
    from tests.export.test_compare_bssrdf import REFERENCES

    materials = Path(__file__).parents[2] / "benchmarks" / "references" / "materials"
    behind, _, _ = prepare(load_scene(materials / "chicken1_sphere_backlit.toml"), resolution=(16, 16))
    front, _, _ = prepare(load_scene(REFERENCES / "skin1_sphere.toml"), resolution=(16, 16))
    assert behind.bssrdf_exit == "multiple-current" and behind.bssrdf_mus == (1.0,) + LIGHTS_BEHIND_MUS
    assert front.bssrdf_mus == (1.0,) + KERNEL_MUS
