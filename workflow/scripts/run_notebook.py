"""Run one stage: a jupytext percent-format notebook, executed by papermill, rendered to HTML.

    python workflow/scripts/run_notebook.py SOURCE.py EXECUTED.ipynb OUTPUT.html PARAMETERS_JSON

The executed notebook is written as papermill goes, to a hidden temporary file
beside EXECUTED.ipynb (``.EXECUTED.<random>.tmp.ipynb``), which becomes
EXECUTED.ipynb when it holds a whole notebook: the run finished, or it stopped (a
cell failed: the traceback is in it; the kernel died) after papermill last saved
it whole. A notebook papermill could not write whole (a full disk) is removed, so
EXECUTED.ipynb is never half-written, and an older one is removed at the start, so
it is always this run's. (It is the rule's log, kept when the stage fails.) The
HTML is written only after the notebook ran through, atomically (:mod:`sdm.io`).
One process does all three steps (jupytext, papermill, nbconvert), which saves two
interpreter start-ups per job. The kernel is ipykernel's, started without its
debugger (workflow/scripts/kernel.py), which saves a third of its start-up.

On failure the FIRST line printed (stderr) is the one-line cause::

    notebooks/sky.py failed: SDMInputError: results/sky/sky.bin: array 'point_depth' fails its CRC-32 check; ...

then where it happened and the executed notebook to open for the traceback;
anything the libraries printed meanwhile comes after, colour codes stripped (in
the text log when one is given; on the console when it cannot be written).
Exit status 1.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import resource
import signal
import sys
import tempfile
from pathlib import Path

from code_deps import library_io  # sdm/io.py, the atomic writer, loaded without importing sdm (torch)

#: ANSI escape sequences (colours, cursor moves) as IPython puts them in tracebacks and messages.
ANSI = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b[@-Z\\-_]")


def strip_ansi(text: str) -> str:
    return ANSI.sub("", text)


#: How often a kernel that dies or stays silent while starting is started again. Jupyter picks the
#: kernel's ports before the kernel binds them, so kernels started at the same moment by parallel jobs
#: can race for a port (jupyter/jupyter_client#154): a lost race is a start-up failure, before any cell
#: ran, and starting afresh is safe.
KERNEL_STARTS = 3
KERNEL_START_FAILURES = ("Kernel died before replying to kernel_info", "Kernel didn't respond in")


def execute_with_kernel_restarts(execute, *args, **kwargs):
    """``execute(*args, **kwargs)`` (papermill's ``execute_notebook``), started again after a kernel start-up
    failure, at most KERNEL_STARTS times in all; any other error, or the last start-up failure, is raised."""
    for attempt in range(1, KERNEL_STARTS + 1):
        try:
            return execute(*args, **kwargs)
        except RuntimeError as error:
            started = not any(message in str(error) for message in KERNEL_START_FAILURES)
            if started or attempt == KERNEL_STARTS:
                raise
            print(f"the kernel failed to start ({error}); starting it again", file=sys.stderr, flush=True)


#: The kernel's launcher: ipykernel's kernel without its debugger (see workflow/scripts/kernel.py).
KERNEL_LAUNCHER = Path(__file__).resolve().with_name("kernel.py")


def kernel_manager():
    """The kernel manager class papermill starts the kernel with: nbclient's (jupyter_client's
    ``AsyncKernelManager``), the kernel spec's command with :data:`KERNEL_LAUNCHER` in place of
    ``-m ipykernel_launcher``; a kernel spec that starts anything else is started as it says."""
    from jupyter_client.manager import AsyncKernelManager

    class StageKernelManager(AsyncKernelManager):
        def format_kernel_cmd(self, extra_arguments=None):
            command = super().format_kernel_cmd(extra_arguments)
            for i in range(1, len(command) - 1):
                if command[i:i + 2] == ["-m", "ipykernel_launcher"]:
                    return command[:i] + [str(KERNEL_LAUNCHER)] + command[i + 2:]
            return command

    return StageKernelManager


def _whole_notebook(path: Path) -> bool:
    """Whether ``path`` holds a whole notebook (JSON with its cells): a truncated write never parses."""
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(content, dict) and isinstance(content.get("cells"), list)


def execute_into(executed: str | Path, run):
    """``run(temporary)`` with papermill writing the executed notebook to a temporary file beside ``executed``.

    The temporary file becomes ``executed`` (atomically, :func:`sdm.io.write_atomic`) when it holds a whole
    notebook: ``run`` returned, or raised after papermill last saved it whole (a failed cell, a dead kernel),
    in which case the error is raised again afterwards. When ``run`` raised and the file is not whole (a
    write cut short by a full disk), it is removed, ``executed`` is left absent and the error raised.
    """
    outcome = {}

    def write(temporary: Path) -> None:
        try:
            outcome["result"] = run(temporary)
        except Exception as error:
            if not _whole_notebook(temporary):
                raise  # write_atomic removes the temporary file
            outcome["error"] = error

    library_io().write_atomic(executed, write)
    if "error" in outcome:
        raise outcome["error"]
    return outcome["result"]


@contextlib.contextmanager
def captured_output():
    """Collect everything written to this process's stdout and stderr (file descriptors 1 and 2, so the
    kernel's and the libraries' output too) into a temporary file; yields a function returning it so far."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    with tempfile.TemporaryFile(mode="w+b") as sink:
        try:
            for fd in (1, 2):
                os.dup2(sink.fileno(), fd)

            def read() -> str:
                sys.stdout.flush()
                sys.stderr.flush()
                sink.seek(0)
                return sink.read().decode("utf-8", errors="replace")

            yield read
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)


