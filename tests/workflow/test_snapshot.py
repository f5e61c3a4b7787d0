"""docs/results/, the committed snapshots (workflow/scripts/snapshot.py): taking one from a run, all or nothing; the
README's verdict is the one the snapshots give; every results number the README and docs quote is one they hold."""
from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import provenance  # noqa: E402
import snapshot  # noqa: E402
from code_deps import fingerprint  # noqa: E402
from provenance import PARTS  # noqa: E402
from run_notebook import STAGE_METADATA  # noqa: E402


def test_the_readme_verdict_is_the_snapshots():
    section = snapshot.readme_section(snapshot.README.read_text())
    assert section == snapshot.assemble().strip("\n") + "\n"
    assert "docs/results/figures/" in section  # the key figure, linked from the README's folder
    for link in re.findall(r"\]\((docs/[^)#]+)", section):
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


# -- taking a snapshot from a run -----------------------------------------------------------------------------


def notebooks(results: Path, stages, code=fingerprint) -> None:
    """Executed notebooks under ``results/notebooks/``, one per stage, each recording its stage's code as the runner
    does (workflow/scripts/run_notebook.py)."""
    (results / "notebooks").mkdir(parents=True, exist_ok=True)
    for stage in stages:
        notebook = {"cells": [], "metadata": {STAGE_METADATA: {"name": stage, "code": code(stage)}}}
        (results / "notebooks" / f"{stage}.ipynb").write_text(json.dumps(notebook))


def fake_run(results: Path, name: str = "default") -> None:
    """A complete, current run of snapshot ``name`` under ``results``: its files (the CSVs through the library's
    writer, the facts the committed snapshot's) and an executed notebook per stage."""
    import pandas as pd

    from sdm.io import write_csv

    part = PARTS[name]
    for source in part.files.values():
        path = results / source
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix == ".csv":
            write_csv(path, pd.DataFrame({"level": [0, 1], "mean_m": [0.000431, 0.03]}))
        else:
            path.write_text(f"{source} of this run\n")
    if part.facts:
        shutil.copy2(part.path() / part.facts, results / part.files[part.facts])
    if "tables/table2.md" in part.files:
        (results / "tables" / "table2.md").write_text("| 0 | 0.431 |\n")
    notebooks(results, part.stages)


def _readme(path: Path) -> Path:
    path.write_text(f"# Title\n\n{snapshot.BEGIN}\nold verdict\n{snapshot.END}\n\nthe rest\n")
    return path


def test_take_copies_the_results_writes_the_provenance_and_the_verdict(tmp_path):
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", _readme(tmp_path / "README.md")
    fake_run(results)
    (docs / "tables").mkdir(parents=True)
    (docs / "tables" / "stale.md").write_text("an old run's table\n")
    (docs / "timing.md").write_text("kept\n")
    snapshot.take("default", results, docs, readme)
    assert (docs / "tables" / "table2.md").read_bytes() == (results / "tables" / "table2.md").read_bytes()
    assert not (docs / "tables" / "stale.md").exists() and (docs / "timing.md").read_text() == "kept\n"
    assert sorted(path.name for path in docs.iterdir()) == ["PROVENANCE.json", "figures", "report", "tables",
                                                            "timing.md"]
    recorded = provenance.read(docs)
    assert recorded["stages"] == {stage: fingerprint(stage) for stage in PARTS["default"].stages}
    assert recorded["config"]["files"] == ["config.yaml"] and len(recorded["config"]["sha256"]) == 64
    assert recorded["commit"] and re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", recorded["date"])
    assert provenance.file_problems(PARTS["default"], docs, recorded) == []
    assert provenance.stale_stages(PARTS["default"], recorded) == []
    section = snapshot.readme_section(readme.read_text())
    assert section == snapshot.assemble(docs).strip("\n") + "\n"
    assert f"commit {recorded['commit'][:7]}" in section


