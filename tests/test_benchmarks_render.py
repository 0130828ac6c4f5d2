"""The renderer benchmarks' --quick paths: each writes its JSON (rows with the harness schema) and PNG."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `benchmarks` is not an installed package; it runs from the repository root.
    sys.path.insert(0, str(ROOT))

from benchmarks import (
    BENCHMARKS,
    ROW_KEYS,
    render_bssrdf_sampling,
    render_cache,
    render_density,
    render_eps,
)

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


def _load(out: Path, name: str) -> dict:
    doc = json.loads((out / f"{name}.json").read_text())
    assert (out / f"{name}.png").stat().st_size > 0
    assert doc["quick"] is True and doc["benchmark"] == name
    for row in doc["rows"]:
        assert list(row)[: len(ROW_KEYS)] == list(ROW_KEYS)
        assert row["seconds"] > 0
    return doc


def test_render_benchmarks_are_registered():
    assert {"render_eps", "render_density", "render_bssrdf_sampling", "render_cache"} <= set(BENCHMARKS)


def test_fit_path_traced_views_are_the_references_lit_pixels_weighted_by_their_noise():
    """The fit benchmark's targets (its fits take minutes: run ``python -m benchmarks.fit_path_traced --quick``)."""
    import numpy as np

    from benchmarks import fit_path_traced

    assert "fit_path_traced" in BENCHMARKS
    _, target, stderr = fit_path_traced.load_view("skin1_sphere")
    with np.load(fit_path_traced.REFERENCES / "skin1_sphere.npz") as f:
        image, coverage = f["image"], f["coverage"]
    lit = target[..., 1] > 0
    assert target.shape == image.shape and 0.3 * lit.size < lit.sum() < coverage.sum()
    np.testing.assert_array_equal(target[lit], image[lit])
    assert np.all(coverage[lit] >= 0.999) and not np.any(target[~lit])
    meta = json.loads((fit_path_traced.REFERENCES / "skin1_sphere.json").read_text())
    np.testing.assert_allclose(stderr[lit], np.asarray(meta["noise_mare_lit"]) * image[lit])


def test_curvature_transport_walk_reflects_chandrasekhars_albedo_and_a_sphere_more_far_away():
    """The benchmark's transport walk (independent of the renderer): the half-space's total reflectance of a normal
    pencil beam equals Chandrasekhar's directional albedo (exact for isotropic scattering at eta 1), and its orders >= 2
    that less the exact first order; on a sphere more light comes out far from the entry than on the plane (the ratio
    the renderer's curvature term models)."""
    import numpy as np

    from benchmarks import curvature_transport as ct
    from jaxsss.render.bssrdf import directional_albedo

    edges = np.array([0.0, 1.0, 3.0, 10.0, 60.0])
    area = np.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    plane, count = ct.pencil_beam_exitance("plane", 0.05, 0.95, 20_000, seed=1, edges=edges)
    total = float(np.sum(plane * area))
    exact = float(directional_albedo(1.0, 0.95))
    assert abs(total - exact) < 0.015, (total, exact)  # ~5 standard errors at 2e4 photons
    assert count.sum() > 10_000
    # The orders >= 2 alone (min_order): Chandrasekhar's albedo less the exact first order.
    from jaxsss.render.first_order import first_order_total

    plane2, _ = ct.pencil_beam_exitance("plane", 0.05, 0.95, 20_000, seed=1, edges=edges, min_order=2)
    exact2 = exact - float(first_order_total(1.0, 0.95))
    assert abs(float(np.sum(plane2 * area)) - exact2) < 0.015, (float(np.sum(plane2 * area)), exact2)
    ratio, se, n_min, _ = ct.measured_ratio(0.061, 0.18, 16_000)
    far = (np.asarray(ct.EDGES[:-1]) >= 14.0) & (n_min >= 100)
    assert far.any() and np.all(ratio[far] - 3 * se[far] > 1.0), (ratio, se)
    assert "curvature_transport" in BENCHMARKS
    # A grazing beam cut at a 4 mm chord: as before near the entry, and beyond the chord less than the uniform
    # fraction that interacts (1 - exp(-sigma_t t) = 0.62 for ketchup's red); uncut, the same walk exactly.
    mid = 0.5 * (ct.EDGES[1:] + ct.EDGES[:-1])
    cut = ct.truncated_ratio(0.061, 0.18, 20_000, 0.1, 4.0)
    assert np.all(np.abs(cut[mid < 2.0] - 1.0) < 0.1) and np.all(cut[(mid > 6.0) & (mid < 20.0)] < 0.4), cut
    np.testing.assert_array_equal(ct.truncated_ratio(0.061, 0.18, 2_000, 0.1, np.inf), 1.0)


