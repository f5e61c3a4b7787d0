"""Run one stage: a jupytext percent-format notebook, executed by papermill, rendered to HTML.

    python workflow/scripts/run_notebook.py SOURCE.py EXECUTED.ipynb OUTPUT.html PARAMETERS_JSON

The executed notebook is written as papermill goes (it is the rule's log and is
kept when a cell fails, with the traceback in it); the HTML is written only
after the notebook ran through, atomically. One process does all three steps
(jupytext, papermill, nbconvert), which saves two interpreter start-ups per job.
"""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path


def _load_writer():
    """The library's one atomic writer, :mod:`sdm.io`, loaded from its file.

    Loaded by path rather than ``import sdm.io`` because importing the ``sdm``
    package imports torch (about 2 s per job); ``sdm/io.py`` uses only the
    standard library.
    """
    source = Path(__file__).resolve().parents[2] / "src" / "sdm" / "io.py"
    spec = importlib.util.spec_from_file_location("sdm_io_for_runner", source)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(source: str, executed: str, html: str, parameters: str) -> int:
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
            parameters=json.loads(parameters),
            kernel_name="python3",
            progress_bar=False,
            log_output=False,
        )
    except papermill.PapermillExecutionError as error:
        print(f"{source} failed in cell {error.exec_count}: {error.ename}: {error.evalue}", file=sys.stderr)
        print(f"the executed notebook, with the traceback, is {executed}", file=sys.stderr)
        return 1
    body, _ = HTMLExporter().from_notebook_node(result)
    _load_writer().write_text(html, body)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    sys.exit(main(*sys.argv[1:]))
