"""The code shown to users runs as shown."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_readme_quick_start_runs():
    """The README's quick start: about ten lines, and it recovers the shift."""
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert len(blocks) == 1 and len(blocks[0].splitlines()) <= 14
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert namespace["distance"](namespace["history"].final_theta) < 2e-3


def test_library_page_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "library.md").read_text(), flags=re.S)
    assert len(blocks) == 3
    namespace: dict = {}
    for block in blocks:  # each block continues the first one's session
        exec(compile(block, "docs/library.md", "exec"), namespace)
    assert namespace["theta"].grad is not None
    assert all(weight.grad is not None for weight in namespace["net"].parameters())  # the flow reached the network


@pytest.mark.slow
def test_calibration_notebook_runs(tmp_path, apollo_sample):
    """The calibration notebook (an analysis beside the benchmarks, not a workflow stage) executes top to bottom on a small synthetic set."""
    import os
    import subprocess
    import sys

    source = (ROOT / "benchmarks" / "studies" / "calibration.py").read_text()
    marker = '# %% tags=["parameters"]\n'
    head, rest = source.split(marker, 1)
    overrides = (f"apollo_sample = {str(apollo_sample)!r}\nn_images = 300\nn_sample = 200\n"
                 f"output_dir = {str(tmp_path / 'out')!r}\n")
    cell_end = rest.index("# %%")
    script = head + marker + rest[:cell_end] + overrides + rest[cell_end:]
    # Displays (bare expressions) are no-ops in a script; plots go to the Agg backend.
    env = {**os.environ, "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert any((tmp_path / "out").glob("*.png")) and any((tmp_path / "out").glob("*.csv"))
