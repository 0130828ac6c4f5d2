"""Reading measured or simulated radial profiles: CSV (the ``jaxsss mc`` format), NumPy files and MCML's ``.mco``
output (:mod:`fitting.mco`).

CSV format: columns ``r_mm, R[, R_stderr][, T, T_stderr]``, comma-separated, one radius per line, ``#`` starts a
comment (whole line or trailing), blank lines are ignored. An optional header line names the columns (any order
after ``r_mm``; names are case-insensitive apart from ``R``, and ``r [mm]`` is accepted for ``r_mm``). Without a header the column count
decides: 2 = ``r, R``; 3 = ``r, R, R_stderr``; 4 = ``r, R, T, T_stderr``; 5 = all. Units: ``r`` in mm; ``R``, ``T``
and their standard errors in 1/mm^2 (absolute profiles per incident photon) or arbitrary units (relative).

Binned layout (MCML's radial arrays, as in ``../shared/reference/mcml/*.csv``): a header ``r_lo_mm, r_hi_mm`` then
the value columns, where ``Rd_per_mm2`` and ``Tt_per_mm2`` are accepted for ``R`` and ``T``. Each row is an annulus
average over ``[r_lo, r_hi)``; the profile's radius is the bin centre (as :func:`fitting.mco.read_mco` does). When the
first comment line says the file is an MCML run (``# MCML ...``) with ``photons=N``: the last bin is dropped (MCML
adds every photon beyond the grid to it), standard errors absent from the file come from the photon count
(:func:`fitting.mco.poisson_stderr`, an empty bin counted as one photon) and a ``T`` column that is zero everywhere
(a half-space) is dropped.

Checks: every cell numeric and finite, ``r >= 0`` and strictly increasing, standard errors ``> 0``, no missing or
extra cells; binned rows contiguous (``r_lo`` of a row is the previous ``r_hi``) with ``r_hi > r_lo``. A bad file
raises :class:`ProfileFileError` (a ``ValueError``) naming the file, line and column.

NumPy: a ``.npy`` array of shape ``(N, k)`` with the same column layout as a header-less CSV, or a ``.npz`` with
arrays named ``r_mm``, ``R``, ``R_stderr``, ``T``, ``T_stderr``; errors name the file, row and column.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["BIN_EDGES", "COLUMNS", "ProfileData", "ProfileFileError", "load_profile_npy", "read_profile", "read_profile_csv"]

COLUMNS = ("r_mm", "R", "R_stderr", "T", "T_stderr")
"""Column names, in file order."""

_BY_COUNT = {
    2: ("r_mm", "R"),
    3: ("r_mm", "R", "R_stderr"),
    4: ("r_mm", "R", "T", "T_stderr"),
    5: COLUMNS,
}
_ALIASES = {"r_mm": "r_mm", "r[mm]": "r_mm", "r [mm]": "r_mm", "r (mm)": "r_mm",
            "rd_per_mm2": "R", "tt_per_mm2": "T"}
BIN_EDGES = ("r_lo_mm", "r_hi_mm")
"""The first two columns of the binned layout (annulus edges, mm)."""


def _canonical(name: str):
    """The column called ``name``: exact, then case-insensitive (``R`` and ``r`` differ: the radius is ``r_mm``)."""
    if name in COLUMNS:
        return name
    return _ALIASES.get(name.lower(), next((c for c in COLUMNS[1:] if c.lower() == name.lower()), None))


class ProfileFileError(ValueError):
    """A profile file that cannot be read; the message names the file, line (or row) and column."""


class ProfileData(NamedTuple):
    """One radial profile: radii (mm) and the measured ``R`` and/or ``T`` (shape ``(N,)`` each), with optional
    per-point standard errors; ``source`` names where it came from (a path, or ``"<array>"``); ``r_edges``
    ``(N + 1,)``: the annuli's edges (mm) when the values are bin averages and the file says so (binned CSV, ``.mco``),
    else ``None``."""

    r: np.ndarray
    R: np.ndarray | None = None
    R_stderr: np.ndarray | None = None
    T: np.ndarray | None = None
    T_stderr: np.ndarray | None = None
    source: str = "<array>"
    r_edges: np.ndarray | None = None


def _parse_header(cells, path, line_no):
    """Column names of a header line: ``r_mm, ...`` or the binned ``r_lo_mm, r_hi_mm, ...``."""
    binned = tuple(c.strip().lower() for c in cells[:2]) == BIN_EDGES
    names = list(BIN_EDGES) if binned else []
    for col, cell in enumerate(cells[len(names):], start=len(names) + 1):
        key = cell.strip()
        canon = _canonical(key)
        if canon is None:
            raise ProfileFileError(
                f"{path}: line {line_no}, column {col}: unknown column name {key!r}; allowed: {', '.join(COLUMNS)}"
            )
        if canon in names:
            raise ProfileFileError(f"{path}: line {line_no}, column {col}: column {canon!r} appears twice")
        names.append(canon)
    _check_layout(["r_mm", *names[2:]] if binned else names, path, f"line {line_no}")
    return tuple(names)


def _check_layout(names, path, where):
    if names[0] != "r_mm":
        raise ProfileFileError(f"{path}: {where}, column 1: the first column must be r_mm (radius, mm), got {names[0]!r}")
    if "R" not in names and "T" not in names:
        raise ProfileFileError(f"{path}: {where}: missing column R (or T): a profile needs R and/or T")
    for se, value in (("R_stderr", "R"), ("T_stderr", "T")):
        if se in names and value not in names:
            raise ProfileFileError(f"{path}: {where}: column {se} without column {value}")


def _is_numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _validate_columns(columns: dict, locate, path) -> None:
    """Physical checks shared by CSV and NumPy input. ``locate(i, name) -> 'line L, column C (name)'``."""
    r = columns["r_mm"]
    for name, values in columns.items():
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.argmax(bad))
            raise ProfileFileError(f"{path}: {locate(i, name)}: value {values[i]!r} is not a finite number")
        if name.endswith("_stderr") and (values <= 0).any():
            i = int(np.argmax(values <= 0))
            raise ProfileFileError(f"{path}: {locate(i, name)}: standard error {values[i]:g} must be > 0")
    if (r < 0).any():
        i = int(np.argmax(r < 0))
        raise ProfileFileError(f"{path}: {locate(i, 'r_mm')}: negative radius {r[i]:g} mm (allowed range [0, inf))")
    if len(r) > 1 and (np.diff(r) <= 0).any():
        i = int(np.argmax(np.diff(r) <= 0)) + 1
        raise ProfileFileError(
            f"{path}: {locate(i, 'r_mm')}: radius {r[i]:g} mm is not greater than the previous one {r[i - 1]:g} mm; "
            "radii must be strictly increasing"
        )
    if len(r) < 2:
        raise ProfileFileError(f"{path}: needs at least 2 radii, found {len(r)}")


def read_profile_csv(path) -> ProfileData:
    """Read a CSV profile (format in the module docstring); raise :class:`ProfileFileError` naming file, line, column."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise ProfileFileError(f"{path}: cannot read the file: {err.strerror or err}") from None
    names = None
    rows, line_of_row, comments = [], [], []
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line, _, comment = raw.partition("#")
        line = line.strip()
        if not line:
            if comment.strip() and not rows:
                comments.append(comment.strip())
            continue
        cells = [c.strip() for c in line.split(",")]
        if names is None:
            if not _is_numeric(cells[0]):  # the first line that is not a comment: a header, or data
                names = _parse_header(cells, path, line_no)
                continue
            if len(cells) not in _BY_COUNT:
                raise ProfileFileError(
                    f"{path}: line {line_no}: {len(cells)} columns; expected 2 to 5 (r_mm, R[, R_stderr][, T, "
                    "T_stderr]) or a header line naming them"
                )
            names = _BY_COUNT[len(cells)]
        if len(cells) < len(names):
            col = len(cells) + 1
            raise ProfileFileError(f"{path}: line {line_no}, column {col} ({names[col - 1]}): missing value")
        if len(cells) > len(names):
            raise ProfileFileError(
                f"{path}: line {line_no}, column {len(names) + 1}: extra value {cells[len(names)]!r} "
                f"(the file has {len(names)} columns: {', '.join(names)})"
            )
        values = []
        for col, (cell, name) in enumerate(zip(cells, names), start=1):
            if cell == "":
                raise ProfileFileError(f"{path}: line {line_no}, column {col} ({name}): missing value")
            try:
                v = float(cell)
            except ValueError:
                raise ProfileFileError(
                    f"{path}: line {line_no}, column {col} ({name}): {cell!r} is not a number"
                ) from None
            if math.isnan(v) or math.isinf(v):
                raise ProfileFileError(f"{path}: line {line_no}, column {col} ({name}): {cell!r} is not a finite number")
            values.append(v)
        rows.append(values)
        line_of_row.append(line_no)
    if names is None or not rows:
        raise ProfileFileError(f"{path}: no data rows (expected lines of r_mm, R[, R_stderr][, T, T_stderr])")
    table = np.asarray(rows, dtype=np.float64)
    columns = {name: table[:, j] for j, name in enumerate(names)}

    def locate(i, name):
        return f"line {line_of_row[i]}, column {names.index(name) + 1} ({name})"

    edges = None
    if names[:2] == BIN_EDGES:
        columns, edges = _from_bins(columns, comments, locate, path)
    _validate_columns(columns, locate, path)
    return _to_data(columns, str(path))._replace(r_edges=edges)


