"""``jaxsss run``: the main job prints the Jensen 2001 table, writes the dipole-profile plot, and simulates and fits a
measurement (with fewer photons than the default, ``--photons``, to keep the module fast)."""

import json

import numpy as np
import pytest

from jaxsss.cli import main
from jaxsss.cli.run import STEPS
from jaxsss.data import list_materials

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PHOTONS = 20_000
SIZE = 32  # pixels a side (the default is 512): the job's fit_image then solves on ~150 pixels
MAX_SAMPLES = 1000  # irradiance samples (the plan asks for 165,000 on the teapot): 442 interactions per shaded point


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """Run the job once for this module (it compiles the profile; keep the suite fast)."""
    import contextlib
    import io

    out_dir = tmp_path_factory.mktemp("run") / "nested" / "out"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["run", "--out-dir", str(out_dir), "--photons", str(PHOTONS), "--resolution", str(SIZE), str(SIZE),
                     "--max-samples", str(MAX_SAMPLES)])
    return code, stdout.getvalue(), stderr.getvalue(), out_dir


def test_job_succeeds_and_writes_the_plot(job):
    code, out, err, out_dir = job
    assert code == 0 and err == ""
    path = out_dir / "dipole_profiles.png"
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    assert f"wrote {path}" in out


def test_job_prints_all_twelve_materials_with_three_channels(job):
    _, out, _, _ = job
    names = list_materials("jensen2001")
    assert len(names) == 12
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("material"))
    rows = [line.split() for line in lines[header + 1: header + 1 + 36]]
    assert [r[0] for r in rows[::3]] == names  # name on the first of each material's three channel rows
    assert [r[2] if i % 3 == 0 else r[0] for i, r in enumerate(rows)] == ["R", "G", "B"] * 12
    assert "nan" not in out.lower()


def test_job_table_agrees_with_reparam(job, capsys):
    """The table's Rd and l_d are the reverse reparameterisation at the table's eta (marble: eta 1.5)."""
    _, out, _, _ = job
    rows = [line.split() for line in out.splitlines()]
    i = next(k for k, r in enumerate(rows) if r and r[0] == "marble")
    table_rd = [float(rows[i][5])] + [float(rows[i + c][3]) for c in (1, 2)]
    table_ld = [float(rows[i][6])] + [float(rows[i + c][4]) for c in (1, 2)]
    assert main(["reparam", "--material", "marble", "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)
    # The table prints 5 significant digits.
    np.testing.assert_allclose(table_rd, ref["rd"], rtol=1e-4)
    np.testing.assert_allclose(table_ld, ref["ld"], rtol=1e-4)
    spectralon = next(k for k, r in enumerate(rows) if r and r[0] == "spectralon")
    assert rows[spectralon][-1] == "inf"  # sigma_a = 0: infinite l_d, printed as inf


def test_job_is_a_list_of_steps(job):
    _, out, _, _ = job
    assert [s.name for s in STEPS] == ["render", "fit_image", "reparam", "dipole_profiles", "measure",
                                       "fit_measurement"]
    for i, step in enumerate(STEPS, 1):
        assert f"step {i}/{len(STEPS)}: {step.name}" in out


def test_job_renders_the_teapot_and_recovers_the_marble(job):
    _, out, _, out_dir = job
    assert (out_dir / "marble_teapot.png").read_bytes()[:8] == PNG_SIGNATURE
    image = np.load(out_dir / "marble_teapot.npy")
    assert image.shape == (SIZE, SIZE, 3) and np.isfinite(image).all() and image.max() > 0
    report = json.loads((out_dir / "marble_teapot.json").read_text())
    assert report["resolution"] == [SIZE, SIZE] and report["plan"]["items"]
    # The recovery table: six rows (sigma_a and sigma_s' in R, G, B), each within 1% at this tiny size.
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("param"))
    errors = [float(line.split()[-1].rstrip("%")) for line in lines[start + 1:start + 7]]
    assert len(errors) == 6 and max(abs(e) for e in errors) < 1.0, errors
    assert "converged" in out


def test_out_dir_that_is_a_file_is_a_user_error(capsys, tmp_path):
    blocker = tmp_path / "out"
    blocker.write_text("")
    assert main(["run", "--out-dir", str(blocker)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("jaxsss: error:") and captured.err.count("\n") == 1


def test_job_simulates_and_fits_a_named_material(job):
    """Steps 3-4: skin1's green channel (g 0.9, n 1.4) is simulated, written as a CSV and fitted. With 2e4 photons
    the mc estimates must still land within 5 standard errors + 2% (the model's systematic error, cf.
    tests/fitting/test_mc_model.py); the dipole's error is printed, whatever it is."""
    from fitting import read_profile
    from jaxsss.cli.run import MEASURE_G, MEASURE_N, MEASURED

    _, out, _, out_dir = job
    path = out_dir / "measurement_skin1_G.csv"
    data = read_profile(path)
    assert len(data.r) > 10 and data.R_stderr is not None
    assert f"{PHOTONS} photons" in out and f"g = {MEASURE_G:g}" in out and f"eta = {MEASURE_N:g}" in out
    rows = {}
    model = None
    for line in out[out.index(": fit_measurement:"):].splitlines():
        parts = line.split()
        if parts and parts[0] in ("mc", "dipole"):
            model, parts = parts[0], parts[1:]
        elif not (parts and parts[0] == "sigma_s'"):
            continue
        if parts and parts[0] in ("sigma_a", "sigma_s'"):
            rows[(model, parts[0])] = [float(parts[1]), float(parts[2]), float(parts[3]), parts[4]]
    assert set(rows) == {(m, p) for m in ("mc", "dipole") for p in ("sigma_a", "sigma_s'")}
    for p in ("sigma_a", "sigma_s'"):
        truth, est, se, rel = rows[("mc", p)]
        assert abs(est - truth) <= 5 * se + 0.02 * truth, (p, truth, est, se)
        assert rel.endswith("%")
    assert out.count("converged") >= 2 and "NOT CONVERGED" not in out
    assert MEASURED[0] == "skin1"