def test_sphere_transport_walk_conserves_light_and_finds_the_flow_at_the_terminator():
    """The whole-sphere walk of ``benchmarks/sphere_transport.py`` (independent of the renderer): without absorption and
    with every order tallied, all the light that enters leaves (the power the sphere intercepts, ``I 2 pi (1 - cos
    alpha)``, to the noise of the bins' Monte Carlo areas); with absorption, the orders >= 2 leave brighter away from
    the light than towards it at the terminator (the first azimuthal harmonic ``A1 > 0``), hardly at all facing it."""
    import numpy as np

    from benchmarks import sphere_transport as st

    light, radius = np.array([-90.0, -70.0, 50.0]), 20.0
    walk = st.sphere_walk(0.0, 1.0, radius, light, 2.0e4, 20_000, seed=3, min_order=0)
    area = st.fine_areas(radius, tuple(light))
    assert abs(area.sum() / (4.0 * np.pi * radius**2) - 1.0) < 1e-12  # every point of the sphere lies in a bin
    cone = np.sqrt(1.0 - (radius / np.linalg.norm(light)) ** 2)
    intercepted = 2.0e4 * 2.0 * np.pi * (1.0 - cone)
    inside = area > 0
    total = np.sum(walk["exitance"].sum(axis=1)[inside] * area[inside])
    assert abs(total / intercepted - 1.0) < 0.01, (total, intercepted)
    walk = st.sphere_walk(0.032, 0.74, radius, light, 2.0e4, 40_000, seed=4)
    h = walk["harmonic"]
    a1 = 2.0 * h[..., 1].sum(axis=1) / h[..., 0].sum(axis=1)  # per light band
    terminator = list(st.LIGHT_EDGES).index(-0.1)
    assert a1[terminator] > 0.2 and abs(a1[-1]) < 0.1, a1
    assert "sphere_transport" in BENCHMARKS


def test_pencil_beams_superpose_to_the_whole_sphere_walk_only_with_their_azimuth():
    """Pencil-beam walks (what the renderer's kernels and tables are fitted to) superposed over a point-lit sphere of 5
    transport lengths (albedo 0.97) against the whole sphere's walk, per light band: with each beam's first two
    azimuthal harmonics about its travel they agree within 10% everywhere (measured 0.92-1.05); by their rings alone
    (each beam's azimuthal mean) the lit centre is 20-35% too bright (1.31-1.33) and the terminator 35-40% dark: on a
    small sphere the light that enters around the lit centre leaves away from it (docs/path_tracer.md, "The lit side of
    small spheres")."""
    import numpy as np

    from benchmarks import sphere_transport as st

    light, radius = np.array([-60.0, -90.0, 50.0]), 5.0
    superposed = st.pencil_superposition(0.03, 0.97, radius, light, 1.0e4, 20_000, points=30_000, queries=30)
    walk = st.sphere_walk(0.03, 0.97, radius, light, 1.0e4, 60_000, seed=2)
    centres = 0.5 * (st.FINE_EDGES[1:] + st.FINE_EDGES[:-1])
    band = np.clip(np.searchsorted(st.LIGHT_EDGES, centres, side="right") - 1, 0, len(st.LIGHT_EDGES) - 2)
    light_out = walk["exitance"].sum(axis=1) * walk["area"]
    whole = np.array([light_out[band == b].sum() / walk["area"][band == b].sum()
                      for b in range(len(st.LIGHT_EDGES) - 1)])
    rings, harmonics = superposed[:, 0] / whole, superposed[:, 1] / whole
    assert np.all(np.abs(harmonics - 1.0) < 0.1), harmonics
    terminator = list(st.LIGHT_EDGES).index(-0.1)
    assert rings[-1] > 1.2 and rings[terminator] < 0.75, rings


