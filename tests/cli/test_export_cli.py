"""``jaxsss export`` (jaxsss.cli.export), through its own parser: files written, refusals naming the key."""

import json
from pathlib import Path

import pytest

from jaxsss.cli import export as export_cli
from jaxsss.cli._common import CLIError, Parser

SCENE = Path(__file__).parents[1] / "export" / "references" / "skin1_sphere.toml"


def _run(argv, capsys):
    parser = Parser(prog="jaxsss")
    export_cli.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["export", *map(str, argv)])
    status = args.run(args)
    return status, capsys.readouterr().out


@pytest.mark.parametrize("target, suffix", [("mitsuba", ".xml"), ("pbrt-v4", ".pbrt")])
def test_export_writes_scene_and_mesh(tmp_path, capsys, target, suffix):
    status, out = _run([SCENE, "--to", target, "--out", tmp_path, "--spp", "32", "--json"], capsys)
    assert status == 0
    doc = json.loads(out)
    assert doc["scene"] == str(tmp_path / f"scene{suffix}") and doc["warnings"] == []
    assert Path(doc["scene"]).is_file() and Path(doc["meshes"][0]).is_file()
    assert "32" in Path(doc["scene"]).read_text()


def test_export_burley_report(tmp_path, capsys):
    status, out = _run([SCENE, "--to", "pbrt-v4", "--out", tmp_path, "--burley", "--json"], capsys)
    doc = json.loads(out)["burley"]
    assert status == 0 and doc["g"] == 0.0 and doc["eta"] == 1.0
    assert all(0 < a < 1 for a in doc["A"]) and all(d > 0 for d in doc["d"])
    status, out = _run([SCENE, "--to", "pbrt-v4", "--out", tmp_path, "--burley"], capsys)
    assert "Christensen-Burley" in out and "shape d [mm]" in out


def test_export_refuses_what_it_cannot_represent(tmp_path, capsys):
    bad = tmp_path / "bg.toml"
    bad.write_text(SCENE.read_text() + "\n[output]\nbackground = 0.2\n")
    with pytest.raises(ValueError, match=r"^\[output.background\] \[0.2, 0.2, 0.2\] is not black"):
        _run([bad, "--to", "mitsuba", "--out", tmp_path / "o"], capsys)
    with pytest.raises(CLIError, match=r"--spp=0 is outside the allowed range \[1, inf\)"):
        _run([SCENE, "--to", "pbrt-v4", "--out", tmp_path / "o", "--spp", "0"], capsys)
    with pytest.raises(CLIError, match="invalid choice"):
        _run([SCENE, "--to", "cycles", "--out", tmp_path], capsys)
