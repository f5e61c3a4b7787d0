"""The workflow on real annotations: files tracked by content, images without cars, an all-empty folder.

A copy of the shipped 57 real frames (data/apollocar3d-sample) with annotation files without cars mixed in,
run end to end once (the session fixture ``real_run``) in a temporary directory, as tests/workflow/test_workflow.py
runs the ``.test`` config; a file of its own so that, under pytest-xdist (``make test``), one worker runs it
beside that file's run.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import yaml

from test_workflow import APOLLO_SAMPLE, _merge, default_config, planned, snakemake, snakemakes, workdir

pytestmark = pytest.mark.workflow


def _real_folder(path: Path, n_empty: int) -> Path:
    """A copy of the shipped 57 real frames (or none) plus ``n_empty`` annotation files without cars."""
    path.mkdir(parents=True)
    (path / "car_poses").mkdir()
    shutil.copytree(APOLLO_SAMPLE / "camera", path / "camera")
    if n_empty < 1000:
        for source in sorted((APOLLO_SAMPLE / "car_poses").glob("*.json")):
            shutil.copy(source, path / "car_poses" / source.name)
    for i in range(n_empty % 1000):
        (path / "car_poses" / f"empty_{i:03d}.json").write_text("[]\n")
    return path


def _small_real_config(folder: Path, n_images: int) -> dict:
    return _merge(default_config(), {
        "data": {"source": "apollo", "apollo_folder": str(folder)},
        "sky": {"n_images": n_images},
        "split": {"n_selected": 40, "n_train": 24, "n_dev": 16},
        "tuning": {"n_epoch": [2], "lr": [1.0e-3]},
        "noise": {"levels": [0, 2], "runs": 2, "chunk_size": 2},
        "baselines": {"enabled": False},
        "floor": {"enabled": False},
        "research": {"rules": {"enabled": False}},
    })


@pytest.fixture(scope="session")
def real_run(tmp_path_factory) -> Path:
    """The 57 real frames with 30 annotation files without cars mixed in, run end to end."""
    root = tmp_path_factory.mktemp("real_run")
    folder = _real_folder(root / "annotations", n_empty=30)
    directory = workdir(root / "run", _small_real_config(folder, n_images=80))
    result = snakemake("-c2", cwd=directory)
    assert result.returncode == 0, (result.stdout + result.stderr)[-5000:]
    return directory


def test_real_frames_with_empty_annotation_files_mixed_in_complete(real_run):
    summary = json.loads((real_run / "results" / "data" / "summary.json").read_text())
    assert summary["images"] == 87 and summary["images_without_car_on_screen"] >= 30
    table2 = (real_run / "results" / "tables" / "table2.csv").read_text()
    assert "nan" not in table2.lower()
    assert "NaN" not in (real_run / "results" / "sky" / "stats.json").read_text()


@pytest.mark.parametrize("change", ["edit", "add", "remove"])
def test_a_changed_annotation_file_reruns_the_data_stage(real_run, tmp_path, change):
    """Adding, removing or editing one annotation file reruns the data stage (and what follows)."""
    config = yaml.safe_load((real_run / "config.yaml").read_text())
    folder = Path(config["data"]["apollo_folder"])
    victim = sorted((folder / "car_poses").glob("*.json"))[0]
    original = victim.read_bytes()
    try:
        if change == "edit":
            cars = json.loads(original)
            cars[0]["pose"][5] += 1.0
            victim.write_text(json.dumps(cars))
            os.utime(victim, ns=(victim.stat().st_atime_ns, victim.stat().st_mtime_ns - 10**12))  # even an old mtime
        elif change == "add":
            (folder / "car_poses" / "added.json").write_text("[]\n")
        else:
            victim.unlink()
        jobs = planned(snakemake("-n", "--quiet", "rules", cwd=real_run))
        assert "data" in jobs and "sky" in jobs and "report" in jobs, jobs
    finally:
        victim.write_bytes(original)
        (folder / "car_poses" / "added.json").unlink(missing_ok=True)
    assert planned(snakemake("-n", "--quiet", "rules", cwd=real_run)) == {}  # restored: nothing to do


def test_an_edited_annotation_changes_what_follows_and_a_moved_folder_changes_nothing(real_run, tmp_path):
    """The same annotations in another folder: the data stage reruns (a new param) and writes the same bytes, so
    nothing after it can differ. The cars of a training image edited in place: the data stage reruns, its Sky
    statistics change, and every stage up to the tables and the report is planned after it. Each on a copy of
    the completed run; the two reruns run side by side (one core each), each only as far as it has to: what a
    stage writes from the same inputs is checked elsewhere (the same config gives byte-identical tables)."""
    config = yaml.safe_load((real_run / "config.yaml").read_text())
    folder = Path(config["data"]["apollo_folder"])
    moved, edited = tmp_path / "moved", tmp_path / "edited"
    for directory in (moved, edited):
        shutil.copytree(real_run, directory, symlinks=True, ignore=shutil.ignore_patterns("locks", "incomplete"))
    copy_dir = _real_folder(tmp_path / "annotations", n_empty=30)
    workdir(moved, _merge(config, {"data": {"apollo_folder": str(copy_dir)}}))
    assert "data" in planned(snakemake("-n", "--quiet", "rules", cwd=moved))  # a new folder is a new param
    split = json.loads((real_run / "results" / "split" / "split.json").read_text())
    victim = folder / "car_poses" / f"{split['train_ids'][0]}.json"  # the run's own folder: restored below
    original = victim.read_bytes()
    try:
        cars = json.loads(original)
        for car in cars:
            car["pose"][3] += 0.8  # every car of a training image 0.8 m to the right
        victim.write_text(json.dumps(cars))
        results = snakemakes((moved, ("-c1", "--until", "data")), (edited, ("-c1", "--until", "sky")))
        for result in results:
            assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
        after_edit = planned(snakemake("-n", "--quiet", "rules", cwd=edited))
    finally:
        victim.write_bytes(original)
    data = sorted(path.relative_to(real_run).as_posix() for path in (real_run / "results" / "data").rglob("*")
                  if path.is_file())
    assert data and all((moved / path).read_bytes() == (real_run / path).read_bytes() for path in data)
    stats = (real_run / "results" / "sky" / "stats.json").read_text()
    assert (edited / "results" / "sky" / "stats.json").read_text() != stats  # the edit reached the statistics
    assert "data" not in after_edit and {"split", "tables", "report"} <= set(after_edit), after_edit
    assert planned(snakemake("-n", "--quiet", "rules", cwd=real_run)) == {}  # restored: nothing to do


def test_an_all_empty_annotation_folder_fails_at_the_first_stage_naming_it(tmp_path):
    folder = _real_folder(tmp_path / "empty_annotations", n_empty=1000 + 8)
    config = _small_real_config(folder, n_images=8)
    config["split"] = {"n_selected": 4, "n_train": 2, "n_dev": 2, "seed": 0}
    config["figures"]["example"] = 0
    result = snakemake("-c1", cwd=workdir(tmp_path / "run", config))
    output = result.stdout + result.stderr
    assert result.returncode != 0
    causes = [line for line in output.splitlines() if " failed: " in line]
    assert causes and "notebooks/data.py" in causes[0] and str(folder) in causes[0], output[-3000:]
    assert not (tmp_path / "run" / "results" / "sample").exists()