def test_render_eps_quick(tmp_path):
    assert render_eps.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = _load(tmp_path, "render_eps")
    hier = [r for r in doc["rows"] if r["method"] == "hierarchical"]
    assert [r["eps"] for r in hier] == [0.2, 0.05]
    # Same irradiance samples as the direct reference; the masked render equals the full render on the subset.
    assert doc["summary"]["same_samples_all_runs"]
    assert hier[-1]["masked_vs_full_render_max_rel_diff"] < 1e-9
    # Smaller eps, smaller error (both well under a few percent on the teapot).
    assert hier[1]["error"] < hier[0]["error"] < 0.05
    assert all(r["speedup_vs_direct"] > 0 and r["mean_ciede2000"] >= 0 for r in hier)


def test_render_density_quick(tmp_path):
    assert render_density.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = _load(tmp_path, "render_density")
    swept = [r for r in doc["rows"] if r["method"] == "hierarchical"]
    assert [r["density"] for r in swept] == [0.5, 1.0]
    assert all(0 < r["error"] < 0.5 for r in swept)
    # The reference's own noise is measured with a second seed.
    assert 0 < doc["summary"]["reference_noise_estimate"] < 0.5


def test_render_bssrdf_sampling_quick(tmp_path):
    assert render_bssrdf_sampling.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = _load(tmp_path, "render_bssrdf_sampling")
    s = doc["summary"]
    assert s["equal_time_K"] >= 1 and s["speedup_at_equal_error"] > 0
    mc = [r for r in doc["rows"] if r["method"] == "bssrdf_sampling" and "noise_relative_rms" in r]
    # Monte Carlo noise falls with K (about 1/sqrt(K)).
    assert mc[-1]["noise_relative_rms"] < mc[0]["noise_relative_rms"]


def test_bssrdf_sampling_estimator_is_unbiased_on_a_lit_plane():
    """The disk-projection estimator against the exact integral on a plane under a directional light."""
    import math

    import numpy as np

    import jaxsss
    from jaxsss.render import parse_scene
    from jaxsss.render.radiance import disc_integral
    from jaxsss.render.rays import SceneGeometry

    scene = parse_scene({
        "mesh": {"builtin": "slab", "width": 300.0, "depth": 300.0, "thickness": 62.0, "subdivisions": 2},
        "material": {"name": "marble"},
        "light": [{"type": "directional", "direction": [0.0, 0.0, -1.0], "intensity": 1.0}],
        "camera": {"position": [0.0, -100.0, 100.0], "look_at": [0.0, 0.0, 0.0], "resolution": [8, 8]},
    })
    geometry = SceneGeometry(scene.mesh)
    top = scene.mesh.bounds[1][2]
    x = np.array([[0.0, 0.0, top], [20.0, -10.0, top]])
    n = np.array([[0.0, 0.0, 1.0]] * 2)
    medium = scene.material.medium
    r_max = math.log(1.0 / render_bssrdf_sampling.TOL) / float(np.min(np.asarray(medium.sigma_tr)))
    expect = (1.0 - float(jaxsss.fresnel_reflectance(medium.eta, 1.0))) * np.asarray(disc_integral(r_max, medium))
    mean, var, _ = render_bssrdf_sampling.bssrdf_exitance(scene, geometry, x, n, 4000, seed=5)
    z = (mean - expect) / np.sqrt(var)
    assert np.all(np.abs(z) < 4.5), z
    assert np.all(np.sqrt(var) / expect < 0.05)


def test_render_cache_quick(tmp_path):
    assert render_cache.main(["--quick", "--out", str(tmp_path)]) == 0
    doc = _load(tmp_path, "render_cache")
    cached = [r for r in doc["rows"] if r["method"] == "cached"]
    assert [r["a"] for r in cached] == [0.3, 1.0]
    for r in cached:
        assert 0 < r["cache_ratio"] <= 1 and r["speedup"] > 0
        assert 0 <= r["error"] <= r["max_error"] < 0.2 and r["mean_ciede2000"] >= 0


