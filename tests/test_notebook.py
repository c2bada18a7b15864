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


def test_the_notebook_run_twice_at_once_in_one_folder_loses_nothing(tmp_path):
    """Two students (two tabs, two terminals) run the notebook at the same time in one folder: both
    finish without an error, and each run's recording is a file of its own, whole (all its
    generations, its summary, its run): neither overwrites or truncates the other's."""
    import re
    import subprocess

    from conftest import wait_or_kill

    from lab.recording.replay import read_recording

    code = """if True:
        import sys, nbclient, nbformat
        nb = nbformat.read(sys.argv[1], as_version=4)
        nbclient.NotebookClient(nb, timeout=int(sys.argv[3]), kernel_name="python3",
                                resources={"metadata": {"path": sys.argv[2]}}).execute()
        nbformat.write(nb, sys.argv[4])
    """
    folder, temp = tmp_path / "class", tmp_path / "tmp"  # the folder both run in; the kernels' temp dir
    folder.mkdir()
    temp.mkdir()
    env = {**os.environ, "TMPDIR": str(temp),
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    outs = [tmp_path / f"run{k}.ipynb" for k in (1, 2)]
    procs = [subprocess.Popen([sys.executable, "-c", code, str(NOTEBOOK), str(folder), str(CELL_TIMEOUT * 2), str(out)],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for out in outs]
    errors = [wait_or_kill(p, TOTAL * 3)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errors[0][-3000:] + errors[1][-3000:]
    paths = []
    for out in outs:
        cells = nbformat.read(out, as_version=4).cells
        printed = "".join(o.get("text", "") for c in cells if c.cell_type == "code" for o in c.outputs)
        assert "the notebook ran in" in printed
        [path] = re.findall(r"^(\S+\.rrd): generations 0-149", printed, re.M)
        paths.append(path)
    assert paths[0] != paths[1] and all(p.startswith(str(temp)) for p in paths), paths
    runs = [read_recording(p) for p in paths]
    assert [(r.salvaged, r.last_generation) for r in runs] == [(False, 149)] * 2
    assert runs[0].protocol["run_id"] != runs[1].protocol["run_id"]  # each file is its own run's
    assert sorted(os.listdir(folder)) == []  # nothing written into the folder the notebooks run in
