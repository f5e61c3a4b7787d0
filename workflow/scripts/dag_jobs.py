"""Every job a dry run plans, in full, to check that a change to the rule files keeps the same DAG.

    python workflow/scripts/dag_jobs.py dump JOBS.jsonl [SNAKEMAKE ARGUMENTS...]   # adds -n
    python workflow/scripts/dag_jobs.py compare BEFORE.jsonl AFTER.jsonl

``dump`` runs ``snakemake -n`` with the given arguments (from where snakemake would run) and writes one
JSON line per job: its rule, wildcards, named inputs, outputs and logs with their flags (``report``
captions included), benchmark, params, threads, resources, conda environment, script and whether it
is a local rule. ``compare`` prints the jobs and fields that differ and ``SAME n jobs`` or ``DIFFERENT``
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
                "threads": one.threads,
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
    return 0


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
    if len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    sys.exit(__doc__)
