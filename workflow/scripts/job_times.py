"""Each job's CPU and wall seconds from Snakemake's ``benchmark:`` files and its text log, and its stage from its
executed notebook: the one reader of them that the snapshots' provenance (``snapshot.py``) and ``make timing``
(``benchmarks/tools/timing.py``) share.

A job ``J`` wrote ``results/benchmarks/J.tsv`` (its last line: ``s``, its wall seconds, and ``cpu_time``, the CPU
seconds of its processes at Snakemake's last sample of them), ``results/logs/J.log``, whose last line is the CPU
seconds of its processes counted whole at its end (``run_notebook.CPU_LINE``; Snakemake samples a job every 30 s
after its first 15 s, so a long job's ``cpu_time`` falls short by up to 30 s), and ``results/notebooks/J.ipynb``,
whose metadata names its stage (``run_notebook.STAGE_METADATA``). The CPU seconds are the log's where it has them,
else the benchmark file's. The standard library only.
"""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

from run_notebook import CPU_LINE, STAGE_METADATA

#: The stage of a job whose notebook records none.
NO_STAGE = "?"


def job_stage(notebooks: Path, job: str) -> str:
    """The stage of ``job``, as its executed notebook in ``notebooks`` records it (:data:`NO_STAGE` where it records
    none or cannot be read)."""
    try:
        metadata = json.loads((notebooks / f"{job}.ipynb").read_text(encoding="utf-8")).get("metadata", {})
    except (OSError, ValueError):
        return NO_STAGE
    stage = metadata.get(STAGE_METADATA)
    return str(stage["name"]) if isinstance(stage, dict) and "name" in stage else NO_STAGE


def logged_cpu(log: Path) -> float | None:
    """The CPU seconds that the last line of the job's log ``log`` gives (``run_notebook.CPU_LINE``), None where there
    is no such file or line."""
    try:
        lines = log.read_text(encoding="utf-8").splitlines()
    except (OSError, ValueError):
        return None
    found = re.match(CPU_LINE, lines[-1]) if lines else None
    return float(found.group(1)) if found else None


def benchmark_row(path: Path) -> dict[str, str]:
    """The measured line of the Snakemake ``benchmark:`` file ``path`` (its last), column name to text; raises
    OSError where it cannot be read and IndexError where it has no line under its header."""
    with path.open(encoding="utf-8") as handle:
        return list(csv.DictReader(handle, delimiter="\t"))[-1]


def job_cpu(sampled: str | None, log: Path | None) -> tuple[float, str]:
    """A job's CPU seconds and where they come from: ``(seconds, "log")`` from its log's whole count
    (:func:`logged_cpu`), else ``(seconds, "benchmark")`` from ``sampled``, its benchmark file's ``cpu_time`` (NaN
    where Snakemake wrote ``-`` or there is none)."""
    whole = logged_cpu(log) if log is not None else None
    if whole is not None:
        return whole, "log"
    return (float(sampled) if sampled not in (None, "", "-") else float("nan")), "benchmark"


def job_times(benchmarks: Path, notebooks: Path | None = None, logs: Path | None = None) -> list[dict]:
    """Per benchmark file of ``benchmarks`` with a measured line: ``job``, ``stage`` (from ``notebooks``;
    :data:`NO_STAGE` without it), ``cpu`` and ``wall`` seconds and ``cpu_from``, where ``cpu`` comes from: ``"log"``
    (the job's log in ``logs`` counted it whole, :func:`job_cpu`) or ``"benchmark"`` (Snakemake's last sample; NaN
    where it wrote ``-``); the most CPU first, then by job."""
    jobs = []
    for path in sorted(benchmarks.glob("*.tsv")):
        try:
            row = benchmark_row(path)
            sampled, wall = row.get("cpu_time"), float(row["s"])
        except (OSError, ValueError, KeyError, IndexError, TypeError):
            continue
        cpu, cpu_from = job_cpu(sampled, logs / f"{path.stem}.log" if logs else None)
        jobs.append({"job": path.stem, "stage": job_stage(notebooks, path.stem) if notebooks else NO_STAGE,
                     "cpu": cpu, "wall": wall, "cpu_from": cpu_from})
    return sorted(jobs, key=lambda job: (-(job["cpu"] if job["cpu"] == job["cpu"] else 0.0), job["job"]))


def stage_times(jobs: list[dict]) -> list[dict]:
    """Per stage of ``jobs`` (:func:`job_times`): its jobs, their CPU and wall seconds summed, the most CPU first."""
    stages: dict[str, dict] = {}
    for job in jobs:
        row = stages.setdefault(job["stage"], {"stage": job["stage"], "jobs": 0, "cpu": 0.0, "wall": 0.0})
        row["jobs"] += 1
        row["cpu"] += job["cpu"]
        row["wall"] += job["wall"]
    return sorted(stages.values(), key=lambda row: (-row["cpu"], row["stage"]))
