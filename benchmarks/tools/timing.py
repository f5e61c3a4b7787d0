"""How long the main commands take on a fresh clone: writes docs/results/timing.md (``make timing``).

    python benchmarks/tools/timing.py [--clone DIR] [--keep] [--repo DIR] [--output FILE]

Clones the committed HEAD of this repository (or ``--repo``) into a temporary folder (or ``--clone DIR``, which
must not exist), then runs there, one after another:

1. ``make run``   (creates the clone's ``.venv`` first: the install is part of it);
2. ``make bench`` (the layer's speed, ``benchmarks/speed/bench_sdm.py``);
3. ``make test``  (the test suite).

Each command is measured three ways: its CPU seconds (user + system of every process it started and waited for,
``getrusage(RUSAGE_CHILDREN)``), its wall seconds, and the machine's 1-minute load average sampled every few
seconds while it ran. On a shared machine the wall time grows with the load; the CPU time barely moves, so the
page leads with it. It then reads the default run's per-job times: each job's CPU seconds from the last line of the
clone's ``results/logs/<job>.log`` (counted whole at the job's end), its wall seconds ``s`` from
``results/benchmarks/<job>.tsv`` (Snakemake's ``benchmark:`` file), each job's stage from its executed notebook
(``results/notebooks/<job>.ipynb``, which records it), and rewrites docs/results/timing.md whole: the
current figures only, with the commit and the date. A command that fails is written as failed, with its exit
status. The clone is deleted afterwards unless ``--keep``. The standard library only.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
from job_times import job_times, stage_times  # noqa: E402  (the reader the snapshots' provenance shares)

OUTPUT = ROOT / "docs" / "results" / "timing.md"
#: The commands timed, in the order they run (the first installs the clone's environment).
COMMANDS = ("make run", "make bench", "make test")
#: Seconds between two samples of the load average while a command runs.
SAMPLE_SECONDS = 5.0


class LoadSampler:
    """The machine's 1-minute load average, sampled every ``every`` seconds in a thread while a command runs."""

    def __init__(self, every: float = SAMPLE_SECONDS):
        self.every, self.samples = every, [os.getloadavg()[0]]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self) -> "LoadSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])


def cpu_of_children() -> float:
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def run_timed(command: str, cwd: Path, log: Path, every: float = SAMPLE_SECONDS) -> dict:
    """Run ``command`` in ``cwd`` (output to ``log``): its CPU and wall seconds, the load average while it ran
    (mean and maximum of the samples), its exit status and the log's tail."""
    cpu_before, start = cpu_of_children(), time.monotonic()
    with log.open("w") as out, LoadSampler(every) as load:
        status = subprocess.run(command, shell=True, cwd=cwd, stdout=out, stderr=subprocess.STDOUT).returncode
    return {"command": command, "cpu": cpu_of_children() - cpu_before, "seconds": time.monotonic() - start,
            "load_mean": sum(load.samples) / len(load.samples), "load_max": max(load.samples),
            "status": status, "tail": log.read_text()[-4000:]}


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


def _command_rows(results: list[dict]) -> list[str]:
    rows = ["| command | CPU time | wall time | load average while it ran (mean / max) | result |",
            "|---|---:|---:|---:|---|"]
    for result in results:
        outcome = "done" if result["status"] == 0 else f"failed (exit status {result['status']})"
        said = summary(result)
        rows.append(f"| `{result['command']}` | {minutes(result['cpu'])} | {minutes(result['seconds'])} | "
                    f"{result['load_mean']:.1f} / {result['load_max']:.1f} | {outcome}"
                    + (f": {said}" if said else "") + " |")
    return rows


