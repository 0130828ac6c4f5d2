"""MCML 1.2.2 ``.mco`` files: every shared reference run parses and agrees with its CSV twin bin by bin, the layers
match the ``.mci`` input, the standard errors bound the bin-to-bin noise, and bad files are named by file and line.

The shared runs live in ``shared/reference/mcml`` beside the repository (``../shared`` from the main checkout,
``../../shared`` from a worktree); a committed copy of one run (``tests/fitting/data``) serves the bad-file tests.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fitting import McoRun, ProfileFileError, read_mco, read_profile

FIXTURE = Path(__file__).parent / "data" / "slab03mm_n133_g09.mco"


def shared_mcml_dir() -> Path:
    """``shared/reference/mcml`` in the nearest ancestor of the repository that has it (the benchmark's locator)."""
    from benchmarks.mcml_fits import mcml_dir

    return mcml_dir()


def shared_runs():
    files = sorted(shared_mcml_dir().glob("*.mco"))
    assert len(files) >= 8, files
    return files


def read_csv_twin(path: Path):
    """The twin CSV: parameters line, totals line, then ``r_lo_mm, r_hi_mm, Rd_per_mm2, Tt_per_mm2`` rows."""
    lines = path.with_suffix(".csv").read_text().splitlines()
    totals = dict(kv.split("=") for kv in lines[1].lstrip("# ").split())
    table = np.loadtxt(lines[3:], delimiter=",")
    return lines[0], {k: float(v) for k, v in totals.items()}, table


def read_mci_layers(path: Path):
    """Layers ``(n, mua, mus, g, d)`` in 1/cm and cm, ambient indices and photons from the ``.mci`` input."""
    rows = [line.split() for line in path.with_suffix(".mci").read_text().splitlines() if line.strip()]
    photons = int(rows[3][0])
    n_layers = int(rows[6][0])
    layers = [tuple(map(float, r)) for r in rows[8 : 8 + n_layers]]
    return photons, float(rows[7][0]), layers, float(rows[8 + n_layers][0])


def test_every_shared_run_matches_its_csv_twin_and_mci_input():
    for path in shared_runs():
        run = read_mco(path)
        params, totals, table = read_csv_twin(path)
        assert run.nr == len(table)
        np.testing.assert_allclose(run.r_lo, table[:, 0], rtol=1e-12, atol=1e-12, err_msg=path.name)
        np.testing.assert_allclose(run.r_hi, table[:, 1], rtol=1e-12, err_msg=path.name)
        # The CSV prints MCML's 5 digits in mm units: the same numbers / 100.
        np.testing.assert_allclose(run.Rd_r, table[:, 2], rtol=1e-12, atol=0, err_msg=path.name)
        np.testing.assert_allclose(run.Tt_r, table[:, 3], rtol=1e-12, atol=0, err_msg=path.name)
        assert (run.specular, run.Rd, run.A, run.Tt) == (totals["specular"], totals["Rd"], totals["A"], totals["Tt"])
        assert f"photons={run.photons} " in params
        photons, n_above, layers, n_below = read_mci_layers(path)
        assert (run.photons, run.n_above, run.n_below) == (photons, n_above, n_below)
        assert len(run.layers) == len(layers)
        for got, (n, mua, mus, g, d) in zip(run.layers, layers):
            # 1/cm -> 1/mm and cm -> mm.
            np.testing.assert_allclose([got.n, got.mua, got.mus, got.g, got.thickness],
                                       [n, mua / 10, mus / 10, g, d * 10], rtol=1e-14)
        # The CSV's own parameter line (mm units) agrees too; "d=inf" marks a semi-infinite layer.
        csv_layers = re.findall(r"layer\d+: n=(\S+) mua=(\S+)/mm mus=(\S+)/mm g=(\S+) d=(\S+) mm", params)
        assert len(csv_layers) == len(run.layers), params
        for got, row in zip(run.layers, csv_layers):
            n, mua, mus, g, d = map(float, row)
            assert (got.n, got.mua, got.mus, got.g) == pytest.approx((n, mua, mus, g), rel=1e-12)
            assert got.semi_infinite == math.isinf(d) and (math.isinf(d) or got.thickness == pytest.approx(d))
        # Semi-infinite exactly when the CSV's deepest layer is; no transmission then.
        assert run.semi_infinite == math.isinf(float(csv_layers[-1][4]))
        assert run.semi_infinite == (run.Tt == 0.0)
        # The profile integrates to the totals (MCML sums the same weights: equal to its 5 printed digits).
        area = np.pi * (run.r_hi**2 - run.r_lo**2)
        np.testing.assert_allclose(np.sum(run.Rd_r * area), run.Rd, rtol=5e-4, err_msg=path.name)
        np.testing.assert_allclose(np.sum(run.Tt_r * area), run.Tt, rtol=5e-4, atol=1e-12, err_msg=path.name)


def test_profile_conversion_bin_centres_and_standard_errors():
    run = read_mco(FIXTURE)
    assert isinstance(run, McoRun) and run.photons == 2_000_000 and run.dr == pytest.approx(0.01)
    assert run.thickness == pytest.approx(0.3) and run.eta == pytest.approx(1.33) and not run.semi_infinite
    assert run.layers[0].sigma_s_prime == pytest.approx(20.0 * 0.1)
    data = read_profile(FIXTURE)
    # The overflow bin (everything beyond nr dr) is dropped; radii are bin centres.
    assert len(data.r) == run.nr - 1
    np.testing.assert_allclose(data.r, (np.arange(run.nr - 1) + 0.5) * run.dr, rtol=1e-14)
    np.testing.assert_array_equal(data.R, run.Rd_r[:-1])
    np.testing.assert_array_equal(data.T, run.Tt_r[:-1])
    # Bernoulli bound by hand for bin 10: p = R * area, SE = sqrt(p (1 - p) / N) / area.
    area = np.pi * run.dr**2 * 21
    p = run.Rd_r[10] * area
    assert data.R_stderr[10] == pytest.approx(math.sqrt(p * (1 - p) / run.photons) / area, rel=1e-12)
    assert np.all(data.R_stderr > 0) and np.all(data.T_stderr > 0)


def test_a_half_space_has_no_transmission_profile():
    data = read_profile(shared_mcml_dir() / "halfspace_n133_g0.mco")
    assert data.T is None and data.T_stderr is None and data.R is not None


def test_empty_bins_get_a_one_photon_standard_error(tmp_path):
    text = FIXTURE.read_text().splitlines()
    start = text.index(next(t for t in text if t.startswith("Rd_r"))) + 1
    text[start + 150] = "  0.0000E+00"
    path = tmp_path / "zero.mco"
    path.write_text("\n".join(text) + "\n")
    run = read_mco(path)
    data = run.to_profile()
    area = np.pi * (run.r_hi[150] ** 2 - run.r_lo[150] ** 2)
    # p = 0 is replaced by 1/N: SE = sqrt(1/N / N) / area = 1 / (N area).
    assert data.R[150] == 0 and data.R_stderr[150] == pytest.approx(1 / (run.photons * area), rel=1e-12)


def test_standard_errors_bound_the_bin_to_bin_noise():
    # Second differences of neighbouring bins are noise (the profiles are smooth on the bin scale beyond bin 20):
    # their RMS in units of the estimated SE is at most ~1 (the estimate is an upper bound; exact without
    # absorption) and not far below (it is not grossly pessimistic). Measured: 0.46 (albedo 0.94) to 0.99.
    for path in shared_runs():
        data = read_profile(path)
        for y, se in ((data.R, data.R_stderr), (data.T, data.T_stderr)):
            if y is None:
                continue
            d = y[1:-1] - 0.5 * (y[:-2] + y[2:])
            z = (d / np.sqrt(se[1:-1] ** 2 + 0.25 * (se[:-2] ** 2 + se[2:] ** 2)))[20:]
            assert 0.3 < np.sqrt(np.mean(z**2)) < 1.15, path.name


def _edit(tmp_path, edit):
    lines = FIXTURE.read_text().splitlines()
    lines = edit(lines)
    path = tmp_path / "bad.mco"
    path.write_text("\n".join(lines) + "\n")
    return path


def _line_of(lines, prefix):
    return next(i for i, t in enumerate(lines) if t.startswith(prefix))


@pytest.mark.parametrize(
    "edit, message",
    [
        # Truncated in the middle of Tt_r (line 300 of 586): the 2-D blocks and the rest of Tt_r are missing.
        (lambda ls: ls[:300], "line 300: block Tt_r ends after"),
        # Truncated inside the last block.
        (lambda ls: ls[:-3], "block Tt_ra ends after"),
        # A bad number in Rd_r (file line 41).
        (lambda ls: ls[:40] + ["  1.2E+0x"] + ls[41:], "line 41: '1.2E+0x' is not a number (Rd_r"),
        (lambda ls: ls[:40] + ["  nan"] + ls[41:], "line 41: 'nan' is not a finite number"),
        # A missing block: Tt_a removed (its title and its value).
        (lambda ls: ls[: _line_of(ls, "Tt_a")] + ls[_line_of(ls, "Tt_a") + 2 :], "missing block Tt_a"),
        # Wrong units: a profile written per mm^2 is not MCML's.
        (lambda ls: [t.replace("[1/cm2]", "[1/mm2]") if t.startswith("Rd_r") else t for t in ls],
         "line 36: block Rd_r is in [1/mm2]; MCML 1.2.2 writes [1/cm2]"),
        (lambda ls: [t.replace("dr [cm]", "dr [mm]") for t in ls], "line 15: block InParm (dz, dr) is in [mm]"),
        (lambda ls: [t.replace("[1/cm3]", "[1/mm3]") for t in ls], "block A_rz is in [1/mm3]"),
        # Not an .mco file at all, or another version.
        (lambda ls: ["r_mm, R", "0.1, 1"], "line 1: expected the format version 'A1'"),
        (lambda ls: ["B2"] + ls[1:], "line 1: expected the format version 'A1'"),
        # Values out of range.
        (lambda ls: [t.replace("1.33\t1\t200\t0.9\t0.03", "1.33\t1\t200\t1.9\t0.03") for t in ls],
         "line 21: layer 1: g = 1.9 must lie in [-1, 1]"),
        (lambda ls: [t.replace("2000000 \t", "-5 \t") for t in ls], "line 14: photon count -5"),
        (lambda ls: ls[:40] + ["  -1.0E+00"] + ls[41:], "line 41: block Rd_r has the negative value"),
        # An extra value in a 1-D block: the last of its 201 values (file line 236) is the one too many.
        (lambda ls: ls[:40] + ["  1.0E+00 2.0E+00"] + ls[41:], "line 236: unexpected value '6.2528E+00' after the "
                                                                "200 values of block Rd_r"),
    ],
)
def test_bad_files_name_the_file_and_line(tmp_path, edit, message):
    path = _edit(tmp_path, edit)
    with pytest.raises(ProfileFileError) as err:
        read_mco(path)
    assert str(err.value).startswith(f"{path}: line "), str(err.value)
    assert message in str(err.value), str(err.value)
    # read_profile dispatches .mco to the same reader.
    with pytest.raises(ProfileFileError, match="line"):
        read_profile(path)


def test_unreadable_file(tmp_path):
    with pytest.raises(ProfileFileError, match="cannot read the file"):
        read_mco(tmp_path / "absent.mco")


def test_an_mcml_profile_matches_white_monte_carlo_at_its_input_parameters():
    # End to end through the reader's conventions (per incident photon, 1/mm^2, bin centres, standard errors), with
    # no fit (the fit itself is benchmarks/mcml_fits.py: 0.0% / 0.1%): at MCML's input parameters the independent
    # white Monte Carlo table for this (g, n) agrees with the file to its noise (mean z^2 0.93 measured beyond
    # 0.1 l_u), while the dipole is far off (mean z^2 ~900).
    import jaxsss
    from jaxsss.mc import load_white_table, white_mc_profile

    run = read_mco(shared_mcml_dir() / "halfspace_n133_g0.mco")
    data, layer = run.to_profile(), run.layers[0]
    beyond = data.r >= 0.1 / (layer.sigma_a + layer.sigma_s_prime)
    model = np.asarray(white_mc_profile(data.r, layer.sigma_a, layer.sigma_s_prime, load_white_table(layer.g, run.eta)))
    z2 = ((data.R - model) / data.R_stderr)[beyond] ** 2
    assert 0.5 < np.mean(z2) < 1.5 and np.max(z2) < 30.0
    medium = jaxsss.Medium(layer.sigma_a, layer.sigma_s_prime, run.eta)
    dipole = (1 - jaxsss.fresnel_reflectance(run.eta, 1.0)) * np.asarray(jaxsss.dipole_profile(data.r, medium))
    assert np.mean(((data.R - dipole) / data.R_stderr)[beyond] ** 2) > 100.0


def test_jaxsss_fit_reports_a_bad_mco_file_in_one_line(capsys, tmp_path):
    from tests.cli.runner import run_cli

    path = _edit(tmp_path, lambda ls: ls[:300])
    code, out, err = run_cli(capsys, "fit", path)
    lines = err.strip().splitlines()
    assert code == 2 and out == "" and len(lines) == 1, err
    assert lines[0].startswith(f"jaxsss: error: {path}: line 300: block Tt_r ends after"), err


@pytest.mark.parametrize("path", shared_runs(), ids=lambda p: p.stem)
def test_csv_twin_reads_as_the_same_profile(path):
    """``read_profile`` on the shared CSV (binned layout) gives the ``.mco`` file's profile: centres, values, errors."""
    from_csv, from_mco = read_profile(path.with_suffix(".csv")), read_profile(path)
    np.testing.assert_allclose(from_csv.r, from_mco.r, rtol=0, atol=1e-12)
    for name in ("R", "R_stderr", "T", "T_stderr"):
        a, b = getattr(from_csv, name), getattr(from_mco, name)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=1e-4, err_msg=name)
