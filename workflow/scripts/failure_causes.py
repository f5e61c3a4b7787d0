"""The one-line causes of the stages that failed in a Snakemake run, for the Snakefile's ``onerror``.

A failed stage's text log (the rule's ``log.stderr``) starts with its cause, as
:func:`run_notebook.report_failure` writes it::

    notebooks/sky.py failed: SDMInputError: results/sky/sky.bin: array 'point_depth' fails its CRC-32 check; ...

Run locally, a stage also prints that line on Snakemake's console; run as a cluster job (SLURM), it
prints it into the job's cluster log, which Snakemake only names. Snakemake's own log names each failed
job with its log files; this reads the cause from there. Not part of any stage's code (no stage reruns
when it changes): it only reads what the stages wrote.
"""
from __future__ import annotations

import re
from pathlib import Path

#: A cause line: ``<notebook> failed: <error>: <message>``.
CAUSE = re.compile(r"^\S.* failed: \S")
#: A failed job's log files in Snakemake's log: ``    log: a.ipynb, logs/a.log (check log file(s) for error details)``.
FAILED_JOB_LOGS = re.compile(r"^\s+log: (.+) \(check log file\(s\) for error details\)$", re.MULTILINE)


def failure_causes(snakemake_logs: list[str]) -> list[str]:
    """The causes of the failed stages named in ``snakemake_logs`` (the run's own log files, what Snakemake
    passes to ``onerror``), in order, each once: the first line of each failed job's log that is a cause."""
    causes = []
    for snakemake_log in snakemake_logs:
        try:
            text = Path(snakemake_log).read_text(encoding="utf-8", errors="replace")
        except OSError:
            continue
        for listed in FAILED_JOB_LOGS.findall(text):
            for path in listed.split(", "):
                try:
                    with open(path, encoding="utf-8", errors="replace") as log:
                        first = log.readline().rstrip("\n")
                except OSError:
                    continue
                if CAUSE.match(first) and first not in causes:
                    causes.append(first)
    return causes
