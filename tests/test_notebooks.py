"""Notebooks are narrative: stored without outputs, no test-style asserts, and when
executed top to bottom they run without error and show at least three figures inline."""

from __future__ import annotations

import ast
import functools
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from IPython.core.inputtransformer2 import TransformerManager
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
MIN_FIGURES = 3


def _code_cells(nb: nbformat.NotebookNode) -> list[nbformat.NotebookNode]:
    return [c for c in nb.cells if c.cell_type == "code"]


@functools.cache
def _executed(path: Path) -> nbformat.NotebookNode:
    """The notebook run top to bottom from its own directory (once per session: the tests
    below share it)."""
    nb = nbformat.read(path, as_version=4)
    NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    ).execute()
    return nb


def test_there_are_notebooks() -> None:
    assert any(p.name == "01_rig_and_loop.ipynb" for p in NOTEBOOKS)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_stored_without_outputs(path: Path) -> None:
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    for cell in _code_cells(nb):
        assert not cell.outputs and cell.execution_count is None, f"{path.name} has outputs"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_has_no_asserts(path: Path) -> None:
    """A notebook explains; checking the library is the tests' job."""
    nb = nbformat.read(path, as_version=4)
    to_python = TransformerManager().transform_cell  # `%matplotlib inline` etc. → Python
    for i, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        tree = ast.parse(to_python(cell.source), filename=f"{path.name}, cell {i}")
        asserts = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Assert)]
        assert not asserts, f"{path.name}, cell {i} ({cell.get('id')}): assert on line(s) {asserts}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path: Path) -> None:
    nb = _executed(path)
    errors = [o for c in _code_cells(nb) for o in c.outputs if o.output_type == "error"]
    assert not errors, f"{path.name}: {errors[0].ename}: {errors[0].evalue}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_shows_figures(path: Path) -> None:
    """At least three figures shown inline (PNG outputs of the executed notebook, whichever
    way a cell shows them: ``plt.show()``, a figure as the cell's value, ``display``)."""
    nb = _executed(path)
    figures = sum(
        "image/png" in o.get("data", {})
        for c in _code_cells(nb)
        for o in c.outputs
        if o.output_type in ("display_data", "execute_result")
    )
    assert figures >= MIN_FIGURES, f"{path.name} shows {figures} figures, want >= {MIN_FIGURES}"


def _figures(nb: nbformat.NotebookNode) -> int:
    return sum(
        "image/png" in o.get("data", {})
        for c in _code_cells(nb)
        for o in c.outputs
        if o.output_type in ("display_data", "execute_result")
    )


def test_a_notebook_runs_with_jupyter_execute_away_from_the_repository(tmp_path: Path) -> None:
    """``jupyter execute NAME.ipynb`` (the README's command; the venv's ``jupyter-execute``)
    on a copy of a notebook in a directory with no ``plants/`` near it: the notebook finds the
    example files itself (the package's copies), whatever its working directory."""
    jupyter = Path(sys.executable).with_name("jupyter")
    assert jupyter.is_file(), f"no {jupyter}: pip install -e .[notebooks] installs it"
    nb_path = tmp_path / "elsewhere" / "01_rig_and_loop.ipynb"
    nb_path.parent.mkdir()
    shutil.copy(next(p for p in NOTEBOOKS if p.name == nb_path.name), nb_path)
    assert not any((d / "plants").exists() for d in (nb_path.parent, *nb_path.parents))
    run = subprocess.run(
        [str(jupyter), "execute", "--inplace", "elsewhere/" + nb_path.name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    nb = nbformat.read(nb_path, as_version=4)
    errors = [o for c in _code_cells(nb) for o in c.outputs if o.output_type == "error"]
    assert not errors and _figures(nb) >= MIN_FIGURES