def one_line_cause(source: str, ename: str, evalue: str) -> tuple[str, list[str]]:
    """``"<source> failed: <ename>: <first line of evalue>"`` and the rest of the message's lines."""
    lines = [line.rstrip() for line in strip_ansi(str(evalue)).strip().splitlines()] or [""]
    head = f"{source} failed: {strip_ansi(ename)}: {lines[0]}" if lines[0] else f"{source} failed: {strip_ansi(ename)}"
    return head, [line for line in lines[1:] if line]


def report_failure(head: str, details: list[str], where: str, noise: str, log: Path | None = None) -> None:
    """Print the cause first, then where to look, then what the libraries printed (colour codes stripped).

    With ``log``, what the libraries printed goes to that file (after the cause) and the console gets
    the cause and where to look only.
    """
    out = [head, *(f"    {line}" for line in details), where]
    noise = strip_ansi(noise).strip()
    if log is not None:
        try:
            _write_log(log, "\n".join(out + (["output of the run:", noise] if noise else [])))
            out.append(f"(the tools' messages are in {log})")
            noise = ""
        except OSError as error:  # a full disk: the messages come to the console, after the cause
            out.append(f"(the tools' messages could not be written to {log}: {error})")
    if noise:
        out += ["output of the run:", noise]
    print("\n".join(out), file=sys.stderr, flush=True)


def _write_log(log: Path, text: str) -> None:
    log.parent.mkdir(parents=True, exist_ok=True)
    library_io().write_text(log, text + "\n" if text else "")


def stop_on_termination() -> None:
    """SIGTERM and SIGHUP (how Snakemake, a cluster and a closed terminal stop a job) raise ``SystemExit`` in this
    process, as Ctrl-C raises ``KeyboardInterrupt``: the temporary notebook is removed on the way out
    (:func:`sdm.io.write_atomic`). Only the main thread can set handlers; elsewhere nothing changes."""
    with contextlib.suppress(ValueError):
        for number in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(number, lambda received, frame: sys.exit(128 + received))


def remove_stale_temporaries(executed: str | Path) -> list[Path]:
    """Remove the hidden temporary notebooks of ``executed`` (``.<stem>.<random>.tmp.ipynb``) that an earlier run
    of this job left behind when it was killed beyond catching (SIGKILL, a lost node); the removed paths."""
    executed = Path(executed)
    stale = sorted(executed.parent.glob(f".{executed.stem}.*.tmp{executed.suffix}"))
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def _values(source: str) -> dict[str, tuple[int, int, int, int]]:
    """Each ``name = value`` statement of a cell: name -> where its value is (first and last line, counted from 0;
    start and end column in UTF-8 bytes, as :mod:`ast` gives them)."""
    import ast

    return {node.targets[0].id: (node.value.lineno - 1, node.value.col_offset, node.value.end_lineno - 1,
                                 node.value.end_col_offset)
            for node in ast.parse(source).body
            if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)}


def page(executed):
    """The notebook as its page shows it: the parameters cell holds the values this job ran with.

    papermill runs the notebook's parameters cell (its defaults, each with a comment that says what it is), then
    the cell it injects (this job's values). On the page the parameters cell shows each default replaced by this
    job's value, its comment kept, and a value the notebook has no default for added at its end; papermill's cell
    is left out, so the reader sees one cell, true for this job. ``executed`` (the executed notebook, the job's
    record) is not changed: the page is drawn from a copy.
    """
    import copy

    notebook = copy.deepcopy(executed)
    tags = [set(cell.get("metadata", {}).get("tags", [])) for cell in notebook.cells]
    defaults = [i for i, cell_tags in enumerate(tags) if "parameters" in cell_tags]
    injected = [i for i, cell_tags in enumerate(tags) if "injected-parameters" in cell_tags]
    if len(defaults) != 1 or len(injected) != 1:
        return notebook
    cell = notebook.cells[defaults[0]]
    job = notebook.cells[injected[0]].source
    job_lines = job.encode().splitlines()
    given = {name: b"\n".join([job_lines[first][start:], *job_lines[first + 1:last], job_lines[last][:end]]
                               if last > first else [job_lines[first][start:end]]).decode()
             for name, (first, start, last, end) in _values(job).items()}
    lines = cell.source.encode().splitlines()
    # From the last statement up: a value replaced over several lines leaves the earlier positions true.
    for name, (first, start, last, end) in sorted(_values(cell.source).items(), key=lambda item: item[1],
                                                  reverse=True):
        if name in given:
            lines[first:last + 1] = [lines[first][:start] + given.pop(name).encode() + lines[last][end:]]
    cell.source = "\n".join([line.decode() for line in lines] +
                             [f"{name} = {value}  # this job's value (no default in the notebook)"
                              for name, value in given.items()])
    del notebook.cells[injected[0]]
    return notebook


