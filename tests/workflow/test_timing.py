"""benchmarks/tools/timing.py (``make timing``): the page it writes from measured commands and Snakemake's benchmark
files, CPU time first; and the whole measurement on a tiny repository whose make targets take a moment each."""
from __future__ import annotations

import importlib.util
import json
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("timing", ROOT / "benchmarks" / "tools" / "timing.py")
timing = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(timing)

HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def _job(folder: Path, job: str, wall: float, cpu: float, stage: str | None) -> None:
    (folder / "benchmarks").mkdir(parents=True, exist_ok=True)
    (folder / "notebooks").mkdir(parents=True, exist_ok=True)
    (folder / "benchmarks" / f"{job}.tsv").write_text(HEADER + f"{wall}\t0:00:00\t1\t1\t1\t1\t0\t0\t50\t{cpu}\n")
    metadata = {"sdm_stage": {"name": stage, "code": "0" * 64}} if stage else {}
    (folder / "notebooks" / f"{job}.ipynb").write_text(json.dumps({"cells": [], "metadata": metadata}))


def test_the_page_leads_with_cpu_time_per_command_stage_and_job(tmp_path):
    _job(tmp_path, "sky", 12.5, 11.0, "sky")
    _job(tmp_path, "noise_level0_chunk0", 95.0, 90.5, "noise")
    _job(tmp_path, "noise_level1_chunk0", 50.0, 40.0, "noise")
    _job(tmp_path, "orphan", 3.0, 1.0, None)
    jobs = timing.job_times(tmp_path / "benchmarks", tmp_path / "notebooks")
    assert [(job["job"], job["stage"], job["cpu"]) for job in jobs] == [
        ("noise_level0_chunk0", "noise", 90.5), ("noise_level1_chunk0", "noise", 40.0), ("sky", "sky", 11.0),
        ("orphan", "?", 1.0)]
    assert timing.stage_times(jobs)[0] == {"stage": "noise", "jobs": 2, "cpu": 130.5, "wall": 145.0}
    results = [{"command": "make run", "cpu": 1500.0, "seconds": 612.0, "load_mean": 3.2, "load_max": 15.0,
                "status": 0, "tail": "35 of 35 steps (100%) done\n"},
               {"command": "make bench", "cpu": 40.0, "seconds": 45.25, "load_mean": 1.0, "load_max": 1.5,
                "status": 0, "tail": ""},
               {"command": "make test", "cpu": 900.0, "seconds": 530.0, "load_mean": 2.0, "load_max": 2.5,
                "status": 1, "tail": "===== 1 failed, 750 passed, 4 skipped in 500.01s (0:08:20) =====\n"}]
    text = timing.page(results, jobs, "abc1234", "2026-12-04 06:00", machine="Linux x86_64, 2 cores")
    assert "| command | CPU time | wall time | load average while it ran (mean / max) | result |" in text
    assert "| `make run` | 25 min 0 s | 10 min 12 s | 3.2 / 15.0 | done: 35 jobs |" in text
    assert "| `make bench` | 40.0 s | 45.2 s | 1.0 / 1.5 | done |" in text
    assert ("| `make test` | 15 min 0 s | 8 min 50 s | 2.0 / 2.5 | failed (exit status 1): 1 failed, 750 passed, "
            "4 skipped in 500.01s") in text
    assert "| `noise` | 2 | 130.5 s | 145.0 s |" in text and "| `noise_level0_chunk0` | 90.5 s | 95.0 s |" in text
    assert "All jobs together: 2 min 22 s of CPU time, 2 min 40 s of wall time (4 jobs)." in text
    assert text.index("## The commands") < text.index("stage by stage") < text.index("job by job")
    assert "`abc1234`" in text and "2026-12-04 06:00" in text
    assert "No job ran" in timing.page(results, [], "abc1234", "2026-12-04 06:00")


