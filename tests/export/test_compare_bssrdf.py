"""jaxsss's default renderer against the committed Mitsuba reference (tests/export/references/skin1_sphere): a test
that fails when the image error grows.

The scene: skin1 (Jensen 2001) on a 20 mm sphere, eta = 1, g = 0, one point light, 64 x 64; the reference is
Mitsuba 3's volpathmis at 8192 spp (1.1-1.9% per-pixel noise; its .json sidecar). The default kernel for this medium
is ``white-oblique`` (jaxsss.render.bssrdf). Goals of issue 17: mare_lit <= 5% per channel, <= 15% in the terminator
band, summed radiance within 3%. Achieved (2026-11-23, the default's two oblique nodes): mare_lit 0.057 / 0.043 /
0.044, band 0.100 / 0.116 / 0.142, sum ratio 0.966 / 0.991 / 1.008 (with four nodes: 0.061 / 0.045 / 0.043, band
0.101 / 0.117 / 0.144, sums 0.960 / 0.981 / 0.995). Met: mare_lit in G and B, the band, the sums in G and B. Missed:
mare_lit in R by 0.7 points, the R sum by 0.4 points. Where the goal is met the test asserts the goal; where it is
missed, the worse of the two achieved levels plus about 10% (the render is deterministic: the margin is for platform
rounding and future table regeneration, not noise). The dipole plus single scattering (the old kernel) fails every
bound: 0.138 / 0.181 / 0.225, band 0.28-0.38, sums 1.12-1.23.
"""

from pathlib import Path

import numpy as np
import pytest

from jaxsss.export.compare import compare_images, pixel_geometry
from jaxsss.render import load_scene, render

REFERENCES = Path(__file__).parent / "references"
MARE_LIT_MAX = (0.067, 0.05, 0.05)  # R: achieved 0.057-0.061 + 10%; G, B: the goal
BAND_MAX = (0.15, 0.15, 0.15)  # the goal (achieved 0.101, 0.117, 0.144)
SUM_TOL = (0.045, 0.03, 0.03)  # R: achieved 3.4-4.0% + 10%; G, B: the goal (0.9%, 0.8%)


@pytest.fixture(scope="module")
def skin1():
    scene = load_scene(REFERENCES / "skin1_sphere.toml")
    data = np.load(REFERENCES / "skin1_sphere.npz")
    return scene, data["image"].astype(np.float64), data["coverage"].astype(np.float64), pixel_geometry(scene)


def test_default_render_is_within_the_achieved_error_of_the_path_tracer(skin1):
    scene, ref, coverage, pixels = skin1
    result = render(scene)
    assert result.report["plan"]["bssrdf"] == "white-oblique"
    m = compare_images(result.image, ref, pixels, coverage=coverage)
    assert np.all(np.array(m["mare_lit"]) <= MARE_LIT_MAX), m["mare_lit"]
    assert np.all(np.array(m["mare_band"]) <= BAND_MAX), m["mare_band"]
    assert np.all(np.abs(np.array(m["sum_ratio"]) - 1.0) <= SUM_TOL), m["sum_ratio"]


def test_marble_teapot_against_its_path_traced_reference():
    """Marble (albedo ~0.999) on the watertight teapot, eta 1, one point light; Mitsuba 16384 spp (2.2-2.5% pixel
    noise, which is part of mare_lit here). Achieved (2026-11-23, white-oblique): mare_lit 0.087 / 0.083 / 0.084,
    terminator band 0.30 / 0.34 / 0.37 (goal 0.15: missed; the band includes the spout's and handle's shadow edges),
    sums 1.016 / 1.006 / 0.995 (goal 3%: met). The old dipole + single scattering: mare_lit 0.22-0.23, sums
    1.17-1.20. Bounds: the goal where met, else the achieved level plus about 10%."""
    scene = load_scene(REFERENCES / "marble_teapot.toml")
    data = np.load(REFERENCES / "marble_teapot.npz")
    ref, coverage = data["image"].astype(np.float64), data["coverage"].astype(np.float64)
    result = render(scene)
    assert result.report["plan"]["bssrdf"] == "white-oblique"
    m = compare_images(result.image, ref, pixel_geometry(scene), coverage=coverage)
    assert np.all(np.array(m["mare_lit"]) <= 0.096), m["mare_lit"]
    assert np.all(np.array(m["mare_band"]) <= 0.41), m["mare_band"]
    assert np.all(np.abs(np.array(m["sum_ratio"]) - 1.0) <= 0.03), m["sum_ratio"]


def test_skin1_at_its_own_eta_under_a_sky_against_its_path_traced_reference():
    """skin1 at eta 1.3 (its table value) under skin1_sphere_env's sky: a pair that only the white Monte Carlo family
    covers (oblique nodes from the ratio of the tabulated n = 1.33), against a 32768-spp Mitsuba reference (924 s;
    its own noise 3.3 / 2.6 / 2.9% per pixel, part of mare_lit here). Achieved (2026-11-23): mare_lit 0.119 / 0.082 /
    0.067, sums 0.884 / 0.929 / 0.955, the same as the tabulated eta 1.4 scene (0.130 / 0.081 / 0.059, sums 0.876 /
    0.930 / 0.959). Before the family, auto fell back to the dipole plus single scattering here: mare_lit 0.102 /
    0.374 / 0.657, sums 1.120 / 1.401 / 1.661. The goals (5%, 3%) are missed under the sky (both kernels are 5-12% too
    dark, docs/path_tracer.md): the bounds are the achieved level plus about 10%, and the dipole's G and B sums fail
    them (R: 1.120, within 12.8%)."""
    scene = load_scene(REFERENCES / "skin1_sphere_env13.toml")
    data = np.load(REFERENCES / "skin1_sphere_env13.npz")
    ref, coverage = data["image"].astype(np.float64), data["coverage"].astype(np.float64)
    result = render(scene)
    plan = result.report["plan"]
    assert plan["bssrdf"] == "white-oblique"
    m = compare_images(result.image, ref, pixel_geometry(scene), coverage=coverage)
    assert np.all(np.array(m["mare_lit"]) <= (0.131, 0.09, 0.074)), m["mare_lit"]
    assert np.all(np.abs(np.array(m["sum_ratio"]) - 1.0) <= (0.128, 0.078, 0.05)), m["sum_ratio"]
    old = compare_images(render(scene, bssrdf="dipole").image, ref, pixel_geometry(scene), coverage=coverage)
    assert np.all(np.abs(np.array(old["sum_ratio"][1:]) - 1.0) > (0.078, 0.05)), old["sum_ratio"]