def equal_bin_edges(r) -> np.ndarray | None:
    """The edges of equal bins from ``r = 0`` whose centres are the radii ``r`` (binned data such as the ``jaxsss mc``
    CSV), or ``None`` when ``r`` is not such a set of centres."""
    r = np.asarray(r, dtype=np.float64)
    if r.size < 2 or not r[0] > 0:
        return None
    step = np.diff(r)
    if np.allclose(step, step[0], rtol=1e-6, atol=0.0) and abs(2.0 * r[0] - step[0]) <= 1e-6 * step[0]:
        return step[0] * np.arange(r.size + 1)
    return None


def _mcml_photons(comments) -> int | None:
    """The photon count of an MCML run named in the file's first comment line (``# MCML ... photons=N``), else None."""
    if not comments or not comments[0].startswith("MCML"):
        return None
    found = re.search(r"photons\s*=\s*([0-9.eE+]+)", comments[0])
    return int(float(found.group(1))) if found else None


def _from_bins(columns: dict, comments, locate, path) -> tuple[dict, np.ndarray]:
    """Binned columns -> (columns with ``r_mm`` at the bin centres, the kept bins' edges); see the module docstring
    for MCML files."""
    lo, hi = columns.pop("r_lo_mm"), columns.pop("r_hi_mm")
    for i in range(len(lo)):
        if not hi[i] > lo[i]:
            raise ProfileFileError(f"{path}: {locate(i, 'r_hi_mm')}: bin [{lo[i]:g}, {hi[i]:g}) mm is empty; "
                                   "r_hi_mm must be greater than r_lo_mm")
        if i and lo[i] != hi[i - 1]:
            raise ProfileFileError(f"{path}: {locate(i, 'r_lo_mm')}: bin starts at {lo[i]:g} mm but the previous one "
                                   f"ends at {hi[i - 1]:g} mm; bins must be contiguous")
    columns = {"r_mm": 0.5 * (lo + hi), **columns}
    photons = _mcml_photons(comments)
    if photons is None:
        return columns, np.append(lo, hi[-1])
    from fitting.mco import poisson_stderr  # fitting.mco imports this module

    area = np.pi * (hi**2 - lo**2)
    # MCML's last radial bin also collects every photon beyond the grid: not a profile value.
    keep = slice(0, len(lo) - 1)
    out = {"r_mm": columns["r_mm"][keep]}
    for value in ("R", "T"):
        if value not in columns or (value == "T" and not np.any(columns["T"])):
            continue
        out[value] = columns[value][keep]
        se = columns.get(f"{value}_stderr")
        out[f"{value}_stderr"] = (se if se is not None else poisson_stderr(columns[value], photons, area,
                                                                           empty_as_one=True))[keep]
    return out, np.append(lo, hi[-1])[: len(lo)]


