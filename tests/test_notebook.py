"""examples/evolve_an_arm.ipynb runs from top to bottom on the venv's own python kernel (ipykernel's
`python3`), within a time limit, and is committed without outputs (it is a source, not a result)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="the dev extra (pip install -e '.[dev]') runs the notebook")
nbclient = pytest.importorskip("nbclient")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "evolve_an_arm.ipynb"
CELL_TIMEOUT = 180  # s, one cell; the whole notebook takes about half a minute on 2 cores
TOTAL = 300  # s


def test_the_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code), \
        "clear the outputs before committing (Jupyter: Edit > Clear outputs of all cells)"
    assert nb.metadata.kernelspec.name == "python3"


def test_the_notebook_runs_without_an_error(tmp_path, monkeypatch):
    from jupyter_client.kernelspec import KernelSpecManager

    spec = KernelSpecManager().get_kernel_spec("python3")  # ipykernel's: "python" is this interpreter
    assert spec.argv[0] in ("python", "python3", sys.executable), spec.argv
    nb = nbformat.read(NOTEBOOK, as_version=4)
    # the kernel imports this checkout's packages, whatever the working directory
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    client = nbclient.NotebookClient(nb, timeout=CELL_TIMEOUT, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    t0 = time.monotonic()
    client.execute()  # CellExecutionError, with the cell and its traceback, on any error
    seconds = time.monotonic() - t0
    assert seconds < TOTAL, f"the notebook took {seconds:.0f} s"
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    printed = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    assert "the notebook ran in" in printed
