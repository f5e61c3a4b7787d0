"""The code shown to users runs as shown."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_library_example_runs():
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Using SDM as a PyTorch layer"):]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2
    namespace: dict = {}
    for block in blocks:  # the second block continues the first one's session
        exec(compile(block, "README.md", "exec"), namespace)
    assert namespace["theta"].grad is not None
