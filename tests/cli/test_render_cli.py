"""``jaxsss render``: outputs (PNG, NPY, EXR, JSON report), --explain, --help units, and one-line user errors."""

import json
from pathlib import Path

import numpy as np
import pytest

from tests.cli.runner import run_cli

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "sphere.toml"
    path.write_text(
        """
[mesh]
builtin = "sphere"
radius = 5.0
subdivisions = 3
[material]
name = "skin1"
[[light]]
type = "point"
position = [-20.0, -20.0, 20.0]
intensity = 800.0
[camera]
position = [0.0, -30.0, 5.0]
look_at = [0.0, 0.0, 0.0]
fov_deg = 25.0
resolution = [16, 12]
[render]
density = 0.3
"""
    )
    return path


def test_render_writes_png_npy_exr_and_report(capsys, tmp_path, small_scene):
    out = tmp_path / "img" / "sphere.png"
    report_path = tmp_path / "report.json"
    code, stdout, err = run_cli(capsys, "render", small_scene, "-o", out, "--json", report_path, "--quiet")
    assert code == 0, err
    assert out.read_bytes()[:8] == PNG_SIGNATURE
    image = np.load(out.with_suffix(".npy"))
    assert image.shape == (12, 16, 3) and np.isfinite(image).all() and image.max() > 0
    assert out.with_suffix(".exr").stat().st_size > 0
    report = json.loads(report_path.read_text())
    for key in ("seconds_total", "timings", "n_samples", "interactions_per_point_mean", "interactions_per_point_max",
                "plan", "image", "outputs"):
        assert key in report
    assert report["resolution"] == [16, 12]
    np.testing.assert_allclose(report["image"]["max"], image.max(axis=(0, 1)))
    # The light is on the camera's side: the plan notes the exit's missing azimuth and does not warn of it (the
    # thin sphere's multipole warning is printed).
    azimuth = next(i for i in report["plan"]["items"] if i["name"] == "exit azimuth")
    assert not azimuth["reason"].startswith("WARNING") and "warning: exit azimuth" not in err


def test_render_warns_when_the_light_is_behind_the_object(capsys, tmp_path, small_scene):
    """A light behind the sphere (as the camera sees it): the render still runs, and stderr says where the model is
    known to be off, even with --quiet."""
    back = tmp_path / "backlit.toml"
    back.write_text(small_scene.read_text().replace("position = [-20.0, -20.0, 20.0]", "position = [10.0, 30.0, 5.0]"))
    out = tmp_path / "b.png"
    code, stdout, err = run_cli(capsys, "render", back, "-o", out, "--method", "direct", "--resolution", 8, 6,
                                "--no-exr", "--bssrdf", "dipole", "--quiet")
    assert code == 0, err
    assert "warning: exit azimuth: light[0] is 1" in err and "degrees from the camera" in err and not stdout


def test_render_overrides_and_direct_method(capsys, tmp_path, small_scene):
    out = tmp_path / "d.png"
    code, stdout, err = run_cli(capsys, "render", small_scene, "-o", out, "--method", "direct", "--resolution", 8, 6,
                                "--no-exr", "--bssrdf", "dipole")
    assert code == 0, err
    assert np.load(out.with_suffix(".npy")).shape == (6, 8, 3)
    assert not out.with_suffix(".exr").exists()
    assert "shaded points" in stdout


def test_explain_prints_the_plan(capsys, small_scene):
    code, out, err = run_cli(capsys, "render", small_scene, "--explain")
    assert code == 0, err
    assert "shadow rays" in out and "convex mesh alone" in out and "single scattering" in out
    # skin1 at its table eta 1.3: the white Monte Carlo family covers it (no tables to make), oblique nodes from the
    # nearest tabulated pair's ratio.
    assert "bssrdf: white-oblique" in out and "ratio of (g=0, n=1.33)" in out and "make_white_tables" not in out


def test_every_example_has_a_plan(capsys):
    for path in sorted(EXAMPLES.glob("*.toml")):
        code, out, err = run_cli(capsys, "render", path, "--explain")
        assert code == 0, (path, err)


def test_help_states_units(capsys):
    with pytest.raises(SystemExit):
        run_cli(capsys, "render", "--help")
    out = capsys.readouterr().out
    assert "mm" in out and "1/mm" in out and "W/sr" in out and "sr" in out


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--eps", "-1"], "--eps"),
        (["--resolution", "0", "4"], "--resolution"),
        (["--method", "nope"], "method"),
        (["--method", "cached", "--bssrdf", "white"], "--bssrdf applies to --method hierarchical / direct"),
    ],
)
def test_bad_options_are_one_line_errors(capsys, small_scene, argv, needle):
    code, out, err = run_cli(capsys, "render", small_scene, *argv)
    assert code == 2 and out == ""
    assert err.startswith("jaxsss: error:") and err.count("\n") == 1 and needle in err


def test_white_kernel_outside_the_family_is_a_one_line_error(capsys, tmp_path, small_scene):
    scene = tmp_path / "eta2.toml"
    scene.write_text(small_scene.read_text().replace('name = "skin1"', 'name = "skin1"\neta = 2.0'))
    code, out, err = run_cli(capsys, "render", scene, "--bssrdf", "white", "--explain")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "bssrdf='white': eta=2 is outside the white Monte Carlo family's range [1, 1.6]" in err


def test_bad_scene_file_names_file_and_key(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[mesh]\nbuiltin = "sphere"\n[material]\nsigma_a = -0.1\nsigma_s_prime = 1.0\n'
                   '[[light]]\ntype = "point"\nposition = [0, 0, 10]\nintensity = 1.0\n'
                   '[camera]\nposition = [0, -10, 0]\nlook_at = [0, 0, 0]\n')
    code, out, err = run_cli(capsys, "render", bad, "--explain")
    assert code == 2 and err.count("\n") == 1
    assert "bad.toml" in err and "material.sigma_a" in err and "-0.1" in err
    code, out, err = run_cli(capsys, "render", tmp_path / "missing.toml")
    assert code == 2 and "missing.toml" in err