#: The executed notebook's metadata key that holds the stage's name and the fingerprint of the code it ran
#: (``workflow/scripts/snapshot.py`` reads it into a snapshot's provenance).
STAGE_METADATA = "sdm_stage"
#: The last line of a job's text log: the CPU seconds of its processes (:func:`cpu_line`), which
#: ``workflow/scripts/job_times.py`` reads (:data:`CPU_LINE` with the number in its one group).
CPU_LINE = r"^cpu: ([0-9]+\.[0-9]+) s of this job's processes \(user \+ system\)$"


def cpu_line() -> str:
    """The CPU seconds (user + system) of this process and of every process it has waited for, the notebook's kernel
    and whatever the kernel waited for, as the log's last line (:data:`CPU_LINE`).

    Snakemake's ``benchmark:`` file samples a job's processes every 0.5 s for its first 15 s, then every 30 s: a
    longer job's ``cpu_time`` is its CPU at the last sample, short of the end by up to 30 s. This count is whole: it
    is taken after the kernel has exited and the page is written, when only the log is left to write.
    """
    used = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    return f"cpu: {sum(usage.ru_utime + usage.ru_stime for usage in used):.2f} s of this job's processes (user + system)"


def main(source: str, executed: str, html: str, parameters: str | dict, stderr_log: str | None = None,
         stage: dict | None = None) -> int:
    """Run ``source`` with ``parameters`` (a dict, or its JSON); 0 on success, 1 on failure.

    With ``stderr_log`` (the rule's text log), the tools' and the kernel's messages go to that file
    instead of stderr; on failure the console still gets the one-line cause first. A termination signal ends
    the run without leaving its temporary notebook (:func:`stop_on_termination`), and one left by an earlier
    run killed outright is removed first (:func:`remove_stale_temporaries`).
    """
    stop_on_termination()
    remove_stale_temporaries(executed)
    if isinstance(parameters, str):
        parameters = json.loads(parameters)
    log = Path(stderr_log) if stderr_log else None
    with captured_output() as output:
        try:
            import jupytext
            import papermill
            from nbconvert import HTMLExporter

            Path(executed).unlink(missing_ok=True)  # what is under that name is this run's notebook or nothing
            notebook = jupytext.read(source)
            notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
            if stage:
                notebook.metadata[STAGE_METADATA] = stage
            result = execute_into(executed, lambda temporary: execute_with_kernel_restarts(
                papermill.execute_notebook,
                notebook,
                str(temporary),
                parameters=parameters,
                kernel_name="python3",
                kernel_manager_class=kernel_manager(),
                progress_bar=False,
                log_output=False,
            ))
            # The page's title is its job's name (the HTML file's: results/notebooks/<job>.html), not "Notebook".
            body, _ = HTMLExporter().from_notebook_node(page(result), resources={"metadata": {"name": Path(html).stem}})
            library_io().write_text(html, body)
        except Exception as error:  # noqa: BLE001 - every failure is reported the same way, cause first
            noise = output()
            failure = error
        else:
            noise, failure = output(), None
    if failure is None:
        try:
            if log is not None:
                _write_log(log, "\n".join(filter(None, [strip_ansi(noise).strip(), cpu_line()])))
            elif noise.strip():
                sys.stderr.write(strip_ansi(noise))
            return 0
        except OSError as error:  # the notebook ran, but its log cannot be written: the job fails, cause first
            failure = error
    if type(failure).__name__ == "PapermillExecutionError":
        head, details = one_line_cause(source, failure.ename, failure.evalue)
        where = f"(in cell [{failure.exec_count}]; the executed notebook, with the traceback, is {executed})"
    else:
        head, details = one_line_cause(source, type(failure).__name__, str(failure))
        if Path(executed).is_file():
            kept = f"; the executed notebook so far is {executed}"
        elif isinstance(failure, OSError):
            kept = f"; no executed notebook is kept: {executed} could not be written whole"
        else:
            kept = ""
        where = f"(while running the notebook{kept})"
    report_failure(head, details, where, noise, log)
    return 1


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    sys.exit(main(*sys.argv[1:]))