def test_snapshots_taken_together_read_each_other_as_taken(tmp_path):
    """Taken together, each snapshot's verdict facts are read from the take itself: Table 6's snapshot, which alone
    needs the default's committed facts, is taken with the default's into an empty folder, and the README's verdict
    names both at this commit. A run that is not complete leaves every snapshot and the README as they were."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", _readme(tmp_path / "README.md")
    fake_run(results)
    fake_run(results, "objects")
    with pytest.raises(SystemExit, match="missing"):  # alone, Table 6's take reads a default snapshot there is not
        snapshot.take("objects", results, docs, readme)
    before = readme.read_text()
    (results / PARTS["objects"].files["table6.csv"]).unlink()
    with pytest.raises(SystemExit, match="'objects' is not complete"):
        snapshot.take_all(["default", "objects"], {"default": results, "objects": results}, docs, readme)
    assert readme.read_text() == before and not (docs / "tables").exists()
    fake_run(results, "objects")
    snapshot.take_all(["default", "objects"], {"default": results, "objects": results}, docs, readme)
    commit = provenance.read(docs)["commit"]
    assert provenance.read(docs / "objects")["commit"] == commit
    section = snapshot.readme_section(readme.read_text())
    assert section == snapshot.assemble(docs).strip("\n") + "\n" and "docs/results/objects/" in section


def test_an_opt_in_take_replaces_its_files_and_keeps_the_folders_own(tmp_path):
    """Table 6's snapshot beside the default's: its README and measurement logs stay, its files are the run's, and
    the README's verdict gains the answers that read it."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", _readme(tmp_path / "README.md")
    fake_run(results)
    snapshot.take("default", results, docs, readme)
    without = snapshot.readme_section(readme.read_text())
    fake_run(results, "objects")
    folder = docs / "objects"
    folder.mkdir()
    (folder / "README.md").write_text("kept\n")
    (folder / "table6.md").write_text("an old table\n")
    snapshot.take("objects", results, docs, readme)
    assert (folder / "README.md").read_text() == "kept\n"
    assert (folder / "table6.md").read_text() == "tables/table6.md of this run\n"
    assert (folder / "objects.png").read_text() == "figures/objects.png of this run\n"
    assert sorted(path.name for path in folder.iterdir()) == sorted([*PARTS["objects"].files, "README.md",
                                                                      "PROVENANCE.json"])
    assert provenance.read(folder)["config"]["files"] == ["config.yaml", "profiles/snapshots/objects.yaml"]
    section = snapshot.readme_section(readme.read_text())
    assert "docs/results/objects/" in section and "docs/results/objects/" not in without


def _tree(root: Path) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*")) if path.is_file()}


@pytest.mark.parametrize("incomplete", ["no-report", "no-table2", "cut-csv", "no-notebook", "edited-code",
                                        "two-versions"])
def test_take_on_an_incomplete_run_leaves_the_snapshot_and_readme_byte_identical(tmp_path, incomplete):
    """A run missing a file, with a damaged CSV, a stage that did not run, one that ran other code than the
    working tree's or two versions of it: nothing is taken. The snapshot here is a copy of the committed one."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", tmp_path / "README.md"
    shutil.copytree(snapshot.SNAPSHOT, docs)
    shutil.copy2(snapshot.README, readme)
    fake_run(results)
    expected = "the run of snapshot 'default' is not complete and current"
    if incomplete == "no-report":
        shutil.rmtree(results / "report")
    elif incomplete == "no-table2":
        (results / "tables" / "table2.csv").unlink()
    elif incomplete == "cut-csv":
        path = results / "tables" / "table1.csv"
        path.write_bytes(path.read_bytes()[:-3])
    elif incomplete == "no-notebook":
        (results / "notebooks" / "table3.ipynb").unlink()
        expected = "stage table3: no executed notebook"
    elif incomplete == "edited-code":
        notebooks(results, ["noise"], code=lambda stage: "0" * 64)
        expected = "stage noise: it ran other code than the working tree's"
    else:
        notebooks(results / "other", ["noise"], code=lambda stage: "0" * 64)
        shutil.copy2(results / "other" / "notebooks" / "noise.ipynb", results / "notebooks" / "noise_level1.ipynb")
        expected = "stage noise: its jobs ran 2 versions of its code"
    before, readme_before = _tree(docs), readme.read_bytes()
    with pytest.raises(SystemExit, match=expected):
        snapshot.take("default", results, docs, readme)
    assert _tree(docs) == before and readme.read_bytes() == readme_before


def test_take_never_mixes_the_opt_in_tables_into_the_default_snapshot(tmp_path):
    """Tables 5-7 in results/ stay out of docs/results/tables/: their snapshots have folders of their own."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", _readme(tmp_path / "README.md")
    fake_run(results)
    for name in ("table5.md", "table6.csv", "table6.md", "table7.tex", "table7_summary.md"):
        (results / "tables" / name).write_text("opt-in\n")
    (results / "figures" / "objects.png").write_text("opt-in\n")
    snapshot.take("default", results, docs, readme)
    taken = {part: sorted(path.name for path in (docs / part).iterdir()) for part in snapshot.DEFAULT_RUN}
    assert taken == {part: sorted(names) for part, names in snapshot.DEFAULT_RUN.items()}


