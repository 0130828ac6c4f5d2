"""Execute every notebook under notebooks/ end to end (at a small size: JAXSSS_NOTEBOOK_QUICK=1).

One test class per notebook: ``make test`` distributes the suite with ``--dist loadscope``, whose unit is a module or
a class, so each notebook (each runs in its own kernel process and shares nothing with the others) can go to
whichever worker is free; as one parametrized test they were one 165 s unit on one worker (tests/conftest.py,
``HEAVY_FIRST``)."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks_to_run():
    assert NOTEBOOKS, "notebooks/ holds no notebook: the suite is meant to execute them"


def execute_notebook(path: Path, monkeypatch) -> None:
    monkeypatch.setenv("JAXSSS_NOTEBOOK_QUICK", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


def _notebook_class(path: Path) -> type:
    @pytest.mark.notebook
    def test_executes(self, monkeypatch):
        execute_notebook(path, monkeypatch)

    return type(f"TestNotebook_{path.stem}", (), {"test_executes": test_executes, "path": path})


for _path in NOTEBOOKS:
    _cls = _notebook_class(_path)
    globals()[_cls.__name__] = _cls
