"""The verdict's Table 6 line from the committed snapshot, without rerunning the default run.

    PYTHONPATH=src python workflow/scripts/table6_verdict.py

Writes ``- **Parameters attached to points (Table 6):** ...`` (:func:`sdm.report.objects.verdict_sentence` of
``docs/results/objects/table6.csv``, the line the default run's report stage makes from that snapshot when Table 6
is off) over that line of ``docs/results/report/verdict.md`` and of the README's verdict section, and prints it.
Exits naming the file where either has no such line, or more than one.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PREFIX = "- **Parameters attached to points (Table 6):** "


def main() -> int:
    from sdm.io import write_text
    from sdm.report.io import read_csv
    from sdm.report.objects import verdict_sentence

    line = PREFIX + verdict_sentence(read_csv(ROOT / "docs" / "results" / "objects" / "table6.csv"))
    paths = (ROOT / "docs" / "results" / "report" / "verdict.md", ROOT / "README.md")
    texts = {}
    for path in paths:
        lines = path.read_text().split("\n")
        found = [i for i, text in enumerate(lines) if text.startswith(PREFIX)]
        if len(found) != 1:
            raise SystemExit(f"{path}: {len(found)} lines begin {PREFIX.strip()!r}; expected one")
        lines[found[0]] = line
        texts[path] = "\n".join(lines)
    for path, text in texts.items():
        write_text(path, text)
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
