"""docs/results/, the committed snapshot of the default run: the README's verdict is its verdict, and every
results number the README and docs quote is one it holds (workflow/scripts/snapshot.py)."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
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
                    "`benchmarks/studies/flow_rules.py` gives 123.457e-3 m.\n")
    found = snapshot.unheld_numbers([readme, docs], values, {readme})
    assert found == [f"{readme}:1: 123.457e-3 m", f"{readme}:3: 97.5x", f"{docs}:1: 123.457e-3 m"]


def test_a_quoted_number_matches_the_snapshot_at_its_precision():
    assert snapshot.held("5.76", [5.758]) and snapshot.held("5.758", [5.758])
    assert not snapshot.held("5.75", [5.758]) and not snapshot.held("5.7", [5.76])


def _default_run(results: Path) -> None:
    """A complete default run's files under ``results`` (stand-ins: the CSVs through the library's writer)."""
    import pandas as pd

    from sdm.io import write_csv

    for part, names in snapshot.DEFAULT_RUN.items():
        (results / part).mkdir(parents=True, exist_ok=True)
        for name in names:
            if name.endswith(".csv"):
                write_csv(results / part / name, pd.DataFrame({"level": [0, 1], "mean_m": [0.000431, 0.03]}))
            else:
                (results / part / name).write_text(f"{name} of this run\n")
    (results / "tables" / "table2.md").write_text("| 0 | 0.431 |\n")
    (results / "report" / "verdict.md").write_text("| 0 | 0.431 |\n\n![key](../figures/distances.png)\n")


def test_take_copies_the_results_and_writes_the_verdict_into_the_readme(tmp_path):
    results, docs = tmp_path / "results", tmp_path / "docs" / "results"
    _default_run(results)
    (docs / "tables").mkdir(parents=True)
    (docs / "tables" / "stale.md").write_text("an old run's table\n")
    (docs / "timing.md").write_text("kept\n")
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n\n{snapshot.BEGIN}\nold verdict\n{snapshot.END}\n\nthe rest\n")
    snapshot.take(results, docs, readme)
    assert (docs / "tables" / "table2.md").read_bytes() == (results / "tables" / "table2.md").read_bytes()
    assert not (docs / "tables" / "stale.md").exists() and (docs / "timing.md").read_text() == "kept\n"
    assert snapshot.readme_section(readme.read_text()) == (
        "| 0 | 0.431 |\n\n![key](docs/results/figures/distances.png)\n")
    assert sorted(path.name for path in docs.iterdir()) == ["figures", "report", "tables", "timing.md"]


def _tree(root: Path) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*")) if path.is_file()}


@pytest.mark.parametrize("incomplete", ["no-report", "no-table2", "cut-csv"])
def test_take_on_an_incomplete_run_leaves_the_snapshot_and_readme_byte_identical(tmp_path, incomplete):
    """On main `make snapshot` without results/report replaced the tables and figures first (a half-replaced
    snapshot), and a cut CSV was copied. The snapshot here is a copy of the committed one."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", tmp_path / "README.md"
    shutil.copytree(snapshot.SNAPSHOT, docs)
    shutil.copy2(snapshot.README, readme)
    _default_run(results)
    if incomplete == "no-report":
        shutil.rmtree(results / "report")
    elif incomplete == "no-table2":
        (results / "tables" / "table2.csv").unlink()
    else:
        path = results / "tables" / "table1.csv"
        path.write_bytes(path.read_bytes()[:-3])
    before, readme_before = _tree(docs), readme.read_bytes()
    with pytest.raises(SystemExit, match="the default run is not complete in results/"):
        snapshot.take(results, docs, readme)
    assert _tree(docs) == before and readme.read_bytes() == readme_before


def test_take_never_mixes_the_opt_in_tables_into_the_default_snapshot(tmp_path):
    """On main Tables 5-7 in results/ were copied into docs/results/tables/ without a word."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", tmp_path / "README.md"
    _default_run(results)
    for name in ("table5.md", "table6.csv", "table6.md", "table7.tex", "table7_summary.md"):
        (results / "tables" / name).write_text("opt-in\n")
    (results / "figures" / "objects.png").write_text("opt-in\n")
    readme.write_text(f"{snapshot.BEGIN}\n{snapshot.END}\n")
    snapshot.take(results, docs, readme)
    taken = {part: sorted(path.name for path in (docs / part).iterdir()) for part in snapshot.DEFAULT_RUN}
    assert taken == {part: sorted(names) for part, names in snapshot.DEFAULT_RUN.items()}


def test_the_default_run_is_the_committed_snapshot():
    """DEFAULT_RUN names exactly the files of docs/results/{tables,figures,report}/."""
    for part, names in snapshot.DEFAULT_RUN.items():
        assert sorted(path.name for path in (snapshot.SNAPSHOT / part).iterdir()) == sorted(names)
