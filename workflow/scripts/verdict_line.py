"""An opt-in table's line of the verdict from its committed snapshot, without rerunning the default run.

    PYTHONPATH=src python workflow/scripts/verdict_line.py table6     # or table7

Writes the table's line (:data:`LINES`: its prefix, the snapshot's CSV and the sentence that reads it; the line the
default run's report stage makes from that snapshot when the table is off) over that line of
``docs/results/report/verdict.md`` and of the README's verdict section, and prints it. Exits naming the file where
either has no such line, or more than one.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Per table: the verdict line's prefix, its snapshot's CSV (under docs/results/) and the module of its sentence.
LINES = {
    "table6": ("- **Parameters attached to points (Table 6):** ", "objects/table6.csv", "sdm.report.objects"),
    "table7": ("- **SDM inside a network (Table 7):** ", "network/table7.csv", "sdm.report.network"),
}


def main(table: str = "table6") -> int:
    import importlib

    from sdm.io import write_text
    from sdm.report.io import read_csv

    if table not in LINES:
        raise SystemExit(f"table must be one of {sorted(LINES)}, got {table!r}")
    prefix, csv, module = LINES[table]
    sentence = importlib.import_module(module).verdict_sentence
    line = prefix + sentence(read_csv(ROOT / "docs" / "results" / csv))
    paths = (ROOT / "docs" / "results" / "report" / "verdict.md", ROOT / "README.md")
    texts = {}
    for path in paths:
        lines = path.read_text().split("\n")
        found = [i for i, text in enumerate(lines) if text.startswith(prefix)]
        if len(found) != 1:
            raise SystemExit(f"{path}: {len(found)} lines begin {prefix.strip()!r}; expected one")
        lines[found[0]] = line
        texts[path] = "\n".join(lines)
    for path, text in texts.items():
        write_text(path, text)
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:2]))
