"""``jaxsss profile``: values against an independent dipole formula, JSON layout, table, plots, multipole, errors."""


import numpy as np
import pytest

from tests.cli.runner import run_cli, run_json
from tests.profiles.test_dipole import paper_eq8

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


RADII = [0.0, 0.05, 1.0, 7.5, 40.0]


def independent_dipole(r, sigma_a, sigma_s_prime, eta):
    """The dipole test's NumPy transcription of Eq. 8-10, radii down the rows and channels across."""
    return paper_eq8(np.asarray(r, dtype=float)[:, None], np.asarray(sigma_a), np.asarray(sigma_s_prime), eta)


def test_dipole_json_matches_independent_formula_three_channels(capsys):
    sa, ss = [0.0021, 0.0041, 0.0071], [2.19, 2.62, 3.00]
    got = run_json(capsys, "profile", "--model", "dipole", "--sigma-a", *sa, "--sigma-s-prime", *ss, "--eta", 1.5,
                   "--r", *RADII)
    assert list(got) == ["r", "R"]
    assert got["r"] == RADII
    R = np.array(got["R"])
    assert R.shape == (len(RADII), 3)  # per radius, one value per channel
    # 1e-12: the same closed form evaluated in a different arrangement; only rounding differs.
    np.testing.assert_allclose(R, independent_dipole(RADII, sa, ss, 1.5), rtol=1e-12)


def test_single_channel_json_is_a_flat_list_per_radius(capsys):
    got = run_json(capsys, "profile", "--sigma-a", 0.05, "--sigma-s-prime", 1.2, "--eta", 1.3, "--r", *RADII)
    assert all(isinstance(x, float) for x in got["R"])
    np.testing.assert_allclose(got["R"], independent_dipole(RADII, [0.05], [1.2], 1.3)[:, 0], rtol=1e-12)


def test_material_option_matches_explicit_coefficients(capsys):
    by_name = run_json(capsys, "profile", "--material", "skin1", "--r", 0.5, 2)
    explicit = run_json(capsys, "profile", "--sigma-a", 0.032, 0.17, 0.48, "--sigma-s-prime", 0.74, 0.88, 1.01,
                        "--eta", 1.3, "--r", 0.5, 2)
    assert by_name == explicit


def test_table_has_one_row_per_radius_and_channel_columns(capsys):
    code, out, err = run_cli(capsys, "profile", "--material", "marble", "--r", *RADII)
    assert code == 0 and err == ""
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("r [mm]"))
    assert lines[header].split()[2:] == ["R[R]", "R[G]", "R[B]"]
    rows = lines[header + 1:]
    assert [float(row.split()[0]) for row in rows] == RADII
    assert "1/mm^2" in out and "nan" not in out.lower()


def test_plot_writes_png(capsys, tmp_path):
    path = tmp_path / "sub" / "dipole.png"
    code, out, err = run_cli(capsys, "profile", "--material", "marble", "--r", 0.01, 0.1, 1, 10, "--plot", path)
    assert code == 0, err
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    assert str(path) in out


@pytest.fixture
def multipole():
    # The multipole module is written in parallel with the CLI; the CLI imports it lazily.
    return pytest.importorskip("jaxsss.profiles.multipole")


def test_multipole_thick_slab_is_the_dipole(capsys, multipole, tmp_path):
    common = ["--sigma-a", 0.05, 0.1, 0.2, "--sigma-s-prime", 1.0, 1.5, 2.0, "--eta", 1.3, "--r", 0.1, 1, 3]
    dip = run_json(capsys, "profile", "--model", "dipole", *common)
    # 1000 mm is hundreds of diffuse mean free paths: the image pairs and T vanish below double precision.
    mp_ = run_json(capsys, "profile", "--model", "multipole", "--thickness", 1000, *common)
    assert list(mp_) == ["r", "R", "T"]
    np.testing.assert_allclose(mp_["R"], dip["R"], rtol=1e-10)
    assert np.all(np.array(mp_["T"]) < 1e-100)


def test_multipole_thin_slab_json_table_and_plot(capsys, multipole, tmp_path):
    args = ["profile", "--model", "multipole", "--material", "marble", "--thickness", 2, "--r", 0.1, 1, 5]
    got = run_json(capsys, *args)
    R, T = np.array(got["R"]), np.array(got["T"])
    assert R.shape == T.shape == (3, 3)
    assert np.all(np.isfinite(R)) and np.all(T > 0)
    expected_R, expected_T = multipole.multipole_profile(np.array([0.1, 1, 5])[:, None], _marble(), 2.0)
    np.testing.assert_allclose(R, expected_R, rtol=1e-12)
    np.testing.assert_allclose(T, expected_T, rtol=1e-12)
    path = tmp_path / "multipole.png"
    code, out, err = run_cli(capsys, *args, "--plot", path)
    assert code == 0, err
    assert out.splitlines()[1].split()[2:] == ["R[R]", "R[G]", "R[B]", "T[R]", "T[G]", "T[B]"]
    assert path.read_bytes()[:8] == PNG_SIGNATURE


def _marble():
    from jaxsss.data import material_medium

    return material_medium("marble")


USER_ERRORS = {
    "multipole_without_thickness": (["--model", "multipole", "--material", "marble", "--r", 1], "--thickness"),
    "dipole_with_thickness": (["--material", "marble", "--thickness", 2, "--r", 1], "--thickness"),
    "thickness_zero": (["--model", "multipole", "--material", "marble", "--thickness", 0, "--r", 1], "thickness=0"),
    "negative_radius": (["--material", "marble", "--r", 1, -1], "r=-1"),
    "unknown_model": (["--model", "quadpole9", "--material", "marble", "--r", 1], "quadpole9"),
    "malformed_radius": (["--material", "marble", "--r", "1mm"], "'1mm'"),
    "mismatched_channels": (["--sigma-a", 0.1, 0.2, "--sigma-s-prime", 1, 2, 3, "--eta", 1.3, "--r", 1], "channel"),
    "material_and_coefficients": (["--material", "marble", "--sigma-a", 0.1, "--r", 1], "--material"),
    "negative_sigma_a": (["--sigma-a", -0.1, "--sigma-s-prime", 1, "--eta", 1.3, "--r", 1], "sigma_a=-0.1"),
    "eta_zero": (["--sigma-a", 0.1, "--sigma-s-prime", 1, "--eta", 0, "--r", 1], "eta=0"),
    "missing_eta": (["--sigma-a", 0.1, "--sigma-s-prime", 1, "--r", 1], "--eta"),
    "missing_radii": (["--material", "marble"], "--r"),
    "unknown_material": (["--material", "jelly", "--r", 1], "jelly"),
}


@pytest.mark.parametrize("argv, fragment", USER_ERRORS.values(), ids=USER_ERRORS.keys())
def test_user_errors_give_one_line_and_exit_2(capsys, argv, fragment):
    code, out, err = run_cli(capsys, "profile", *argv)
    assert code == 2
    assert out == ""
    assert err.startswith("jaxsss: error:") and err.count("\n") == 1, err
    assert fragment in err


def test_unwritable_plot_path_is_a_user_error(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code, _, err = run_cli(capsys, "profile", "--material", "marble", "--r", 1, "--plot", blocker / "x.png")
    assert code == 2
    assert err.startswith("jaxsss: error: cannot write the plot") and err.count("\n") == 1