def test_cached_method_with_debug_images(capsys, tmp_path, small_scene):
    out = tmp_path / "c.png"
    report_path = tmp_path / "c.json"
    code, stdout, err = run_cli(capsys, "render", small_scene, "-o", out, "--method", "cached", "--cache-error", 0.2,
                                "--debug-images", "--json", report_path, "--no-exr")
    assert code == 0, err
    for name in ("c.png", "c_caches.png", "c_gradient.png", "c_variance.png"):
        assert (tmp_path / name).read_bytes()[:8] == PNG_SIGNATURE
    report = json.loads(report_path.read_text())
    assert report["method"] == "cached" and report["n_caches"] > 0 and 0 < report["cache_ratio"] <= 1
    assert "caches (" in stdout
    code, _, err = run_cli(capsys, "render", small_scene, "--method", "cached", "--cache-error", 0)
    assert code == 2 and "--cache-error" in err


def test_cached_explain_reports_the_cache_ratio(capsys, small_scene):
    code, stdout, err = run_cli(capsys, "render", small_scene, "--method", "cached", "--cache-error", 0.5,
                                "--cache-always", "--explain", "--resolution", 12, 12)
    assert code == 0, err
    line = next(x for x in stdout.splitlines() if "irradiance caches" in x)
    assert "cache ratio" in line and "silhouettes" in line and "where the light varies" in line


def _layered_scene(tmp_path, diffusion: str) -> Path:
    text = (EXAMPLES / "layered_veins.toml").read_text()
    text = text.replace("[layers]\n", f'[layers]\ndiffusion = "{diffusion}"\n', 1).replace("size = 256", "size = 64")
    text += "\n[render]\nmax_samples = 3000  # the diffusion term's samples: enough for a 16 x 12 image\n"
    path = tmp_path / f"layered_{diffusion}.toml"
    path.write_text(text)
    return path


def test_layered_method_explain_and_render(capsys, tmp_path):
    scene = _layered_scene(tmp_path, "auto")
    code, stdout, err = run_cli(capsys, "render", scene, "--method", "layered", "--explain")
    assert code == 0, err
    assert "+ ray marching" in stdout and "- outer-layer diffusion" in stdout and "reduced mean free paths" in stdout
    out = tmp_path / "l.png"
    code, stdout, err = run_cli(capsys, "render", scene, "--method", "layered", "--samples", 8, "--resolution", 24,
                                18, "-o", out, "--no-exr", "--json", tmp_path / "l.json")
    assert code == 0, err
    assert out.read_bytes()[:8] == PNG_SIGNATURE
    report = json.loads((tmp_path / "l.json").read_text())
    assert report["method"] == "layered" and report["samples"] == 8 and "diffusion" not in report
    assert [i["name"] for i in report["plan"]["items"]] == ["ray marching", "outer-layer diffusion"]


def test_layered_method_adds_the_forced_diffusion_term(capsys, tmp_path):
    off, on = _layered_scene(tmp_path, "off"), _layered_scene(tmp_path, "on")
    images = {}
    for path in (off, on):
        out = tmp_path / f"{path.stem}.png"
        code, _, err = run_cli(capsys, "render", path, "--method", "layered", "--samples", 4, "--resolution", 16, 12,
                               "-o", out, "--no-exr", "--quiet")
        assert code == 0, err
        images[path.stem] = np.load(out.with_suffix(".npy"))
    off_img, on_img = images["layered_off"], images["layered_on"]
    obj = np.any(off_img != np.array([0.003, 0.003, 0.004]), axis=-1)  # not the scene's background
    assert obj.sum() > 20
    assert np.all(on_img[obj] >= off_img[obj]) and on_img[obj].sum() > 1.5 * off_img[obj].sum()  # only adds light
    np.testing.assert_array_equal(on_img[~obj], off_img[~obj])


def test_layered_method_needs_a_layers_table(capsys, small_scene):
    code, _, err = run_cli(capsys, "render", small_scene, "--method", "layered")
    assert code == 2 and "[layers]" in err and err.count("\n") == 1


def test_photon_method_explain_and_render(capsys, tmp_path):
    scene = EXAMPLES / "photon_blocker.toml"
    code, stdout, err = run_cli(capsys, "render", scene, "--method", "photon", "--photons", 2000, "--resolution", 16,
                                12, "--explain", "--quiet")
    assert code == 0, err
    assert "+ volumetric shadows" in stdout and "blocker(s)" in stdout and "+ multipole" in stdout
    out = tmp_path / "p.png"
    code, stdout, err = run_cli(capsys, "render", scene, "--method", "photon", "--photons", 2000, "--resolution", 16,
                                12, "-o", out, "--no-exr", "--json", tmp_path / "p.json")
    assert code == 0, err
    assert out.read_bytes()[:8] == PNG_SIGNATURE and "2000 photons" in stdout
    report = json.loads((tmp_path / "p.json").read_text())
    assert report["method"] == "photon" and report["n_photons"] == 2000 and report["n_pairs_blocked"] > 0
    img = np.load(out.with_suffix(".npy"))
    assert img.shape == (12, 16, 3) and np.isfinite(img).all() and img.min() >= 0 and img.max() > 0


def test_photon_method_rejects_bad_photon_counts(capsys):
    code, _, err = run_cli(capsys, "render", EXAMPLES / "photon_blocker.toml", "--method", "photon", "--photons", 0)
    assert code == 2 and "--photons 0" in err and "[1, inf)" in err and err.count("\n") == 1
