"""The one atomic writer (sdm.io): files get the mode a plain open() gives them, and a failed write leaves nothing."""
from __future__ import annotations

import importlib.util
import os
import re
import stat
from pathlib import Path

import pandas as pd
import pytest

import sdm.errors
import sdm.io
import sdm.experiments.report.io
from sdm.camera import APOLLO_CAMERA_5
from sdm.experiments.data import write_sky_file, write_synthetic_apollo
from sdm.sky import SKY_SHIFT

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def umask():
    """Set the process umask for one test (restored afterwards)."""
    previous = os.umask(0o022)
    yield os.umask
    os.umask(previous)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def runner_writer():
    """The writer as workflow/scripts/run_notebook.py loads it (code_deps.library_io: by path, without importing
    sdm)."""
    spec = importlib.util.spec_from_file_location("code_deps_for_test", ROOT / "workflow" / "scripts" / "code_deps.py")
    deps = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(deps)
    return deps.library_io()


def write_everything(folder: Path) -> dict[str, Path]:
    """One file (or folder) from every writer the workflow uses."""
    import matplotlib.pyplot as plt

    from sdm.experiments.report.figures import save_figure

    figure, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    return {
        "text": sdm.io.write_text(folder / "a.md", "# a\n"),
        "json": sdm.experiments.report.io.write_json(folder / "b.json", {"x": 1}),
        "csv": sdm.experiments.report.io.write_csv(folder / "c.csv", pd.DataFrame({"x": [1, 2]})),
        "bytes": sdm.io.write_bytes(folder / "d.bin", b"\x00\x01"),
        "png": save_figure(figure, folder / "e.png", pdf=True),
        "pdf": folder / "e.pdf",
        "sky": (write_sky_file(folder / "sky.bin", [], SKY_SHIFT, APOLLO_CAMERA_5), folder / "sky.bin")[1],
        "html": runner_writer().write_text(folder / "f.html", "<html></html>"),
        "synthetic": write_synthetic_apollo(folder / "synthetic", n_images=2, seed=0),
    }


@pytest.mark.parametrize("mask, file_mode, folder_mode", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700), (0o002, 0o664, 0o775)])
def test_files_get_the_mode_of_a_plain_open_under_the_umask(tmp_path, umask, mask, file_mode, folder_mode):
    umask(mask)
    (tmp_path / "plain.txt").write_text("reference")  # what open() gives, for comparison
    assert mode(tmp_path / "plain.txt") == file_mode
    written = write_everything(tmp_path / "out")
    for kind, path in written.items():
        assert path.exists(), kind
        expected = folder_mode if path.is_dir() else file_mode
        assert mode(path) == expected, f"{kind}: {oct(mode(path))} != {oct(expected)}"
    for path in (written["synthetic"] / "car_poses").iterdir():
        assert mode(path) == file_mode
    # nothing but the outputs is left in the folder (no temporary file)
    assert not [p.name for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]


def test_the_umask_is_read_without_changing_it(umask):
    umask(0o027)
    assert sdm.io.current_umask() == 0o027
    assert os.umask(0o027) == 0o027


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path, error):
    path = sdm.io.write_text(tmp_path / "table.md", "old complete content\n")

    def half_then_fail(temporary: Path) -> None:
        with temporary.open("w") as stream:
            stream.write("new but only half")
            stream.flush()
            raise error

    with pytest.raises(type(error)):
        sdm.io.write_atomic(path, half_then_fail)
    assert path.read_text() == "old complete content\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]

    with pytest.raises(type(error)):
        sdm.io.write_atomic(tmp_path / "new.md", half_then_fail)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]


def test_a_failing_figure_or_csv_writer_leaves_nothing(tmp_path):
    class Unwritable:
        def to_csv(self, path=None, index=False):
            if path is not None:
                Path(path).write_text("x\n1\n")
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        sdm.io.write_csv(tmp_path / "t.csv", Unwritable())
    assert list(tmp_path.iterdir()) == []


