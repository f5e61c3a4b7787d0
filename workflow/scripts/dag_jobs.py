"""Every job a dry run plans, in full, to check that a change to the rule files keeps the same DAG.

    python workflow/scripts/dag_jobs.py dump JOBS.jsonl [SNAKEMAKE ARGUMENTS...]   # adds -n
    python workflow/scripts/dag_jobs.py compare BEFORE.jsonl AFTER.jsonl
    python workflow/scripts/dag_jobs.py chain JOBS.jsonl

``dump`` runs ``snakemake -n`` with the given arguments (from where snakemake would run) and writes one
JSON line per job: its rule, wildcards, named inputs, outputs and logs with their flags (``report``
captions included), benchmark, params, threads, priority, resources, conda environment, script and whether it
is a local rule, then prints the DAG's longest chain (``chain``). ``compare`` prints the jobs and fields that differ and ``SAME n jobs`` or ``DIFFERENT``
(exit status 0 or 1). What means nothing to a stage is left out of the comparison: the order of a rule's
named files (stages read them by name) and the order of the target rule's inputs.

Two checkouts give different absolute paths for the report captions (a flag); run both dumps from the
same path (one checkout after the other), or compare after replacing one root with the other. The param
``stage`` holds the fingerprint of the code a job runs: a refactoring of the rule files keeps it, an edit
of the code it covers does not (workflow/scripts/code_deps.py).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from job_times import benchmark_row, job_cpu


def _files(files) -> dict:
    """A rule's input, output or log files: all of them, by name, and their flags."""
    names = dict(getattr(files, "_names", {}))
    by_name = {name: [str(f) for f in (files[start:end] if end is not None else [files[start]])]
               for name, (start, end) in names.items()}
    flags = {}
    for file in files:
        flags[str(file)] = {
            key: repr((value.caption.get_path_or_uri(secret_free=True), value.category, value.subcategory,
                       value.labels, value.patterns, value.htmlindex)) if key == "report" else repr(value)
            for key, value in sorted((getattr(file, "flags", None) or {}).items())}
    return {"all": [str(f) for f in files], "by_name": dict(sorted(by_name.items())), "flags": flags}


def dump(out_path: str, arguments: list[str]) -> int:
    from snakemake.cli import main
    from snakemake.executors import dryrun

    records = []
    run_job = dryrun.Executor.run_job

    def recording_run_job(self, job):
        for one in (job.jobs if job.is_group() else [job]):
            records.append(json.dumps({
                "rule": one.rule.name, "wildcards": dict(one.wildcards_dict),
                "input": _files(one.input), "output": _files(one.output), "log": _files(one.log),
                "benchmark": str(one.benchmark), "params": {name: repr(value) for name, value in one.params.items()},
                "positional_params": sorted(repr(value) for value in one.params),
                "threads": one.threads, "priority": one.priority,
                "resources": {key: repr(value) for key, value in one.resources.items() if key != "tmpdir"},
                "conda": str(one.rule.conda_env), "script": str(one.rule.script),
                "localrule": one.rule.name in one.dag.workflow._localrules,
            }, sort_keys=True))
        return run_job(self, job)

    dryrun.Executor.run_job = recording_run_job
    sys.argv = ["snakemake", "-n", *arguments]
    try:
        main()
    except SystemExit as exit:
        if exit.code:
            return int(exit.code)
    finally:
        with open(out_path, "w") as out:
            out.write("".join(f"{line}\n" for line in sorted(records)))
    return chain(out_path)


def _load(path: str) -> dict:
    jobs = {}
    for line in open(path):
        job = json.loads(line)
        job["positional_params"] = sorted(job["positional_params"])  # Snakemake compares params as a set
        for part in ("input", "output", "log"):
            job[part]["all"] = sorted(job[part]["all"])
        if job["rule"] == "all":
            job["input"] = sorted(set(job["input"]["all"]))
        key = (job["rule"], json.dumps(job["wildcards"], sort_keys=True))
        if key in jobs:
            raise SystemExit(f"{path}: job {key} twice")
        jobs[key] = job
    return jobs


