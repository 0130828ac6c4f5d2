"""Measured scattering coefficients of real materials, as package data with their citations.

Two tables ship with the package (``jaxsss/data/*.csv``, each with its citation in a ``#`` comment header):

=================  ==========================================================================================  =====
table              source                                                                                      eta
=================  ==========================================================================================  =====
``jensen2001``     Jensen, Marschner, Levoy, Hanrahan, "A Practical Model for Subsurface Light Transport",     yes
                   SIGGRAPH 2001 (12 materials, as tabulated in pbrt's SubsurfaceParameterTable)
``narasimhan2006`` Narasimhan, Gupta, Donner, Ramamoorthi, Nayar, Jensen, "Acquiring Scattering Properties of  no
                   Participating Media by Dilution", SIGGRAPH 2006 (35 media, as tabulated in pbrt-v4)
=================  ==========================================================================================  =====

Units: ``sigma_a`` and ``sigma_s_prime`` in 1/mm, channels R, G, B (a trailing axis of length 3). ``eta`` is
``n_inside / n_outside``.

The Narasimhan table has no refractive index, so its records carry ``eta=None`` and :func:`material_medium` requires
the caller to pass ``eta`` for them (there is no single right default: the media range from water-like drinks,
eta about 1.33, to powders). Many of those media are dilute (``sigma_s' << sigma_a``), where the diffusion
approximation does not hold.

Example:
    >>> m = material("Marble")
    >>> m.eta, m.table
    (1.5, 'jensen2001')
    >>> material_medium("marble").l_d.shape
    (3,)
"""

from __future__ import annotations

import csv
import functools
import math
from dataclasses import dataclass
from importlib import resources
from typing import NamedTuple

import numpy as np

__all__ = [
    "MATERIAL_TABLES",
    "MeasuredMaterial",
    "list_materials",
    "material",
    "material_medium",
]


class MaterialTable(NamedTuple):
    """A registered table of measured materials: its CSV file (in :mod:`jaxsss.data`) and citation."""

    name: str
    filename: str
    citation: str


MATERIAL_TABLES: dict[str, MaterialTable] = {
    t.name: t
    for t in (
        MaterialTable(
            "jensen2001",
            "measured_materials_jensen2001.csv",
            "Jensen, Marschner, Levoy, Hanrahan, 'A Practical Model for Subsurface Light Transport', SIGGRAPH 2001",
        ),
        MaterialTable(
            "narasimhan2006",
            "measured_materials_narasimhan2006.csv",
            "Narasimhan, Gupta, Donner, Ramamoorthi, Nayar, Jensen, 'Acquiring Scattering Properties of "
            "Participating Media by Dilution', SIGGRAPH 2006",
        ),
    )
}
"""Registry of the shipped tables, by name (search order of :func:`material`)."""


@dataclass(frozen=True, eq=False)
class MeasuredMaterial:
    """One measured material (immutable; the arrays are read-only).

    Attributes:
        name: the table's name for it (lower case, ``_`` between words).
        sigma_a: absorption coefficient per channel (R, G, B), 1/mm, shape ``(3,)``.
        sigma_s_prime: reduced scattering coefficient per channel, 1/mm, shape ``(3,)``.
        eta: tabulated relative index ``n_inside / n_outside``, or ``None`` when the table has none.
        table: name of the table in :data:`MATERIAL_TABLES`.
        citation: the publication the values come from.
    """

    name: str
    sigma_a: np.ndarray
    sigma_s_prime: np.ndarray
    eta: float | None
    table: str
    citation: str

    def medium(self, eta=None, g=None, fresnel: str = "poly"):
        """This material as a :class:`jaxsss.medium.Medium` (see :func:`material_medium`)."""
        from jaxsss.medium import Medium

        if eta is None:
            if self.eta is None:
                raise ValueError(
                    f"material {self.name!r} ({self.table}) has no tabulated eta; pass eta=... (n_inside / n_outside)"
                )
            eta = self.eta
        return Medium(self.sigma_a, self.sigma_s_prime, eta, g, fresnel=fresnel)


# --- CSV parsing ---------------------------------------------------------------------------------------------------
_CHANNELS = ("r", "g", "b")
_REQUIRED = ("name",) + tuple(f"sigma_s_prime_{c}" for c in _CHANNELS) + tuple(f"sigma_a_{c}" for c in _CHANNELS)


