"""``jaxsss fit``: JSON keys and values against the library, the table, the plot, and user errors (exit 2, one line).

The profile is written in the format of ``jaxsss mc -o`` (``#`` comments, header ``r_mm,R,R_stderr``) from the dipole
plus 2% Gaussian noise, so the fit reuses the compilation of the library tests (a dipole fit of <= 4 problems) and
needs no Monte Carlo run."""

from pathlib import Path

import numpy as np
import pytest

import fitting
import jaxsss
from tests.cli.runner import run_cli, run_json

SA, SS, ETA = 0.01, 1.5, 1.3
R_GRID = np.geomspace(0.05, 20.0, 40)
JSON_KEYS = {"sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr", "converged", "iterations",
             "seconds", "model"}


@pytest.fixture(scope="module")
def profile_csv(tmp_path_factory):
    R = np.asarray(fitting.entry_transmittance(ETA) * jaxsss.dipole_profile(R_GRID, jaxsss.Medium(SA, SS, ETA)))
    se = 0.02 * R
    data = R + se * np.random.default_rng(11).standard_normal(R.size)
    path = tmp_path_factory.mktemp("fit") / "profile.csv"
    lines = ["# jaxsss mc: sigma_a=0.01 1/mm, ... (a synthetic profile in the mc format)",
             "# r_mm: bin centre (mm); R: per incident photon per mm^2 (1/mm^2); *_stderr: standard errors",
             "r_mm,R,R_stderr"]
    lines += [f"{float(r)!r},{float(y)!r},{float(s)!r}" for r, y, s in zip(R_GRID, data, se)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_json_has_the_documented_keys_and_matches_the_library(capsys, profile_csv):
    got = run_json(capsys, "fit", profile_csv, "--eta", ETA)
    assert JSON_KEYS <= set(got)
    ref = fitting.fit_profile(fitting.read_profile(profile_csv), eta=ETA, warn=False)
    for key in ("sigma_a", "sigma_s_prime", "sigma_a_stderr", "sigma_s_prime_stderr"):
        assert got[key] == pytest.approx(float(getattr(ref, key)), rel=1e-12)
    assert got["converged"] is True and got["model"] == "dipole" and got["seconds"] > 0 and got["iterations"] >= 1
    # 2% noise: the truth within 4 standard errors.
    assert abs(got["sigma_a"] - SA) < 4 * got["sigma_a_stderr"]
    assert abs(got["sigma_s_prime"] - SS) < 4 * got["sigma_s_prime_stderr"]
    assert got["r_min"] >= 1.0 / (SA + SS) * 0.5 and got["range_reason"].startswith("default: r >= l_u")


def test_table_and_plot(capsys, profile_csv, tmp_path):
    png = tmp_path / "plots" / "fit.png"
    code, out, err = run_cli(capsys, "fit", profile_csv, "--eta", ETA, "--r-min", 0.5, "--plot", png)
    assert code == 0, err
    assert "sigma_a [1/mm]" in out and "user: r_min = 0.5 mm" in out and "converged" in out and str(png) in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_not_converged_exits_1_and_says_so(capsys, profile_csv):
    code, out, err = run_cli(capsys, "fit", profile_csv, "--eta", ETA, "--max-steps", 1)
    assert code == 1
    assert "NOT CONVERGED" in out and "did not converge" in err


@pytest.mark.parametrize(
    "body, args, match",
    [
        (None, ["--eta", "-1"], "eta=-1"),
        (None, ["--eta", ETA, "--model", "tripole"], "invalid choice: 'tripole'"),
        (None, ["--eta", ETA, "--model", "multipole"], "needs thickness"),
        (None, ["--eta", ETA, "--r-min", 5, "--r-max", 1], "--r-min 5 must be below --r-max 1"),
        ("r_mm,R\n0.1,1.0\n0.2,abc\n", ["--eta", ETA], "line 3, column 2 (R): 'abc' is not a number"),
        ("r_mm,R\n0.2,1.0\n0.1,0.5\n", ["--eta", ETA], "line 3, column 1 (r_mm)"),
        ("missing", ["--eta", ETA], "cannot read the file"),
        (None, [], "--eta is required for a profile file"),
        (None, ["--eta", ETA, "--photons", 5000], "--photons applies to MCML .mco runs and to --model mc with --thickness only"),
    ],
)
def test_user_errors_exit_2_with_one_line(capsys, profile_csv, tmp_path, body, args, match):
    path = profile_csv
    if body is not None:
        path = tmp_path / "bad.csv"
        if body != "missing":
            path.write_text(body)
    code, out, err = run_cli(capsys, "fit", path, *args)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxsss: error:") and match in lines[0], err


def test_help_lists_the_models_and_solvers(capsys):
    with pytest.raises(SystemExit) as exc:
        run_cli(capsys, "fit", "--help")
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in ("dipole", "multipole", "levenberg_marquardt", "--relative", "--plot"):
        assert name in out


MCO = Path(__file__).resolve().parents[1] / "fitting" / "data" / "slab03mm_n133_g09.mco"


def test_an_mco_run_needs_no_other_argument(capsys):
    """``jaxsss fit RUN.mco --json``: the transport-accurate route (replay MC for this slab), values per free layer."""
    d = run_json(capsys, "fit", MCO, "--photons", 20_000, "--seed", 1)
    assert d["model"] == "mc" and d["method"] == "replay" and d["free_layers"] == [0]
    assert d["file"] == str(MCO) and d["simulations"] >= 2
    assert len(d["sigma_a"]) == len(d["sigma_s_prime"]) == 1
    # 2e4 photons per simulation: a loose check of the answer (the library test holds 3% at 5e4).
    assert abs(d["sigma_a"][0] / 0.1 - 1) < 0.15 and abs(d["sigma_s_prime"][0] / 2.0 - 1) < 0.05


@pytest.mark.parametrize("args, match", [
    (["--eta", "1.33"], "--eta does not apply to an MCML run"),
    (["--thickness", "0.3"], "--thickness does not apply"),
    (["--free-layers", "1"], "free_layers=(1,)"),
    (["--free-layers", "a"], "not a comma-separated list"),
    (["--photons", "10"], "--photons 10 must be >= 1000"),
    (["--model", "multipole", "--free-layers", "-2"], "outside the allowed range"),
])
def test_mco_user_errors_exit_2_with_one_line(capsys, args, match):
    code, out, err = run_cli(capsys, "fit", MCO, *args)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxsss: error:") and match in lines[0], err


@pytest.mark.parametrize("args, match", [
    (["--relative"], "--relative does not apply to --model mc with --thickness"),
    (["--r-min", "0.5"], "--r-min does not apply"),
    (["--free-layers", "0"], "applies to MCML .mco runs"),
])
def test_slab_mc_user_errors_exit_2_with_one_line(capsys, tmp_path, args, match):
    """``--model mc --thickness``: replay Monte Carlo of a slab profile; options it cannot honour are refused."""
    csv = tmp_path / "slab.csv"
    csv.write_text("r_lo_mm, r_hi_mm, Rd_per_mm2\n0, 0.1, 1.0\n0.1, 0.2, 0.5\n")
    code, out, err = run_cli(capsys, "fit", csv, "--eta", "1.33", "--g", "0.9", "--model", "mc", "--thickness", "0.3",
                             *args)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxsss: error:") and match in lines[0], err


def test_profile_fit_imports_leave_out_monte_carlo_and_image_fits():
    """Start-up (issue 18): `jaxsss fit PROFILE.csv` needs the profile fits only; ``fitting`` imports its public names
    lazily, so the Monte Carlo engine, the renderer and the image/replay fits stay unimported."""
    import subprocess
    import sys

    code = ("import sys, fitting; fitting.fit_profile, fitting.read_profile, fitting.FORWARD_MODELS; "
            "print(sorted(m for m in ('jaxsss.mc', 'jaxsss.render', 'fitting.image_fit', 'fitting.replay_fit', "
            "'fitting.mco_fit') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


@pytest.mark.parametrize("args, match", [
    (["--model", "dipole"], "--free-g needs --model mc"),
    (["--model", "mc", "--g", "0.5"], "--g does not apply with --free-g"),
    (["--model", "mc", "--relative"], "--relative does not apply with --free-g"),
])
def test_free_g_user_errors_exit_2_with_one_line(capsys, tmp_path, args, match):
    csv = tmp_path / "p.csv"
    csv.write_text("r_mm, R, R_stderr\n0.1, 1.0, 0.01\n0.2, 0.5, 0.01\n0.3, 0.3, 0.01\n0.4, 0.2, 0.01\n")
    code, out, err = run_cli(capsys, "fit", csv, "--eta", "1.33", "--free-g", *args)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxsss: error:") and match in lines[0], err