def test_equal_error_of_the_path_tracer_comparison():
    """render_vs_path_tracer's equal-error column: a path tracer whose error falls as 1/sqrt(seconds) (0.2 at 1 s,
    0.1 at 4 s) reaches 0.05 at 16 s, so a 1-s render with that error is 16x faster, by the line and by 1/sqrt."""
    from benchmarks.render_vs_path_tracer import equal_error

    mitsuba = [{"error": 0.4, "seconds": 0.25}, {"error": 0.1, "seconds": 4.0}, {"error": 0.2, "seconds": 1.0}]
    q = equal_error({"error": 0.05, "seconds": 1.0}, mitsuba)
    assert q["slope"] == pytest.approx(-0.5)
    assert q["mitsuba_seconds"] == pytest.approx(16.0) and q["ratio"] == pytest.approx(16.0)
    assert q["ratio_sqrt"] == pytest.approx(16.0)
    # A path tracer that converges slowly (slope -0.25) needs longer by the line than at 1/sqrt(spp).
    slow = equal_error({"error": 0.05, "seconds": 2.0}, [{"error": 0.2, "seconds": 1.0},
                                                           {"error": 0.2 / 2 ** 0.5, "seconds": 4.0}])
    assert slow["slope"] == pytest.approx(-0.25) and slow["ratio"] > slow["ratio_sqrt"] > 1.0
    with pytest.raises(ValueError, match="at least 2"):
        equal_error({"error": 0.05, "seconds": 1.0}, mitsuba[:1])


def test_equal_error_with_the_reference_noise_apart():
    """A path tracer measured against a reference with its own noise (0.03 / 0.02 / 0.01 per channel): its error is
    e^2 = f^2 + c^2 / seconds per channel (c 0.2 / 0.3 / 0.1). To reach 0.05 in every channel it needs
    max(0.04 / 0.0016, 0.09 / 0.0021, 0.01 / 0.0024) = 42.9 s, which the plain 1/sqrt(spp) estimate from the highest
    row understates (it reads the floor as convergence still to come). Under one channel's noise it cannot be
    measured to get there."""
    import numpy as np

    from benchmarks.render_vs_path_tracer import equal_error

    f, c = np.array([0.03, 0.02, 0.01]), np.array([0.2, 0.3, 0.1])
    rows = []
    for t in (1.0, 4.0, 16.0):
        mare = np.sqrt(f ** 2 + c ** 2 / t)
        rows.append({"error": mare.max(), "mare_lit": mare.tolist(), "seconds": t})
    q = equal_error({"error": 0.05, "seconds": 0.5}, rows, f)
    assert q["mitsuba_seconds_floor"] == pytest.approx(0.09 / (0.05 ** 2 - 0.02 ** 2), rel=1e-9)
    assert q["ratio_floor"] == pytest.approx(q["mitsuba_seconds_floor"] / 0.5)
    assert q["mitsuba_seconds_sqrt"] < q["mitsuba_seconds_floor"]
    assert equal_error({"error": 0.025, "seconds": 0.5}, rows, f)["ratio_floor"] is None
    assert equal_error({"error": 0.05, "seconds": 0.5}, rows)["ratio_floor"] is None  # no noise given
    # A noiseless reference: the same as 1/sqrt(spp) from the highest row.
    clean = equal_error({"error": 0.05, "seconds": 0.5}, rows, [0.0, 0.0, 0.0])
    assert clean["mitsuba_seconds_floor"] == pytest.approx(clean["mitsuba_seconds_sqrt"], rel=1e-9)


def test_the_material_benchmarks_references_are_complete():
    """benchmarks/render_materials.py: every scene has its scene file, image and sidecar, at the camera's resolution
    and the spp it is listed with, and its goal follows its material's albedo (10x above 0.9, else never slower)."""
    import json

    import numpy as np

    from benchmarks.render_materials import (
        ALBEDO_GOAL,
        REFERENCE_SPP,
        REFERENCES,
        albedo,
        judge,
    )
    from benchmarks.render_vs_path_tracer import load_reference

    assert "render_materials" in BENCHMARKS
    for name, spp in REFERENCE_SPP.items():
        scene, image, coverage, meta = load_reference(name, REFERENCES)
        assert meta["spp"] == spp and meta["scene"] == f"{name}.toml"
        assert image.shape == (*scene.camera.resolution[::-1], 3) and coverage.shape == image.shape[:2]
        assert np.isfinite(image).all() and image.max() > 0 and 0 < coverage.mean() < 1
        assert len(meta["noise_mare_lit"]) == 3 and json.loads(json.dumps(meta)) == meta
        a = albedo(scene)
        assert a.shape == (3,) and ((0 < a) & (a < 1)).all()
    assert max(albedo(load_reference("chicken2_sphere", REFERENCES)[0])) > ALBEDO_GOAL
    assert judge({"ratio_floor": 12.0}, 10.0) is True and judge({"ratio_floor": 4.2}, 10.0) is False
    assert judge({"ratio_floor": None}, 10.0) is None
