"""Every committed snapshot says where it comes from (its PROVENANCE.json: workflow/scripts/provenance.py), and is
fresh -- its stages' code is the working tree's -- unless KNOWN_STALE names it with the reason.

A ratchet, as tests/test_package_layout.py's sizes: a snapshot not listed must be fresh, a listed one that has
become fresh must come off the list. A failure names the snapshot and the command that refreshes it.
"""
from __future__ import annotations

import importlib.util
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import provenance  # noqa: E402
from provenance import KNOWN_STALE, PARTS  # noqa: E402


def test_every_snapshot_is_fresh_or_known_stale():
    assert provenance.ratchet(provenance.staleness()) == []


def test_every_snapshot_holds_the_files_its_provenance_records():
    """Each snapshot's files are the bytes its PROVENANCE.json records (no edit by hand after the take), and it
    records every file of the snapshot."""
    problems = {name: provenance.file_problems(part, part.path(), provenance.read(part.path()))
                for name, part in PARTS.items()}
    assert {name: found for name, found in problems.items() if found} == {}


def test_each_provenance_names_its_commit_date_and_config():
    for name, part in PARTS.items():
        recorded = provenance.read(part.path())
        assert recorded["snapshot"] == name and recorded["config"]["files"] == list(part.config)
        assert re.fullmatch(r"[0-9a-f]{40}", recorded["commit"]) and recorded["date"][:2] == "20"
        assert recorded["take"] == part.take and recorded["run"] == part.run
        if recorded["stages"] is None:  # copied by hand: says so, and is on the list
            assert recorded["note"] and name in KNOWN_STALE


def test_each_overlay_of_the_makefile_is_the_snapshots():
    """`make run-<name>` merges the overlay PARTS names for the snapshot's provenance (config.yaml first)."""
    overlays = dict(re.findall(r"^OVERLAY_(\w+) := (\S+)$", (ROOT / "Makefile").read_text(), flags=re.M))
    assert overlays == {name: part.config[1] for name, part in PARTS.items() if name != "default"}
    assert PARTS["default"].config == ("config.yaml",)
    assert all((ROOT / path).is_file() for part in PARTS.values() for path in part.config)


def _code_deps_of(root: Path):
    """workflow/scripts/code_deps.py of the project copy at ``root``: its fingerprints are that copy's code's."""
    path = root / "workflow" / "scripts" / "code_deps.py"
    spec = importlib.util.spec_from_file_location(f"code_deps_{root.name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def project(tmp_path) -> Path:
    """The code a stage's fingerprint covers, copied: the notebooks, the library and the runner scripts."""
    root = tmp_path / "project"
    for folder in ("notebooks", "src/sdm", "workflow/scripts"):
        shutil.copytree(ROOT / folder, root / folder, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(ROOT / "Snakefile", root / "Snakefile")
    return root


def test_a_planted_edit_of_a_stages_code_makes_its_snapshot_stale(project, tmp_path):
    """The negative control: a snapshot taken at the copy's code is fresh; an edit of a module Table 6's stage runs
    makes it stale, and the ratchet names the snapshot, the stage and the command that refreshes it."""
    part = PARTS["objects"]
    before = _code_deps_of(project)
    folder = tmp_path / "docs" / "results" / "objects"
    folder.mkdir(parents=True)
    for name in part.files:
        (folder / name).write_text(name)
    recorded = provenance.record(part, folder, {stage: before.fingerprint(stage) for stage in part.stages})
    assert provenance.stale_stages(part, recorded, before.fingerprint) == []
    assert provenance.ratchet({"objects": []}, known={}) == []

    module = project / "src" / "sdm" / "experiments" / "report" / "objects.py"
    module.write_text(module.read_text() + "\nPLANTED = 1\n")  # code, not a comment: its syntax tree changes
    after = _code_deps_of(project)
    stale = provenance.stale_stages(part, recorded, after.fingerprint)
    assert stale == ["table6"]
    found = provenance.ratchet({"objects": stale}, known={})
    assert found == ["docs/results/objects/ is stale (table6): refresh it with "
                     "`make run-objects && make snapshot-objects`, or list it in KNOWN_STALE "
                     "(workflow/scripts/provenance.py) with the reason"]
    assert provenance.ratchet({"objects": stale}, known={"objects": "planted"}) == []


def test_a_listed_snapshot_that_is_fresh_must_come_off_the_list():
    assert provenance.ratchet({"depth": []}, known={"depth": "old"}) == [
        "docs/results/depth/ is fresh: take 'depth' off KNOWN_STALE (workflow/scripts/provenance.py)"]
    assert provenance.ratchet({"depth": ["no code fingerprint recorded"]}, known={"depth": "old", "gone": "x"}) == [
        "KNOWN_STALE names 'gone', which is no snapshot"]


def test_a_snapshot_without_fingerprints_is_stale():
    part = PARTS["network"]
    assert provenance.stale_stages(part, None) == ["no provenance file"]
    assert provenance.stale_stages(part, {"stages": None}) == ["no code fingerprint recorded"]
    assert provenance.stale_stages(part, {"stages": {"table7": "x"}}, lambda stage: "x") == [
        stage for stage in part.stages if stage != "table7"]  # a stage it does not record counts as changed


def test_a_file_edited_by_hand_after_the_take_is_found(tmp_path):
    part = PARTS["depth"]
    for name in part.files:
        (tmp_path / name).write_text(name)
    recorded = provenance.record(part, tmp_path, {})
    assert provenance.file_problems(part, tmp_path, recorded) == []
    (tmp_path / "table5.md").write_text("edited\n")
    assert provenance.file_problems(part, tmp_path, recorded) == [
        f"{tmp_path / 'table5.md'}: not the bytes PROVENANCE.json records"]