def test_the_temporary_keeps_the_suffix_and_is_hidden(tmp_path):
    seen = []
    sdm.io.write_atomic(tmp_path / "fig.png", lambda temporary: (seen.append(temporary), temporary.write_bytes(b"png")))
    (temporary,) = seen
    assert temporary.parent == tmp_path and temporary.name.startswith(".fig.") and temporary.suffix == ".png"
    assert (tmp_path / "fig.png").read_bytes() == b"png" and not temporary.exists()


def test_there_is_one_atomic_writer():
    """No other module creates temporary files and renames them into place (the synthetic folder is a folder)."""
    assert sdm.experiments.report.io.write_atomic is sdm.io.write_atomic
    offenders = []
    for path in [*(ROOT / "src").rglob("*.py"), *(ROOT / "workflow" / "scripts").glob("*.py")]:
        if path.name == "io.py" and path.parent.name == "sdm":
            continue
        text = path.read_text()
        if re.search(r"\bmkstemp\b|NamedTemporaryFile|os\.replace\(", text) and path.name != "synthetic.py":
            offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_a_csv_is_written_with_its_checksum_and_read_back_checked(tmp_path):
    frame = pd.DataFrame({"level": [0, 1, 2], "distance_m": [0.1, 0.25, 1.0 / 3.0]})
    path = sdm.io.write_csv(tmp_path / "runs.csv", frame)
    assert path.read_bytes() == frame.to_csv(index=False).encode()
    digest, rows = (tmp_path / "runs.csv.sha256").read_text().split()[:2]
    assert rows == "3" and len(digest) == 64
    pd.testing.assert_frame_equal(sdm.experiments.report.io.read_csv(path), pd.read_csv(path))


@pytest.mark.parametrize("cut", [14, 3, 40], ids=["last-value", "last-digits", "mid-row"])
def test_a_cut_csv_is_refused_naming_it_and_removed_for_its_job_to_rerun(tmp_path, cut):
    """As ``head -c -14``: on main Table 2 was rebuilt from a chunk whose last value was cut, and a chunk cut
    mid-row failed later naming no file."""
    frame = pd.DataFrame({"level": [2] * 4, "run": range(4), "distance_m": [0.04991912345678, 0.05, 0.06, 0.07]})
    path = sdm.io.write_csv(tmp_path / "level2_chunk0.csv", frame)
    path.write_bytes(path.read_bytes()[:-cut])
    with pytest.raises(sdm.errors.SDMInputError, match=r"level2_chunk0\.csv: damaged result: its bytes do not match "
                       r"level2_chunk0\.csv\.sha256 \(written with 4 rows"):
        sdm.experiments.report.io.read_csv(path)
    assert not path.exists() and not (tmp_path / "level2_chunk0.csv.sha256").exists()


def test_a_csv_rewritten_leaves_no_stale_checksum(tmp_path):
    """The old checksum file goes before the new CSV: a write stopped between the two is read unchecked (the CSV
    itself is whole: written atomically), never refused against the old checksum."""
    path = sdm.io.write_csv(tmp_path / "t.csv", pd.DataFrame({"x": [1]}))

    class Failing:
        def to_csv(self, path=None, index=False):
            raise RuntimeError("stopped")

    with pytest.raises(RuntimeError, match="stopped"):
        sdm.io.write_csv(path, Failing())
    assert not (tmp_path / "t.csv.sha256").exists() and sdm.io.csv_damage(path) is None


def test_no_stage_notebook_reads_a_csv_unchecked():
    """The stages read their CSVs through sdm.experiments.report.io.read_csv (checksum first), never pandas' reader directly."""
    notebooks = sorted((ROOT / "notebooks").glob("*.py"))
    assert len(notebooks) > 20
    unchecked = [path.name for path in notebooks if "pd.read_csv(" in path.read_text()]
    assert unchecked == []
