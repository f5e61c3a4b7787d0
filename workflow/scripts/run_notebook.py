"""Run one stage: a jupytext percent-format notebook, executed by papermill, rendered to HTML.

    python workflow/scripts/run_notebook.py SOURCE.py EXECUTED.ipynb OUTPUT.html PARAMETERS_JSON

The executed notebook is written as papermill goes (it is the rule's log and is
kept when a cell fails, with the traceback in it); the HTML is written only
after the notebook ran through, atomically. One process does all three steps
(jupytext, papermill, nbconvert), which saves two interpreter start-ups per job.
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path


def main(source: str, executed: str, html: str, parameters: str | dict, stderr_log: str | None = None) -> int:
    """Run ``source`` with ``parameters`` (a dict or its JSON); 0 on success, 1 when a cell failed.

    With ``stderr_log``, everything the tools and the kernel write to stderr goes to that file,
    and only the one-line cause of a failure reaches this process's stderr.
    """
    if isinstance(parameters, str):
        parameters = json.loads(parameters)
    if stderr_log is None:
        return _run(source, executed, html, parameters, sys.stderr)
    Path(stderr_log).parent.mkdir(parents=True, exist_ok=True)
    console = os.fdopen(os.dup(2), "w")
    with open(stderr_log, "w") as log:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(log.fileno(), 2)
        try:
            return _run(source, executed, html, parameters, console)
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            console.close()


def _run(source: str, executed: str, html: str, parameters: dict, console) -> int:
    import jupytext
    import papermill
    from nbconvert import HTMLExporter

    notebook = jupytext.read(source)
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    Path(executed).parent.mkdir(parents=True, exist_ok=True)
    try:
        result = papermill.execute_notebook(
            notebook,
            executed,
            parameters=parameters,
            kernel_name="python3",
            progress_bar=False,
            log_output=False,
        )
    except papermill.PapermillExecutionError as error:
        for stream in (console, sys.stderr):
            print(f"{source} failed in cell {error.exec_count}: {error.ename}: {error.evalue}", file=stream)
            print(f"the executed notebook, with the traceback, is {executed}", file=stream)
            stream.flush()
        return 1
    body, _ = HTMLExporter().from_notebook_node(result)
    target = Path(html)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".html", dir=target.parent)
    with os.fdopen(handle, "w", encoding="utf-8") as stream:
        stream.write(body)
    os.replace(temporary, target)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    sys.exit(main(*sys.argv[1:]))