def test_the_default_run_is_the_committed_snapshot():
    """DEFAULT_RUN names exactly the files of docs/results/{tables,figures,report}/."""
    for part, names in snapshot.DEFAULT_RUN.items():
        assert sorted(path.name for path in (snapshot.SNAPSHOT / part).iterdir()) == sorted(names)


def test_the_report_stage_reads_nothing_of_docs_results():
    """The verdict's other snapshots are read by the snapshot tool, never by the workflow: no rule file names
    docs/results/ (committed output never feeds a run)."""
    rules = [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]
    code = {path.name: re.sub(r"#.*", "", path.read_text()) for path in rules}  # comments may name a snapshot
    assert [name for name, text in code.items() if "docs/results" in text] == []


def test_a_readme_verdict_edited_by_hand_fails_the_check(tmp_path):
    readme = tmp_path / "README.md"
    text = snapshot.README.read_text()
    section = snapshot.readme_section(text)
    readme.write_text(text.replace(section.strip("\n"), section.strip("\n").replace(" mm", " m", 1)))
    assert "the verdict section is not the one the snapshots give" in snapshot.check(readme)[0]


@pytest.mark.parametrize("name", ["default", "sample", "objects", "network"])
def test_each_snapshots_verdict_facts_are_computed_from_its_own_tables(name):
    """The committed facts files are the library's facts of the snapshot's CSVs (workflow/scripts/verdict_facts.py,
    the same functions the stages call): generated, never typed. A snapshot known to be stale holds the facts of
    the code that made it, so it is left out until it is taken again."""
    import verdict_facts

    if name in provenance.KNOWN_STALE:
        pytest.skip(f"docs/results/{PARTS[name].folder} is known to be stale: {provenance.KNOWN_STALE[name]}")
    part = PARTS[name]
    assert verdict_facts.facts_of(name, part.path()) == json.loads((part.path() / part.facts).read_text())


def test_take_records_each_jobs_cpu_and_wall_time_from_its_benchmark_file(tmp_path):
    """The provenance holds the times Snakemake measured (results/benchmarks/<job>.tsv, last line), per job and
    summed per stage, so that a snapshot's README quotes no time typed by hand; a job without one is left out."""
    results, docs, readme = tmp_path / "results", tmp_path / "docs" / "results", _readme(tmp_path / "README.md")
    fake_run(results)
    snapshot.take("default", results, docs, readme)  # the verdict an opt-in take writes reads the default's facts
    fake_run(results, "objects")
    stage = "objects_runs"
    notebook = (results / "notebooks" / f"{stage}.ipynb").read_text()
    for job in ("objects_scale12_car_level0", "objects_scale12_car_level2"):
        (results / "notebooks" / f"{job}.ipynb").write_text(notebook)
    (results / "notebooks" / f"{stage}.ipynb").unlink()
    (results / "benchmarks").mkdir()
    header = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
    (results / "benchmarks" / "objects_scale12_car_level0.tsv").write_text(
        header + "9.0\t0:00:09\t1\t1\t1\t1\t0\t0\t50\t8.0\n" + "479.37\t0:07:59\t1\t1\t1\t1\t0\t0\t93\t447.49\n")
    (results / "benchmarks" / "objects_scale12_car_level2.tsv").write_text(
        header + "575.89\t0:09:35\t1\t1\t1\t1\t0\t0\t95\t549.191\n")
    (results / "benchmarks" / "table6.tsv").write_text(header + "11.7\t0:00:11\t1\t1\t1\t1\t0\t0\t90\t10.98\n")
    snapshot.take("objects", results, docs, readme)
    recorded = provenance.read(PARTS["objects"].path(docs))
    assert recorded["jobs"] == {
        "objects_scale12_car_level0": {"stage": stage, "cpu_s": 447.49, "wall_s": 479.37},
        "objects_scale12_car_level2": {"stage": stage, "cpu_s": 549.19, "wall_s": 575.89},
        "table6": {"stage": "table6", "cpu_s": 10.98, "wall_s": 11.7}}
    assert recorded["stage_cpu_s"] == {stage: 996.68, "table6": 10.98}