def _job_rows(jobs: list[dict]) -> list[str]:
    if not jobs:
        return ["No job ran: `make run` wrote no benchmark file."]
    stages = stage_times(jobs)
    rows = [
        "From that `make run`'s `results/logs/<job>.log` (the CPU time of each job's processes, user + system,",
        "counted whole at its end) and `results/benchmarks/<job>.tsv` (Snakemake's `benchmark:` files: its wall",
        "time, its span), each job's stage from its executed notebook."
        + ("" if all(job.get("cpu_from", "log") == "log" for job in jobs) else
           " A job whose log has no count shows the benchmark file's CPU time, Snakemake's last sample of it: up"
           " to 30 s short for a job longer than 15 s."),
        f"All jobs together: {minutes(sum(job['cpu'] for job in jobs))} of CPU time, "
        f"{minutes(sum(job['wall'] for job in jobs))} of wall time ({len(jobs)} jobs).",
        "",
        "| stage | jobs | CPU time | wall time |",
        "|---|---:|---:|---:|",
        *(f"| `{row['stage']}` | {row['jobs']} | {row['cpu']:.1f} s | {row['wall']:.1f} s |" for row in stages),
        "",
        "## The default run, job by job",
        "",
        "| job | CPU time | wall time |",
        "|---|---:|---:|",
        *(f"| `{job['job']}` | {job['cpu']:.1f} s | {job['wall']:.1f} s |" for job in jobs),
    ]
    return rows


def page(results: list[dict], jobs: list[dict], commit: str, date: str, machine: str | None = None) -> str:
    """docs/results/timing.md's text."""
    machine = machine or (f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores, Python "
                          f"{platform.python_version()}")
    lines = [
        "# How long the commands take",
        "",
        "Written by `make timing` (`benchmarks/tools/timing.py`); do not edit by hand.",
        "",
        f"- Commit: `{commit}`, cloned fresh (`git clone`), each command run there in turn.",
        f"- Date: {date} (UTC).",
        f"- Machine: {machine}.",
        "- CPU time: user + system seconds of every process a command started. It is the figure to compare:",
        "  on a shared machine the wall time grows with the load average beside it, the CPU time hardly.",
        "",
        "## The commands",
        "",
        *_command_rows(results),
        "",
        "`make run` includes creating `.venv` and installing into it (a fresh clone has none).",
        "`make bench` prints the layer's speed ratios, measured in one run; see its own output.",
        "",
        "## The default run, stage by stage",
        "",
        *_job_rows(jobs),
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clone", type=Path, help="where to clone (must not exist; default: a temporary folder)")
    parser.add_argument("--keep", action="store_true", help="keep the clone afterwards")
    parser.add_argument("--repo", type=Path, default=ROOT, help="the repository to clone (default: this one)")
    parser.add_argument("--output", type=Path, default=OUTPUT, help="the page to write (default: %(default)s)")
    parser.add_argument("--every", type=float, default=SAMPLE_SECONDS, help="seconds between load samples")
    args = parser.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=args.repo, capture_output=True, text=True,
                            check=True).stdout.strip()
    clone = args.clone or Path(tempfile.mkdtemp(prefix="sdm-timing-")) / "sdm"
    if clone.exists():
        sys.exit(f"--clone {clone}: already exists")
    subprocess.run(["git", "clone", "--quiet", str(args.repo), str(clone)], check=True)
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
    results = []
    try:
        for command in COMMANDS:
            print(f"timing `{command}` in {clone} ...", flush=True)
            results.append(run_timed(command, clone, clone.parent / f"{command.replace(' ', '_')}.log", args.every))
            print(f"  {minutes(results[-1]['cpu'])} CPU, {minutes(results[-1]['seconds'])} wall, exit status "
                  f"{results[-1]['status']}", flush=True)
        made = clone / "results"
        jobs = job_times(made / "benchmarks", made / "notebooks", made / "logs")
    finally:
        if not args.keep and not args.clone:
            shutil.rmtree(clone.parent, ignore_errors=True)
    args.output.write_text(page(results, jobs, commit, date))
    print(f"wrote {args.output}")
    return 0 if all(result["status"] == 0 for result in results) else 1


if __name__ == "__main__":
    sys.exit(main())
