"""The code shown to users runs as shown."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_library_example_runs():
    blocks = python_blocks(ROOT / "docs" / "library.md")
    assert len(blocks) == 2
    namespace: dict = {}
    for block in blocks:  # the second block continues the first one's session
        exec(compile(block, "docs/library.md", "exec"), namespace)
    assert namespace["theta"].grad is not None