MAKEFILE = """\
run:
\tmkdir -p results/benchmarks results/notebooks
\tprintf '{header}12.5\\t0:00:12\\t1\\t1\\t1\\t1\\t0\\t0\\t50\\t11.0\\n' > results/benchmarks/sky.tsv
\tprintf '{{"cells": [], "metadata": {{"sdm_stage": {{"name": "sky", "code": "x"}}}}}}' > results/notebooks/sky.ipynb
\t@echo "2 of 2 steps (100%) done"
bench:
\tpython3 -c "sum(i * i for i in range(4 * 10 ** 6))"
test:
\t@echo "===== 3 passed in 0.01s ====="
"""


@pytest.fixture
def tiny_repository(tmp_path) -> Path:
    """A git repository whose `make run` writes one benchmark file and notebook, `make bench` spends CPU."""
    repo = tmp_path / "repo"
    repo.mkdir()
    header = HEADER.replace("\t", "\\t").replace("\n", "\\n")
    (repo / "Makefile").write_text(MAKEFILE.format(header=header))
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(repo)]
    subprocess.run(["git", "init", "--quiet", str(repo)], check=True)
    subprocess.run([*git, "add", "Makefile"], check=True)
    subprocess.run([*git, "commit", "--quiet", "-m", "tiny"], check=True)
    return repo


def test_make_timing_measures_each_command_of_a_fresh_clone(tiny_repository, tmp_path):
    output = tmp_path / "timing.md"
    assert timing.main(["--repo", str(tiny_repository), "--output", str(output), "--every", "0.05"]) == 0
    text = output.read_text()
    rows = {line.split("|")[1].strip(): [cell.strip() for cell in line.split("|")[2:-1]]
            for line in text.splitlines() if line.startswith("| `make ")}
    assert list(rows) == ["`make run`", "`make bench`", "`make test`"]
    assert rows["`make run`"][-1] == "done: 2 jobs" and rows["`make test`"][-1] == "done: 3 passed in 0.01s"
    bench_cpu = float(rows["`make bench`"][0].removesuffix(" s"))
    assert bench_cpu >= 0.1  # the loop's CPU, measured in the processes make started
    assert "| `sky` | 1 | 11.0 s | 12.5 s |" in text and "| `sky` | 11.0 s | 12.5 s |" in text


def test_a_jobs_cpu_is_its_logs_whole_count_where_the_log_has_one(tmp_path):
    """Snakemake's benchmark file has the CPU at its last sample (every 30 s after 15 s): the job's log's last line
    counts it whole and wins; a job without that line keeps the benchmark file's, and the page says so."""
    _job(tmp_path, "baselines_chamfer", 58.0, 44.5, "baseline_runs")
    _job(tmp_path, "sky", 12.5, 11.0, "sky")
    _job(tmp_path, "split", 4.0, 3.5, "split")
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "baselines_chamfer.log").write_text("a warning\ncpu: 57.25 s of this job's processes (user + system)\n")
    (logs / "sky.log").write_text("cpu: 12.00 s of this job's processes (user + system)\nthen something else\n")
    jobs = timing.job_times(tmp_path / "benchmarks", tmp_path / "notebooks", logs)
    assert [(job["job"], job["cpu"], job["cpu_from"]) for job in jobs] == [
        ("baselines_chamfer", 57.25, "log"), ("sky", 11.0, "benchmark"), ("split", 3.5, "benchmark")]
    text = timing.page([], jobs, "abc1234", "2026-12-04 06:00")
    assert "| `baselines_chamfer` | 57.2 s | 58.0 s |" in text and "up to 30 s short" in text
    (logs / "sky.log").write_text("cpu: 12.00 s of this job's processes (user + system)\n")
    (logs / "split.log").write_text("cpu: 3.75 s of this job's processes (user + system)\n")
    text = timing.page([], timing.job_times(tmp_path / "benchmarks", tmp_path / "notebooks", logs), "abc1234",
                       "2026-12-04 06:00")
    assert "up to 30 s short" not in text and "| `sky` | 12.0 s | 12.5 s |" in text
