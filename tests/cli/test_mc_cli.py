"""``jaxsss mc``: JSON keys and values against the engine, the CSV profile, the table, --help, user errors."""

import numpy as np
import pytest

from jaxsss.mc import Stack, simulate
from tests.cli.runner import run_cli, run_json

SLAB = ["--sigma-a", 0.1, "--sigma-s", 0.9, "--g", 0.75, "--eta", 1.0, "--thickness", 2.0]
JSON_KEYS = {"R_specular", "R_diffuse", "R_diffuse_stderr", "T", "T_stderr", "T_unscattered", "A", "photons",
             "seconds"}


def test_json_has_the_documented_keys_and_matches_the_engine(capsys):
    got = run_json(capsys, "mc", *SLAB, "--photons", 3000, "--seed", 4)
    assert JSON_KEYS <= set(got)
    ref = simulate(Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0), 3000, seed=4)
    assert got["R_diffuse"] == ref.R_diffuse and got["T"] == ref.T and got["A"] == ref.A
    assert got["photons"] == 3000 and got["seconds"] >= got["compile_seconds"] >= 0
    assert got["devices"] == 1  # in-process: the devices the test's JAX already has
    # van de Hulst (MCML manual Table 6.1), 3 standard errors + 1e-3.
    assert abs(got["R_diffuse"] - 0.09739) <= 3 * got["R_diffuse_stderr"] + 1e-3
    assert abs(got["T"] - 0.66096) <= 3 * got["T_stderr"] + 1e-3


def test_half_space_with_mismatch_reports_specular(capsys):
    got = run_json(capsys, "mc", "--sigma-a", 0.1, "--sigma-s", 0.9, "--eta", 1.5, "--photons", 2000, "--seed", 1)
    assert got["R_specular"] == pytest.approx(0.04, abs=1e-12)
    assert got["T"] == 0.0 and got["T_unscattered"] == 0.0


def test_csv_profile(capsys, tmp_path):
    path = tmp_path / "out" / "profile.csv"
    code, out, err = run_cli(capsys, "mc", *SLAB, "--photons", 3000, "--seed", 2, "--r-max", 3, "--r-bins", 6,
                             "--angle", 20, "-o", path)
    assert code == 0, err
    text = path.read_text().splitlines()
    comments = [line for line in text if line.startswith("#")]
    assert comments and "1/mm^2" in " ".join(comments) and "angle=20 deg" in comments[0]
    header = text[len(comments)]
    assert header == "r_mm,R,R_stderr,T,T_stderr"
    data = np.loadtxt(path, delimiter=",", comments="#", skiprows=len(comments) + 1)
    assert data.shape == (6, 5)
    np.testing.assert_allclose(data[:, 0], np.linspace(0.25, 2.75, 6))
    ref = simulate(Stack.slab(0.1, 0.9, 0.75, 1.0, 2.0), 3000, seed=2, angle_deg=20.0,
                   r_edges=np.linspace(0, 3, 7))
    np.testing.assert_allclose(data[:, 1], ref.R_r, rtol=1e-15)
    np.testing.assert_allclose(data[:, 3], ref.T_r, rtol=1e-15)
    assert str(path) in out


def test_half_space_csv_has_no_T_columns(capsys, tmp_path):
    path = tmp_path / "p.csv"
    code, _, err = run_cli(capsys, "mc", "--sigma-a", 0.1, "--sigma-s", 1.0, "--eta", 1.3, "--photons", 1000,
                           "--r-max", 2, "--r-bins", 4, "-o", path, "--json")
    assert code == 0, err
    assert "r_mm,R,R_stderr" in path.read_text().splitlines()


def test_split_length_measures_the_far_field(capsys, tmp_path):
    """--split-length (radial splitting): the CSV says the errors are batch means, and the far bins that a plain run
    of the same photons leaves empty are measured."""
    medium = ["--sigma-a", 0.3, "--sigma-s", 1.0, "--eta", 1.0, "--photons", 4000, "--seed", 3, "--r-max", 15,
              "--r-bins", 15]
    path = tmp_path / "split.csv"
    code, _, err = run_cli(capsys, "mc", *medium, "--split-length", 0.93, "-o", path, "--no-progress")
    assert code == 0, err
    text = path.read_text()
    assert "from 16 batch means (radial splitting, length 0.93 mm)" in text
    data = np.loadtxt(path, delimiter=",", comments="#", skiprows=4)
    plain = run_json(capsys, "mc", *medium, "--no-progress")
    assert np.all(data[:, 1] > 0) and np.all(data[:, 2] < 0.5 * data[:, 1])
    assert np.sum(np.asarray(plain["R"]) == 0) >= 2  # the plain run has no counts at all in the last bins


def test_table(capsys):
    code, out, err = run_cli(capsys, "mc", *SLAB, "--photons", 1000)
    assert code == 0 and err == ""
    for label in ("R_specular", "R_diffuse", "T", "unscattered", "A"):
        assert label in out
    assert "nan" not in out.lower()


def test_help_states_units(capsys):
    with pytest.raises(SystemExit) as info:
        run_cli(capsys, "mc", "--help")
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "1/mm" in out and "degrees" in out and "per mm^2" in out


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--sigma-a", -0.1, "--sigma-s", 1, "--photons", 10], "sigma_a=-0.1"),
        (["--sigma-a", 0.1, "--sigma-s", -1, "--photons", 10], "sigma_s=-1"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--g", 1, "--photons", 10], "g=1"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--eta", 0, "--photons", 10], "n=0"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--thickness", 0, "--photons", 10], "thickness=0"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 0], "--photons=0"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--angle", 95], "angle_deg=95"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "-o", "x.csv"], "--r-max"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--r-max", 0], "--r-max=0"),
        (["--sigma-a", "nan", "--sigma-s", 1, "--photons", 10], "invalid number"),
        (["--sigma-s", 1, "--photons", 10], "--sigma-a"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--split-length", 2], "needs --r-max"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--r-max", 5, "--split-length", 0], "--split-length=0"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 4, "--r-max", 5, "--split-length", 2], "[8, inf)"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--devices", 0], "--devices=0"),
        (["--sigma-a", 0.1, "--sigma-s", 1, "--photons", 10, "--devices", 99], "devices=99"),
    ],
)
def test_user_errors_give_one_line_and_exit_2(capsys, argv, fragment):
    code, out, err = run_cli(capsys, "mc", *argv)
    assert code == 2
    assert err.startswith("jaxsss: error:") and err.count("\n") == 1, err
    assert fragment in err
    assert out == ""