def _to_data(columns: dict, source: str) -> ProfileData:
    return ProfileData(
        r=columns["r_mm"],
        R=columns.get("R"),
        R_stderr=columns.get("R_stderr"),
        T=columns.get("T"),
        T_stderr=columns.get("T_stderr"),
        source=source,
    )


def load_profile_npy(path) -> ProfileData:
    """Read a ``.npy`` (``(N, k)`` array, header-less CSV layout) or ``.npz`` (named arrays) profile."""
    path = Path(path)
    try:
        loaded = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise ProfileFileError(f"{path}: cannot read as a NumPy file: {err}") from None
    if isinstance(loaded, np.ndarray):
        arr = loaded
        if arr.ndim != 2 or arr.shape[1] not in _BY_COUNT:
            raise ProfileFileError(
                f"{path}: array of shape {arr.shape}; expected (N, k) with k = 2..5 columns "
                "(r_mm, R[, R_stderr][, T, T_stderr])"
            )
        if arr.dtype.kind not in "biuf":
            raise ProfileFileError(f"{path}: array of dtype {arr.dtype} is not numeric")
        names = _BY_COUNT[arr.shape[1]]
        columns = {name: np.asarray(arr[:, j], dtype=np.float64) for j, name in enumerate(names)}
    else:
        with loaded:
            keys = list(loaded.keys())
            names = []
            for key in keys:
                canon = _canonical(key)
                if canon is None:
                    raise ProfileFileError(f"{path}: unknown array name {key!r}; allowed: {', '.join(COLUMNS)}")
                names.append(canon)
            if "r_mm" not in names:
                raise ProfileFileError(f"{path}: missing array r_mm (radius, mm)")
            names_sorted = sorted(names, key=COLUMNS.index)
            _check_layout(names_sorted, path, "arrays")
            raw = {canon: loaded[key] for key, canon in zip(keys, names)}
        n = np.shape(raw["r_mm"])
        for name, a in raw.items():
            if np.ndim(a) != 1 or np.shape(a) != n or np.asarray(a).dtype.kind not in "biuf":
                raise ProfileFileError(f"{path}: array {name} must be numeric of shape {n}, got {np.shape(a)}")
        columns = {name: np.asarray(raw[name], dtype=np.float64) for name in names_sorted}
        names = tuple(names_sorted)

    def locate(i, name):
        return f"row {i + 1}, column {list(columns).index(name) + 1} ({name})"

    _validate_columns(columns, locate, path)
    return _to_data(columns, str(path))


def read_profile(path) -> ProfileData:
    """Read a profile by file extension: ``.npy``/``.npz`` with :func:`load_profile_npy`, ``.mco`` (MCML 1.2.2 output)
    with :func:`fitting.mco.read_mco` (bin centres, per-bin standard errors from the photon count), anything else as
    CSV."""
    suffix = Path(path).suffix.lower()
    if suffix == ".mco":
        from fitting.mco import read_mco  # fitting.mco imports this module

        return read_mco(path).to_profile()
    return load_profile_npy(path) if suffix in (".npy", ".npz") else read_profile_csv(path)
