"""Profile files: good CSV/NumPy input, and bad files named by file, line and column."""

import numpy as np
import pytest

from fitting import ProfileFileError, load_profile_npy, read_profile, read_profile_csv


def test_csv_with_header_comments_and_all_columns(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("# a comment\nr_mm, R, R_stderr, T, T_stderr\n\n0.1, 1.0, 0.1, 0.5, 0.05  # trailing\n0.2, 0.5, 0.05, 0.4, 0.04\n")
    d = read_profile_csv(p)
    np.testing.assert_array_equal(d.r, [0.1, 0.2])
    np.testing.assert_array_equal(d.T_stderr, [0.05, 0.04])
    assert d.source == str(p)


@pytest.mark.parametrize("ncol, present", [(2, ("R",)), (3, ("R", "R_stderr")), (4, ("R", "T", "T_stderr"))])
def test_headerless_csv_layout_by_column_count(tmp_path, ncol, present):
    p = tmp_path / "p.csv"
    rows = np.column_stack([[0.1, 0.2, 0.3]] + [[1.0, 0.5, 0.25]] * (ncol - 1))
    p.write_text("\n".join(", ".join(map(str, row)) for row in rows))
    d = read_profile(p)
    for name in ("R", "R_stderr", "T", "T_stderr"):
        assert (getattr(d, name) is not None) == (name in present)


@pytest.mark.parametrize(
    "body, where",
    [
        ("r_mm, R, R_stderr\n0.1, 1.0, 0.1\n0.2, 0.5\n", "line 3, column 3 (R_stderr): missing value"),
        ("r_mm, R\n0.1, 1.0\n0.2, abc\n", "line 3, column 2 (R): 'abc' is not a number"),
        ("r_mm, R\n-0.1, 1.0\n0.2, 0.5\n", "line 2, column 1 (r_mm): negative radius"),
        ("r_mm, R\n0.2, 1.0\n0.1, 0.5\n", "line 3, column 1 (r_mm)"),
        ("# c\nr_mm, R\n0.1, nan\n0.2, 0.5\n", "line 3, column 2 (R): 'nan' is not a finite number"),
        ("r_mm, Q\n0.1, 1.0\n", "line 1, column 2: unknown column name 'Q'"),
        ("r_mm, R\n0.1, 1.0, 3\n0.2, 1\n", "line 2, column 3: extra value"),
        ("r_mm, R, R_stderr\n0.1, 1.0, 0\n0.2, 1, 1\n", "line 2, column 3 (R_stderr): standard error 0"),
    ],
)
def test_bad_csv_names_file_line_and_column(tmp_path, body, where):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ProfileFileError) as err:
        read_profile_csv(p)
    assert str(p) in str(err.value) and where in str(err.value)


def test_empty_file_and_missing_file(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("# nothing\n")
    with pytest.raises(ProfileFileError, match="no data rows"):
        read_profile_csv(p)
    with pytest.raises(ProfileFileError, match="cannot read"):
        read_profile_csv(tmp_path / "missing.csv")


def test_npy_and_npz(tmp_path):
    arr = np.array([[0.1, 1.0, 0.1], [0.2, 0.5, 0.05]])
    np.save(tmp_path / "p.npy", arr)
    d = load_profile_npy(tmp_path / "p.npy")
    np.testing.assert_array_equal(d.R_stderr, [0.1, 0.05])
    np.savez(tmp_path / "p.npz", r_mm=arr[:, 0], R=arr[:, 1])
    assert read_profile(tmp_path / "p.npz").R_stderr is None
    bad = arr.copy()
    bad[1, 0] = 0.05  # unsorted
    np.save(tmp_path / "bad.npy", bad)
    with pytest.raises(ProfileFileError, match=r"bad\.npy: row 2, column 1 \(r_mm\)"):
        load_profile_npy(tmp_path / "bad.npy")
    np.save(tmp_path / "shape.npy", np.zeros((3, 7)))
    with pytest.raises(ProfileFileError, match="shape"):
        load_profile_npy(tmp_path / "shape.npy")


def test_binned_csv_uses_bin_centres(tmp_path):
    """Annulus rows ``r_lo_mm, r_hi_mm, ...`` (no MCML comment): radii at the centres, every bin kept, no errors."""
    p = tmp_path / "bins.csv"
    p.write_text("r_lo_mm, r_hi_mm, Rd_per_mm2\n0, 0.1, 2.0\n0.1, 0.2, 1.0\n0.2, 0.3, 0.5\n")
    d = read_profile(p)
    np.testing.assert_allclose(d.r, [0.05, 0.15, 0.25])
    np.testing.assert_array_equal(d.R, [2.0, 1.0, 0.5])
    assert d.R_stderr is None and d.T is None


def test_binned_mcml_csv_drops_overflow_bin_and_adds_errors(tmp_path):
    """An MCML comment with a photon count: the overflow bin goes, errors follow the photon count, zero T is dropped."""
    p = tmp_path / "mcml.csv"
    p.write_text("# MCML 1.2.2 run: photons=10000\n# totals\nr_lo_mm,r_hi_mm,Rd_per_mm2,Tt_per_mm2\n"
                 "0,0.1,2.0,0\n0.1,0.2,1.0,0\n0.2,0.3,0.5,0\n0.3,0.4,9.0,0\n")
    d = read_profile(p)
    np.testing.assert_allclose(d.r, [0.05, 0.15, 0.25])
    area = np.pi * (np.array([0.1, 0.2, 0.3]) ** 2 - np.array([0.0, 0.1, 0.2]) ** 2)
    frac = d.R * area  # fraction of the photons in each annulus: Poisson error sqrt(p (1 - p) / N) / area
    np.testing.assert_allclose(d.R_stderr, np.sqrt(frac * (1 - frac) / 10000) / area)
    assert d.T is None


@pytest.mark.parametrize(
    "rows, where",
    [
        ("0, 0.1, 2.0\n0.1, 0.1, 1.0\n", "line 3, column 2 (r_hi_mm): bin [0.1, 0.1) mm is empty"),
        ("0, 0.1, 2.0\n0.2, 0.3, 1.0\n", "line 3, column 1 (r_lo_mm): bin starts at 0.2 mm"),
        ("0, 0.1, 2.0\n0.1, 0.2, x\n", "line 3, column 3 (R): 'x' is not a number"),
    ],
)
def test_bad_binned_csv_names_line_and_column(tmp_path, rows, where):
    p = tmp_path / "bad_bins.csv"
    p.write_text("r_lo_mm, r_hi_mm, Rd_per_mm2\n" + rows)
    with pytest.raises(ProfileFileError) as err:
        read_profile_csv(p)
    assert str(p) in str(err.value) and where in str(err.value)
