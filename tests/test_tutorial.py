"""examples/tutorial.ipynb runs from top to bottom (nbclient, a fresh kernel, offline) and
is kept in git without outputs."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "tutorial.ipynb"


def test_the_tutorial_is_stored_without_outputs():
    nb = json.loads(NOTEBOOK.read_text(encoding="utf-8"))
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert code, "the tutorial has no code"
    for cell in code:
        assert cell["outputs"] == [] and cell["execution_count"] is None, cell["source"][:2]


def test_every_cell_of_the_tutorial_runs(monkeypatch):
    import img2dmp

    # The kernel imports the img2dmp under test (the one this process imported), whatever
    # the kernel's working directory (the notebook's folder) makes of a relative path.
    src = str(Path(img2dmp.__file__).resolve().parents[1])
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(filter(None, [src, os.environ.get("PYTHONPATH")]))
    )
    nbformat = pytest.importorskip("nbformat", reason="nbformat is in the dev extra")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is in the dev extra")
    pytest.importorskip("ipykernel", reason="ipykernel is in the dev extra")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=240,  # per cell
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOK.parent)}},  # it reads samples/
    )
    client.execute()  # a cell that raises fails the test (CellExecutionError)
    text = "".join(
        o.get("text", "")
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
        if o.output_type == "stream"
    )
    assert "digits-real" in text and "refinement steps: 30" in text
    assert "flags: []" in text  # the sample photo is read as one digit
    assert "shifted: off a translation by" in text
    assert "StrokePrediction(" in text and "strokes per letter: [" in text  # section 6
    figures = sum(
        "image/png" in o.get("data", {})
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
    )
    # Every plt.show() draws: no library call (training writes its curve) may switch the
    # notebook's backend away from under it.
    shows = sum(c.source.count("plt.show()") for c in nb.cells if c.cell_type == "code")
    assert figures == shows >= 4, (figures, shows)
    assert not NOTEBOOK.with_name("tutorial.nbconvert.ipynb").exists()
