"""benchmarks/tools/timing.py (``make timing``): the page it writes from measured commands and Snakemake's benchmark files."""
from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("timing", ROOT / "benchmarks" / "tools" / "timing.py")
timing = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(timing)


def test_the_page_holds_each_command_and_each_job(tmp_path):
    header = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
    (tmp_path / "sky.tsv").write_text(header + "12.5\t0:00:12\t1\t1\t1\t1\t0\t0\t50\t11.0\n")
    (tmp_path / "tune_1_3e-04.tsv").write_text(header + "95.0\t0:01:35\t1\t1\t1\t1\t0\t0\t50\t90.5\n")
    jobs = timing.job_times(tmp_path)
    assert jobs == [("tune_1_3e-04", 95.0, 90.5), ("sky", 12.5, 11.0)]
    results = [{"command": "make run", "seconds": 612.0, "status": 0, "tail": "35 of 35 steps (100%) done\n"},
               {"command": "make bench", "seconds": 45.25, "status": 0, "tail": ""},
               {"command": "make test", "seconds": 530.0, "status": 1,
                "tail": "===== 1 failed, 750 passed, 4 skipped in 500.01s (0:08:20) =====\n"}]
    text = timing.page(results, jobs, "abc1234", "2026-12-04 06:00", ("1.0 / 2.0 / 3.0", "4.0 / 5.0 / 6.0"))
    assert "| `make run` | 10 min 12 s | done: 35 jobs |" in text
    assert "| `make bench` | 45.2 s | done |" in text
    assert "| `make test` | 8 min 50 s | failed (exit status 1): 1 failed, 750 passed, 4 skipped in 500.01s" in text
    assert "| `tune_1_3e-04` | 95.0 s | 90.5 s |" in text and "`abc1234`" in text and "2026-12-04 06:00" in text
    assert "1 min 48 s of wall time" in text
