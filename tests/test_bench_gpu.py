"""benchmarks/speed/bench_gpu.py (the GPU section of ``make bench``): where CUDA is missing it says so and succeeds."""
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present: the section runs for real")
def test_without_cuda_the_gpu_section_says_so_and_succeeds(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "speed" / "bench_gpu.py"), "--json", str(tmp_path / "x")],
                          capture_output=True, text=True, cwd=ROOT,
                          env={"PYTHONPATH": f"{ROOT / 'src'}:{ROOT / 'benchmarks'}", "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "no CUDA device" in done.stdout
    assert not (tmp_path / "x").exists()
