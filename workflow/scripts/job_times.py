"""Each job's CPU and wall seconds from Snakemake's ``benchmark:`` files, and its stage from its executed notebook:
the one reader of both that the snapshots' provenance (``snapshot.py``) and ``make timing``
(``benchmarks/tools/timing.py``) share.

A job ``J`` wrote ``results/benchmarks/J.tsv`` (its last line: ``cpu_time``, the CPU seconds of its processes, and
``s``, its wall seconds) and ``results/notebooks/J.ipynb``, whose metadata names its stage
(``run_notebook.STAGE_METADATA``). The standard library only.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

from run_notebook import STAGE_METADATA

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


def job_times(benchmarks: Path, notebooks: Path | None = None) -> list[dict]:
    """Per benchmark file of ``benchmarks`` with a measured line: ``job``, ``stage`` (from ``notebooks``;
    :data:`NO_STAGE` without it), ``cpu`` and ``wall`` seconds (``cpu`` NaN where Snakemake wrote ``-``); the most
    CPU first, then by job."""
    jobs = []
    for path in sorted(benchmarks.glob("*.tsv")):
        try:
            with path.open(encoding="utf-8") as handle:
                rows = list(csv.DictReader(handle, delimiter="\t"))
            cpu, wall = rows[-1].get("cpu_time") or "-", float(rows[-1]["s"])
        except (OSError, ValueError, KeyError, IndexError, TypeError):
            continue
        jobs.append({"job": path.stem, "stage": job_stage(notebooks, path.stem) if notebooks else NO_STAGE,
                     "cpu": float(cpu) if cpu != "-" else float("nan"), "wall": wall})
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
