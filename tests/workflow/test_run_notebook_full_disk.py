"""The notebook runner on a full disk: no half-written executed notebook under its name, the cause first.

Each run is workflow/scripts/run_notebook.py's ``main`` in a subprocess in which one write fails with
ENOSPC: papermill's save of the executed notebook (half of it reaching the file first, as a full disk
leaves it), or the text log.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_run_notebook import HEADER, ROOT

#: Every test runs a notebook in a kernel (seconds): out of `make test-fast`.
pytestmark = pytest.mark.slow

#: Runs run_notebook.main(source, executed, html, parameters[, log]) with ENOSPC from the n-th call of
#: papermill's local write on (argv[1]; 0: never): half of that one reaches the file, the later ones
#: leave it empty, as on a disk that stays full. With argv[2] == "log", the runner's log writer fails.
FULL_DISK = """
import errno, os, sys
sys.path.insert(0, {scripts!r})
import papermill.iorw
import run_notebook

fail_at, what, *arguments = sys.argv[1:]
calls = [0]

def full(path):
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

original = papermill.iorw.LocalHandler.write
def write(self, buf, path):
    calls[0] += 1
    if what == "notebook" and int(fail_at) and calls[0] >= int(fail_at):
        with open(path, "w", encoding="utf-8") as handle:
            handle.write(buf[: len(buf) // 2] if calls[0] == int(fail_at) else "")  # what reached the disk
        raise full(path)
    return original(self, buf, path)
papermill.iorw.LocalHandler.write = write

if what == "log":
    def no_log(log, text):
        raise full(log)
    run_notebook._write_log = no_log

sys.exit(run_notebook.main(*arguments))
"""


def run_full(tmp_path: Path, cells: list[str], fail_at: int, what: str = "notebook", log: bool = False):
    source = tmp_path / "stage.py"
    body = [HEADER, '# %% tags=["parameters"]\n' + cells[0]] + [f"# %%\n{cell}" for cell in cells[1:]]
    source.write_text("\n".join(body))
    executed, html = tmp_path / "notebooks" / "stage.ipynb", tmp_path / "notebooks" / "stage.html"
    executed.parent.mkdir()
    executed.write_text('{"cells": [], "from": "an earlier run"}')  # an older notebook under the final name
    arguments = [str(source), str(executed), str(html), json.dumps({})]
    if log:
        arguments.append(str(tmp_path / "logs" / "stage.log"))
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("MPLBACKEND", None)
    process = subprocess.run(
        [sys.executable, "-c", FULL_DISK.format(scripts=str(ROOT / "workflow" / "scripts")), str(fail_at), what,
         *arguments], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    return process, source, executed, html


CELLS = ["x = 1\n", "y = x + 1\n", "print(y)\n"]


@pytest.mark.parametrize("fail_at", [1, 3, 5])
def test_a_full_disk_leaves_no_half_written_notebook_and_says_so_after_the_cause(tmp_path, fail_at):
    """Papermill's n-th save of the executed notebook fails half-way: nothing is left under the notebook's
    name (neither the truncated file nor the earlier run's), no temporary file stays, and the first line
    is the cause."""
    process, source, executed, html = run_full(tmp_path, CELLS, fail_at)
    assert process.returncode == 1
    lines = process.stderr.splitlines()
    assert lines[0].startswith(f"{source} failed: OSError: [Errno 28] No space left on device"), process.stderr
    assert lines[1] == f"(while running the notebook; no executed notebook is kept: {executed} could not be written " \
                       "whole)", process.stderr
    assert not executed.exists()
    assert not html.exists()
    assert sorted(path.name for path in executed.parent.iterdir()) == []  # no temporary file left behind


def test_the_same_notebook_without_a_full_disk_is_kept_whole(tmp_path):
    """The control: with no failing write the run succeeds and the executed notebook is this run's, whole."""
    process, _, executed, html = run_full(tmp_path, CELLS, fail_at=0)
    assert process.returncode == 0, process.stderr
    notebook = json.loads(executed.read_text())
    assert "from" not in notebook and "".join(notebook["cells"][-1]["source"]) == "print(y)"
    assert html.is_file()
    assert sorted(path.name for path in executed.parent.iterdir()) == ["stage.html", "stage.ipynb"]


def test_a_failed_cell_keeps_its_whole_notebook_when_the_disk_is_not_full(tmp_path):
    """A cell that raises: papermill saves the notebook with the traceback whole, and it is kept."""
    process, source, executed, _ = run_full(tmp_path, ["x = 1\n", "raise ValueError('bad value')\n"], fail_at=0)
    assert process.returncode == 1
    assert process.stderr.splitlines()[0] == f"{source} failed: ValueError: bad value"
    assert "ValueError" in executed.read_text() and json.loads(executed.read_text())["cells"]


@pytest.mark.parametrize("cells, cause", [
    (CELLS, "OSError: [Errno 28] No space left on device"),
    (["x = 1\n", "raise ValueError('bad value')\n"], "ValueError: bad value"),
])
def test_a_log_that_cannot_be_written_still_gives_the_cause_first(tmp_path, cells, cause):
    """The text log cannot be written (the disk is full): the run fails, the cause first, no traceback; a failed
    cell stays the cause, and the tools' messages come to the console instead."""
    process, source, _, _ = run_full(tmp_path, cells, fail_at=0, what="log", log=True)
    assert process.returncode == 1
    lines = process.stderr.splitlines()
    assert lines[0].startswith(f"{source} failed: {cause}"), process.stderr
    assert "Traceback" not in process.stderr.split("output of the run:")[0]
    assert any("could not be written to" in line for line in lines), process.stderr