def _job_name(job: dict) -> str:
    """A job as its files name it: its benchmark file's stem (``baselines_cmaes``), else its rule."""
    return job["benchmark"].rsplit("/", 1)[-1].removesuffix(".tsv") if job["benchmark"] != "None" else job["rule"]


def _cpu_seconds(job: dict) -> float | None:
    """The CPU seconds of a job's run (:func:`job_times.job_cpu`: its text log's whole count, else Snakemake's
    ``cpu_time`` in its benchmark file); None with neither."""
    try:
        sampled = benchmark_row(Path(job["benchmark"]))["cpu_time"]
        float(sampled)  # "-" (Snakemake measured nothing) or no number: no sample
    except (OSError, ValueError, KeyError, IndexError, TypeError):
        sampled = None
    logs = job.get("log", {}).get("by_name", {}).get("stderr", [])
    seconds, _ = job_cpu(sampled, Path(logs[0]) if logs else None)
    return None if seconds != seconds else seconds


def longest_chain(jobs: list[dict], weight) -> tuple[list[dict], float]:
    """The chain of ``jobs`` (each the producer of an input of the next) of the largest sum of ``weight(job)``,
    and that sum; the target rule ``all`` is left out."""
    jobs = [job for job in jobs if job["rule"] != "all"]
    producer = {path: index for index, job in enumerate(jobs) for path in job["output"]["all"]}
    before = [sorted({producer[path] for path in job["input"]["all"] if path in producer}) for job in jobs]
    best: dict[int, tuple[float, list[int]]] = {}

    def reach(index: int) -> tuple[float, list[int]]:  # the heaviest chain ending at job `index`
        if index not in best:
            total, chain = max((reach(earlier) for earlier in before[index]), default=(0.0, []),
                               key=lambda found: found[0])
            best[index] = (total + weight(jobs[index]), chain + [index])
        return best[index]

    total, chain = max((reach(index) for index in range(len(jobs))), default=(0.0, []), key=lambda found: found[0])
    return [jobs[index] for index in chain], total


def chain(path: str) -> int:
    """Print the longest chain of the dump at ``path``: by jobs, and by CPU seconds where every job has them."""
    jobs = [json.loads(line) for line in open(path)]
    by_count, count = longest_chain(jobs, lambda job: 1)
    print(f"longest chain: {int(count)} jobs: {' -> '.join(_job_name(job) for job in by_count)}")
    cpu = {id(job): _cpu_seconds(job) for job in jobs if job["rule"] != "all"}  # each job's files read once
    if jobs and None not in cpu.values():
        by_cpu, seconds = longest_chain(jobs, lambda job: cpu[id(job)])
        every = sum(cpu.values())
        steps = " -> ".join(f"{_job_name(job)} ({cpu[id(job)]:.1f} s)" for job in by_cpu)
        print(f"longest chain by CPU: {seconds:.1f} s of the jobs' {every:.1f} s: {steps}")
    return 0


def compare(before_path: str, after_path: str) -> int:
    before, after = _load(before_path), _load(after_path)
    same = set(before) == set(after)
    for key in sorted(set(before) ^ set(after)):
        print("only in", before_path if key in before else after_path, ":", *key)
    for key in sorted(set(before) & set(after)):
        for field in sorted(set(before[key]) | set(after[key])):
            if before[key].get(field) != after[key].get(field):
                same = False
                print(*key, field, "\n  before:", before[key].get(field), "\n  after: ", after[key].get(field))
    print(f"SAME {len(before)} jobs" if same else "DIFFERENT")
    return 0 if same else 1


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "dump":
        sys.exit(dump(sys.argv[2], sys.argv[3:]))
    if len(sys.argv) == 3 and sys.argv[1] == "chain":
        sys.exit(chain(sys.argv[2]))
    if len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    sys.exit(__doc__)
