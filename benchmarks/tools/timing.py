"""How long the main commands take on a fresh clone: writes docs/results/timing.md (``make timing``).

    python benchmarks/tools/timing.py [--clone DIR] [--keep]

Clones the committed HEAD of this repository into a temporary folder (or ``--clone DIR``, which must not
exist), then runs there, one after another, each under a wall clock:

1. ``make run``   (creates the clone's ``.venv`` first: the install is part of its time);
2. ``make bench`` (the layer's speed, ``benchmarks/speed/bench_sdm.py``);
3. ``make test``  (the test suite).

It then reads the default run's per-job times from the clone's ``results/benchmarks/<job>.tsv`` (Snakemake's
``benchmark:`` files: wall seconds ``s`` and ``cpu_time``) and rewrites docs/results/timing.md here, whole:
the current figures only, each with its command, the commit and the date. A command that fails is written
as failed, with its exit status. The clone is deleted afterwards unless ``--keep``.

The figures are wall times on whatever else the machine runs; the page records the load average before
and after. The standard library only.
"""
from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUTPUT = ROOT / "docs" / "results" / "timing.md"
#: The commands timed, in the order they run (the first installs the clone's environment).
COMMANDS = ("make run", "make bench", "make test")


def run_timed(command: str, cwd: Path, log: Path) -> dict:
    """Run ``command`` in ``cwd`` (output to ``log``); its wall seconds, exit status and the log's tail."""
    start = time.monotonic()
    with log.open("w") as out:
        status = subprocess.run(command, shell=True, cwd=cwd, stdout=out, stderr=subprocess.STDOUT).returncode
    seconds = time.monotonic() - start
    return {"command": command, "seconds": seconds, "status": status, "tail": log.read_text()[-4000:]}


def job_times(benchmarks: Path) -> list[tuple[str, float, float]]:
    """``(job, wall s, CPU s)`` per Snakemake benchmark file of ``benchmarks``, longest first."""
    jobs = []
    for path in sorted(benchmarks.glob("*.tsv")):
        with path.open() as handle:
            rows = list(csv.DictReader(handle, delimiter="\t"))
        if rows:
            jobs.append((path.stem, float(rows[-1]["s"]), float(rows[-1].get("cpu_time") or "nan")))
    return sorted(jobs, key=lambda job: -job[1])


def minutes(seconds: float) -> str:
    return f"{int(seconds // 60)} min {round(seconds % 60):d} s" if seconds >= 60 else f"{seconds:.1f} s"


def summary(result: dict) -> str:
    """What the command's own output says it did (jobs run, tests passed), for the table's last column."""
    tail = result["tail"]
    if result["command"] == "make test":
        found = re.findall(r"=+ (.*? in [\d.]+s.*?) =+", tail)
        return found[-1] if found else ""
    if result["command"] == "make run":
        found = re.findall(r"(\d+) of (\d+) steps \(100%\) done", tail)
        return f"{found[-1][1]} jobs" if found else ""
    return ""


def load() -> str:
    return " / ".join(f"{value:.1f}" for value in os.getloadavg())


def page(results: list[dict], jobs: list[tuple[str, float, float]], commit: str, date: str,
         loads: tuple[str, str]) -> str:
    """docs/results/timing.md's text."""
    lines = [
        "# How long the commands take",
        "",
        "Written by `make timing` (`benchmarks/tools/timing.py`); do not edit by hand. History lives in git.",
        "",
        f"- Commit: `{commit}`, cloned fresh (`git clone`), each command run there in turn.",
        f"- Date: {date} (UTC).",
        f"- Machine: {platform.system()} {platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}.",
        f"- Load average (1 / 5 / 15 min): {loads[0]} before, {loads[1]} after. The machine may be shared,",
        "  so these are wall times under that load, not a quiet machine's.",
        "",
        "## The commands",
        "",
        "| command | wall time | result |",
        "|---|---|---|",
    ]
    for result in results:
        outcome = "done" if result["status"] == 0 else f"failed (exit status {result['status']})"
        said = summary(result)
        lines.append(f"| `{result['command']}` | {minutes(result['seconds'])} | {outcome}"
                     + (f": {said}" if said else "") + " |")
    lines += [
        "",
        "`make run` includes creating `.venv` and installing into it (a fresh clone has none).",
        "`make bench` prints the layer's speed ratios, measured in one run; see its own output.",
        "",
        "## The default run, job by job",
        "",
    ]
    if jobs:
        lines += [
            "From `results/benchmarks/<job>.tsv` of that `make run` (Snakemake's `benchmark:` files), longest first.",
            f"All jobs together: {minutes(sum(job[1] for job in jobs))} of wall time, "
            f"{minutes(sum(job[2] for job in jobs))} of CPU time.",
            "",
            "| job | wall time | CPU time |",
            "|---|---:|---:|",
        ]
        lines += [f"| `{name}` | {wall:.1f} s | {cpu:.1f} s |" for name, wall, cpu in jobs]
    else:
        lines.append("No job ran: `make run` wrote no benchmark file.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clone", type=Path, help="where to clone (must not exist; default: a temporary folder)")
    parser.add_argument("--keep", action="store_true", help="keep the clone afterwards")
    args = parser.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                            check=True).stdout.strip()
    clone = args.clone or Path(tempfile.mkdtemp(prefix="sdm-timing-")) / "sdm"
    if clone.exists():
        sys.exit(f"--clone {clone}: already exists")
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
    before = load()
    results = []
    try:
        for command in COMMANDS:
            print(f"timing `{command}` in {clone} ...", flush=True)
            results.append(run_timed(command, clone, clone.parent / f"{command.replace(' ', '_')}.log"))
            print(f"  {minutes(results[-1]['seconds'])}, exit status {results[-1]['status']}", flush=True)
        jobs = job_times(clone / "results" / "benchmarks")
    finally:
        if not args.keep and not args.clone:
            shutil.rmtree(clone.parent, ignore_errors=True)
    OUTPUT.write_text(page(results, jobs, commit, date, (before, load())))
    print(f"wrote {OUTPUT.relative_to(ROOT)}")
    return 0 if all(result["status"] == 0 for result in results) else 1


if __name__ == "__main__":
    sys.exit(main())