def _parse_cell(text: str, where: str, column: str, *, positive: bool = False) -> float:
    """A non-negative (or positive) finite float from one cell; errors name file:line:column and the column."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where}: column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value) or value < 0.0 or (positive and value == 0.0):
        allowed = "(0, inf)" if positive else "[0, inf)"
        raise ValueError(f"{where}: column {column!r}: {text!r} is outside the allowed range {allowed}")
    return value


def _parse_table(text: str, source: str, table: str, citation: str) -> dict[str, MeasuredMaterial]:
    """Parse one materials CSV (``#`` comment lines, a header row, one material per row).

    Args:
        text: the file's contents.
        source: the file name used in error messages (``source:line:column``; both 1-based).
        table, citation: stored in every record.

    Returns:
        Records by (lower-case) name, in file order. Raises ``ValueError`` for a missing column, a row with the
        wrong number of cells, a duplicate name, or a cell that is not a finite non-negative number (``eta > 0``).
    """
    header: list[str] | None = None
    records: dict[str, MeasuredMaterial] = {}
    for line_no, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in next(csv.reader([line]))]
        if header is None:
            header = [c.lower() for c in cells]
            missing = [c for c in _REQUIRED if c not in header]
            if missing:
                raise ValueError(f"{source}:{line_no}: header lacks column(s) {', '.join(missing)}")
            continue
        if len(cells) != len(header):
            raise ValueError(f"{source}:{line_no}: {len(cells)} cells, the header has {len(header)}")
        col = {name: i for i, name in enumerate(header)}

        def cell(name, *, positive=False):
            i = col[name]
            return _parse_cell(cells[i], f"{source}:{line_no}:{i + 1}", name, positive=positive)

        name = cells[col["name"]].lower()
        if not name:
            raise ValueError(f"{source}:{line_no}:{col['name'] + 1}: column 'name' is empty")
        if name in records:
            raise ValueError(f"{source}:{line_no}:{col['name'] + 1}: duplicate material name {name!r}")
        arrays = {}
        for quantity in ("sigma_a", "sigma_s_prime"):
            arr = np.array([cell(f"{quantity}_{c}") for c in _CHANNELS], dtype=np.float64)
            arr.flags.writeable = False
            arrays[quantity] = arr
        eta = cell("eta", positive=True) if "eta" in col else None
        records[name] = MeasuredMaterial(name, arrays["sigma_a"], arrays["sigma_s_prime"], eta, table, citation)
    if header is None:
        raise ValueError(f"{source}: no header row")
    return records


@functools.cache
def _load(table: str) -> dict[str, MeasuredMaterial]:
    spec = MATERIAL_TABLES[table]
    text = resources.files("jaxsss.data").joinpath(spec.filename).read_text(encoding="utf-8")
    return _parse_table(text, spec.filename, spec.name, spec.citation)


# --- Lookup ----------------------------------------------------------------------------------------------------------
def _resolve_tables(table: str | None) -> tuple[str, ...]:
    if table is None:
        return tuple(MATERIAL_TABLES)
    key = str(table).lower()
    if key not in MATERIAL_TABLES:
        valid = ", ".join(repr(t) for t in MATERIAL_TABLES)
        raise ValueError(f"table={table!r} is not a known materials table; valid: {valid}")
    return (key,)


def _normalise(name: str) -> str:
    # Case-insensitive; "Whole Milk", "whole-milk" and "wholemilk" differ only where the table's names do.
    return str(name).strip().lower().replace(" ", "_").replace("-", "_")


def list_materials(table: str | None = None) -> list[str]:
    """Names of the measured materials, in table order (``table=None``: all tables, in :data:`MATERIAL_TABLES` order)."""
    return [name for t in _resolve_tables(table) for name in _load(t)]


def material(name: str, table: str | None = None) -> MeasuredMaterial:
    """Look up a measured material by name, case-insensitively (spaces and ``-`` count as ``_``).

    Args:
        name: e.g. ``"marble"``, ``"Skin1"``, ``"regular milk"``.
        table: restrict the search to one table of :data:`MATERIAL_TABLES`; ``None`` searches all.

    Raises:
        ValueError: unknown name (the message lists the valid names), unknown table, or a name present in more
            than one table when ``table`` is ``None`` (the message names the tables to choose from).
    """
    key = _normalise(name)
    tables = _resolve_tables(table)
    hits = [_load(t)[key] for t in tables if key in _load(t)]
    if not hits:
        scope = f"table {tables[0]!r}" if table is not None else "any table"
        valid = ", ".join(list_materials(table))
        raise ValueError(f"material {name!r} is not in {scope}; valid names: {valid}")
    if len(hits) > 1:
        where = ", ".join(repr(m.table) for m in hits)
        raise ValueError(f"material {name!r} is in several tables ({where}); pass table=... to choose")
    return hits[0]


def material_medium(name: str, eta=None, g=None, fresnel: str = "poly", *, table: str | None = None):
    """A :class:`jaxsss.medium.Medium` for a measured material.

    Args:
        name: material name (see :func:`material`).
        eta: relative index ``n_inside / n_outside``; defaults to the table's value. Required for tables without
            one (``narasimhan2006``): a missing eta raises ``ValueError``.
        g: optional Henyey-Greenstein anisotropy in ``(-1, 1)`` (gives the medium ``sigma_s`` and ``sigma_t``).
        fresnel: ``F_dr`` method, ``"poly"`` or ``"exact"``.
        table: restrict the lookup to one table.

    Returns:
        The medium, with ``sigma_a`` and ``sigma_s_prime`` in 1/mm, channels R, G, B.
    """
    return material(name, table).medium(eta=eta, g=g, fresnel=fresnel)
