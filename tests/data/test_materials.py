"""Measured-material tables: contents, lookup, media, and the CSV parser's error messages."""

from importlib import resources

import numpy as np
import pytest

from jaxsss.data import MATERIAL_TABLES, MeasuredMaterial, list_materials, material, material_medium
from jaxsss.data import materials as materials_module
from jaxsss.data.materials import _parse_table
from jaxsss.medium import Medium


def test_tables_have_the_published_sizes_and_citations():
    assert len(list_materials("jensen2001")) == 12
    assert len(list_materials("narasimhan2006")) == 35
    assert list_materials() == list_materials("jensen2001") + list_materials("narasimhan2006")
    assert "SIGGRAPH 2001" in material("marble").citation and "Jensen" in material("marble").citation
    assert "SIGGRAPH 2006" in material("espresso").citation and "Narasimhan" in material("espresso").citation


@pytest.mark.parametrize("table, year", [("jensen2001", "2001"), ("narasimhan2006", "2006")])
def test_shipped_csv_keeps_its_citation_header(table, year):
    text = resources.files("jaxsss.data").joinpath(MATERIAL_TABLES[table].filename).read_text()
    header = [line for line in text.splitlines() if line.startswith("#")]
    assert header and f"SIGGRAPH {year}" in " ".join(header)


def test_values_and_units():
    # Jensen et al. 2001, Fig. 5 as tabulated by pbrt: marble, 1/mm.
    marble = material("marble")
    np.testing.assert_array_equal(marble.sigma_a, [0.0021, 0.0041, 0.0071])
    np.testing.assert_array_equal(marble.sigma_s_prime, [2.19, 2.62, 3.00])
    assert marble.eta == 1.5 and marble.table == "jensen2001"
    espresso = material("espresso")
    np.testing.assert_array_equal(espresso.sigma_a, [4.7984, 6.5751, 8.8493])
    assert espresso.eta is None and espresso.table == "narasimhan2006"
    for name in list_materials():
        m = material(name)
        assert m.sigma_a.shape == m.sigma_s_prime.shape == (3,)
        assert np.all(m.sigma_a >= 0) and np.all(m.sigma_s_prime >= 0)
        assert np.all(m.sigma_a + m.sigma_s_prime > 0)


def test_records_are_immutable():
    m = material("skin1")
    assert isinstance(m, MeasuredMaterial)
    with pytest.raises(ValueError):
        m.sigma_a[0] = 1.0
    with pytest.raises(AttributeError):
        m.eta = 2.0


@pytest.mark.parametrize("spelling", ["Marble", "MARBLE", " marble "])
def test_lookup_is_case_insensitive(spelling):
    assert material(spelling) is material("marble")


def test_spaces_and_hyphens_match_underscores():
    assert material("Regular Milk") is material("regular_milk") is material("regular-milk")


def test_unknown_name_lists_valid_names():
    with pytest.raises(ValueError, match="not in any table") as exc:
        material("unobtainium")
    assert "marble" in str(exc.value) and "espresso" in str(exc.value)
    with pytest.raises(ValueError, match="table 'jensen2001'") as exc:
        material("espresso", table="jensen2001")
    assert "espresso" not in str(exc.value).split("valid names:")[1]


def test_unknown_table():
    with pytest.raises(ValueError, match="'jensen2001', 'narasimhan2006'"):
        list_materials("pbrt")


def test_name_in_two_tables_is_ambiguous(monkeypatch):
    a = _parse_table(_CSV_HEADER + "\nwax,1,1,1,0.1,0.1,0.1,1.3\n", "a.csv", "jensen2001", "A")
    b = _parse_table(_CSV_HEADER + "\nwax,2,2,2,0.2,0.2,0.2,1.3\n", "b.csv", "narasimhan2006", "B")
    monkeypatch.setattr(materials_module, "_load", {"jensen2001": a, "narasimhan2006": b}.__getitem__)
    with pytest.raises(ValueError, match="several tables"):
        material("wax")
    assert material("wax", table="narasimhan2006").citation == "B"


def test_material_medium():
    m = material_medium("marble", g=0.5)
    assert isinstance(m, Medium)
    np.testing.assert_array_equal(m.sigma_a, [0.0021, 0.0041, 0.0071])
    assert float(m.eta) == 1.5 and float(m.g) == 0.5
    assert float(material_medium("marble", eta=1.3).eta) == 1.3
    assert material_medium("marble", fresnel="exact").fresnel == "exact"


def test_narasimhan_medium_requires_eta():
    with pytest.raises(ValueError, match="no tabulated eta"):
        material_medium("espresso")
    assert float(material_medium("espresso", eta=1.33).eta) == 1.33


# --- The parser ------------------------------------------------------------------------------------------------------
_CSV_HEADER = "# a citation\nname,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g,sigma_a_b,eta"


def test_parser_reads_a_good_table():
    got = _parse_table(_CSV_HEADER + "\n\nWax, 1, 2, 3, 0.1, 0.2, 0.3, 1.4\n", "t.csv", "t", "cite")
    assert list(got) == ["wax"]
    np.testing.assert_array_equal(got["wax"].sigma_s_prime, [1, 2, 3])
    assert got["wax"].eta == 1.4 and got["wax"].citation == "cite"


BAD_ROWS = {
    # row text, expected "file:line:column" prefix (row is line 3), and a fragment of the message.
    "not_a_number": ("wax,1,2,3,0.1,abc,0.3,1.3", "bad.csv:3:6:", "'sigma_a_g': 'abc' is not a number"),
    "negative": ("wax,1,-2,3,0.1,0.2,0.3,1.3", "bad.csv:3:3:", "'-2' is outside the allowed range [0, inf)"),
    "nan": ("wax,nan,2,3,0.1,0.2,0.3,1.3", "bad.csv:3:2:", "'nan' is outside"),
    "inf": ("wax,1,2,3,0.1,0.2,inf,1.3", "bad.csv:3:7:", "'inf' is outside"),
    "eta_zero": ("wax,1,2,3,0.1,0.2,0.3,0", "bad.csv:3:8:", "'eta': '0' is outside the allowed range (0, inf)"),
    "empty_cell": ("wax,1,,3,0.1,0.2,0.3,1.3", "bad.csv:3:3:", "'' is not a number"),
    "empty_name": (",1,2,3,0.1,0.2,0.3,1.3", "bad.csv:3:1:", "'name' is empty"),
    "too_few_cells": ("wax,1,2,3,0.1,0.2", "bad.csv:3:", "6 cells, the header has 8"),
}


@pytest.mark.parametrize("row, where, fragment", BAD_ROWS.values(), ids=BAD_ROWS.keys())
def test_parser_errors_name_file_line_and_column(row, where, fragment):
    with pytest.raises(ValueError) as exc:
        _parse_table(_CSV_HEADER + "\n" + row + "\n", "bad.csv", "t", "c")
    message = str(exc.value)
    assert message.startswith(where), message
    assert fragment in message


def test_parser_rejects_duplicates_and_missing_columns():
    with pytest.raises(ValueError, match=r"^bad.csv:4:1: duplicate material name 'wax'"):
        _parse_table(_CSV_HEADER + "\nwax,1,1,1,1,1,1,1\nWAX,1,1,1,1,1,1,1\n", "bad.csv", "t", "c")
    with pytest.raises(ValueError, match=r"^bad.csv:1: header lacks column\(s\) sigma_a_b"):
        _parse_table("name,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g\n", "bad.csv", "t", "c")
    with pytest.raises(ValueError, match="no header row"):
        _parse_table("# only comments\n", "bad.csv", "t", "c")
