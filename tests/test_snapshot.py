"""docs/results/, the committed snapshot of the default run: the README's verdict is its verdict, and every
results number the README and docs quote is one it holds (workflow/scripts/snapshot.py)."""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import snapshot  # noqa: E402


def test_the_readme_verdict_is_the_snapshots():
    section = snapshot.readme_section(snapshot.README.read_text())
    assert section == snapshot.readme_verdict().strip("\n") + "\n"
    assert "docs/results/figures/" in section  # the key figure, linked from the README's folder
    for link in __import__("re").findall(r"\]\((docs/results/[^)]+)\)", section):
        assert (ROOT / link).exists(), link


def test_every_results_number_of_the_readme_and_docs_is_in_the_snapshot():
    assert snapshot.check() == []


def test_a_number_the_snapshot_does_not_hold_fails_the_check(tmp_path):
    """The negative control: a results number nobody measured is found, in a README-wide file or in a docs
    paragraph that speaks of the run's tables; the same number quoting a benchmark's command is not checked."""
    snap = tmp_path / "snapshot"
    (snap / "tables").mkdir(parents=True)
    (snap / "tables" / "table2.md").write_text("| 2 | 24.972 | 45.470 | 1.82x |\n")
    values = snapshot.snapshot_values(snap)
    readme = tmp_path / "README.md"
    readme.write_text("Our mean distance at noise level 2 is 123.457e-3 m.\n\nThe ratio is 97.5x.\n\n"
                      "Held: 45.47e-3 m, 1.8x, 24.97-45.47e-3 m.\n")
    docs = tmp_path / "method.md"
    docs.write_text("The default run's Table 2 gives 123.457e-3 m at level 2.\n\nUnrelated: 123.457e-3 m.\n\n"
                    "`benchmarks/flow_rules.py` gives 123.457e-3 m.\n")
    found = snapshot.unheld_numbers([readme, docs], values, {readme})
    assert found == [f"{readme}:1: 123.457e-3 m", f"{readme}:3: 97.5x", f"{docs}:1: 123.457e-3 m"]


def test_a_quoted_number_matches_the_snapshot_at_its_precision():
    assert snapshot.held("5.76", [5.758]) and snapshot.held("5.758", [5.758])
    assert not snapshot.held("5.75", [5.758]) and not snapshot.held("5.7", [5.76])


def test_take_copies_the_results_and_writes_the_verdict_into_the_readme(tmp_path):
    results, docs = tmp_path / "results", tmp_path / "docs" / "results"
    for part, name, content in [("tables", "table2.md", "| 0 | 0.431 |\n"), ("figures", "distances.png", "png"),
                                ("report", "verdict.md", "| 0 | 0.431 |\n\n![key](../figures/distances.png)\n")]:
        (results / part).mkdir(parents=True)
        (results / part / name).write_text(content)
    (docs / "tables").mkdir(parents=True)
    (docs / "tables" / "stale.md").write_text("an old run's table\n")
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n\n{snapshot.BEGIN}\nold verdict\n{snapshot.END}\n\nthe rest\n")
    snapshot.take(results, docs, readme)
    assert (docs / "tables" / "table2.md").read_bytes() == (results / "tables" / "table2.md").read_bytes()
    assert not (docs / "tables" / "stale.md").exists()
    assert snapshot.readme_section(readme.read_text()) == "| 0 | 0.431 |\n\n![key](docs/results/figures/distances.png)\n"
    assert readme.read_text().endswith(f"{snapshot.END}\n\nthe rest\n")
