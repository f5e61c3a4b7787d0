"""workflow/scripts/dag_jobs.py chain: the DAG's longest chain, by jobs and by the CPU seconds of a run."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import dag_jobs  # noqa: E402


def job(rule, inputs, outputs, benchmark="None"):
    return {"rule": rule, "wildcards": {}, "input": {"all": inputs}, "output": {"all": outputs},
            "benchmark": benchmark}


def write_benchmark(path: Path, cpu: float) -> str:
    path.write_text("s\th:m:s\tmax_rss\tcpu_time\n" f"{cpu + 1:.2f}\t0:00:01\t1.0\t{cpu:.2f}\n")
    return str(path)


def test_longest_chain_by_jobs_and_by_cpu_seconds(tmp_path):
    """a -> b -> c -> d is the longest by jobs; a -> heavy -> d the heaviest by CPU; `all` is no job of a chain."""
    seconds = {"a": 1.0, "b": 1.0, "c": 1.0, "heavy": 10.0, "d": 1.0}
    bench = {name: write_benchmark(tmp_path / f"{name}.tsv", cpu) for name, cpu in seconds.items()}
    jobs = [job("all", ["d.out"], []), job("a", [], ["a.out"], bench["a"]), job("b", ["a.out"], ["b.out"], bench["b"]),
            job("c", ["b.out"], ["c.out"], bench["c"]), job("heavy", ["a.out"], ["h.out"], bench["heavy"]),
            job("d", ["c.out", "h.out"], ["d.out"], bench["d"])]
    by_count, count = dag_jobs.longest_chain(jobs, lambda one: 1)
    assert [one["rule"] for one in by_count] == ["a", "b", "c", "d"] and count == 4
    by_cpu, cpu = dag_jobs.longest_chain(jobs, dag_jobs._cpu_seconds)
    assert [one["rule"] for one in by_cpu] == ["a", "heavy", "d"] and cpu == 12.0

    dump = tmp_path / "jobs.jsonl"
    dump.write_text("".join(json.dumps(one) + "\n" for one in jobs))
    out = subprocess.run([sys.executable, str(ROOT / "workflow" / "scripts" / "dag_jobs.py"), "chain", str(dump)],
                         capture_output=True, text=True, check=True).stdout
    assert "longest chain: 4 jobs: a -> b -> c -> d" in out
    assert "longest chain by CPU: 12.0 s of the jobs' 14.0 s: a (1.0 s) -> heavy (10.0 s) -> d (1.0 s)" in out
    (tmp_path / "c.tsv").unlink()  # a job without its benchmark file: no chain by CPU
    out = subprocess.run([sys.executable, str(ROOT / "workflow" / "scripts" / "dag_jobs.py"), "chain", str(dump)],
                         capture_output=True, text=True, check=True).stdout
    assert "by CPU" not in out


def test_the_chain_by_cpu_takes_a_jobs_whole_count_from_its_log(tmp_path):
    """A job's log's last line (its CPU counted whole) wins over its benchmark file's sampled cpu_time."""
    bench = {name: write_benchmark(tmp_path / f"{name}.tsv", 1.0) for name in ("a", "b", "c")}
    (tmp_path / "b.log").write_text("cpu: 30.00 s of this job's processes (user + system)\n")
    jobs = [job("a", [], ["a.out"], bench["a"]), job("b", ["a.out"], ["b.out"], bench["b"]),
            job("c", ["a.out"], ["c.out"], bench["c"]), job("d", ["c.out"], ["d.out"], bench["c"])]
    for one in jobs:
        one["log"] = {"by_name": {"stderr": [str(tmp_path / f"{one['rule']}.log")]}}
    by_cpu, cpu = dag_jobs.longest_chain(jobs, dag_jobs._cpu_seconds)
    assert [one["rule"] for one in by_cpu] == ["a", "b"] and cpu == 31.0
