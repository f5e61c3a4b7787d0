"""Packaging: installing the library beside a researcher's own torch 2.x leaves that torch in place.

pyproject.toml declares compatible ranges (``torch>=2.4``); the exact tested versions are in
constraints.txt, which only ``make`` installs with. The test asks pip's resolver what it would do in an
environment that already holds another torch 2.x release, with a newer torch on offer:

- the environment is a fresh venv whose site-packages holds a symlink to every entry of this test's own
  site-packages except torch and this project's installed copies, plus a metadata-only ``torch 2.5.1``
  (a dist-info folder: enough for pip and importlib.metadata to see it installed). Exactly one torch is
  visible, so nothing depends on which of two shadowing copies pip happens to read first. (A
  ``--system-site-packages`` venv would not do: made from a venv's interpreter it sees the *base*
  interpreter's site-packages, not this environment's, and it would show both torches.)
- the only package source is a local folder holding a metadata-only ``torch 2.13.0`` wheel
  (``--no-index``, pip's configuration files and ``PIP_*`` variables switched off), so pip *could*
  change torch if the requirement asked for it;
- ``pip install --dry-run --report`` on a copy of the project (pyproject.toml, README.md, LICENSE, src/)
  must plan to install only spatial-domain-mapping, and the venv's torch must still read 2.5.1;
- the negative control: the same resolution on a copy whose pyproject pins ``torch==2.13.0`` (what
  the project once declared) plans to install torch 2.13.0 over it.
"""
from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DECLARED_TORCH = '"torch>=2.4"'
RESEARCHERS_TORCH = "2.5.1"  # an older 2.x release than the tested one (constraints.txt)
OFFERED_TORCH = "2.13.0"
PROJECT = "spatial-domain-mapping"


def _top_level_entries(distribution: str) -> set[str]:
    """The site-packages entries (packages, dist-info folders, .pth files) of an installed distribution."""
    try:
        files = importlib.metadata.distribution(distribution).files or []
    except importlib.metadata.PackageNotFoundError:
        return set()
    return {path.parts[0] for path in files if path.parts[0] != ".."}


def _researchers_venv(directory: Path) -> Path:
    """A venv holding this environment's packages but with torch 2.5.1 (metadata only) as its torch.

    Returns the venv's python.
    """
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(directory)], check=True, timeout=120)
    python = directory / "bin" / "python"
    site_packages = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                        capture_output=True, text=True, check=True, timeout=60).stdout.strip())
    # torch and the project itself (an editable install under either distribution name) stay out.
    left_out = {"__pycache__"}
    for distribution in ("torch", PROJECT, "sdm"):
        left_out |= _top_level_entries(distribution)
    ours = {Path(sysconfig.get_paths()[key]) for key in ("purelib", "platlib")}
    for folder in ours:
        for entry in folder.iterdir():
            if entry.name not in left_out and not (site_packages / entry.name).exists():
                (site_packages / entry.name).symlink_to(entry)
    info = site_packages / f"torch-{RESEARCHERS_TORCH}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: torch\nVersion: {RESEARCHERS_TORCH}\n")
    (info / "INSTALLER").write_text("pip\n")
    (info / "RECORD").write_text("".join(f"{info.name}/{name},,\n" for name in ("METADATA", "INSTALLER", "RECORD")))
    return python


def _offered_torch_wheel(folder: Path) -> None:
    """A metadata-only torch 2.13.0 wheel in ``folder``: what pip could install if asked."""
    folder.mkdir()
    info = f"torch-{OFFERED_TORCH}.dist-info"
    with zipfile.ZipFile(folder / f"torch-{OFFERED_TORCH}-py3-none-any.whl", "w") as wheel:
        wheel.writestr(f"{info}/METADATA", f"Metadata-Version: 2.1\nName: torch\nVersion: {OFFERED_TORCH}\n")
        wheel.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nGenerator: sdm-tests\nRoot-Is-Purelib: true\n"
                                        "Tag: py3-none-any\n")
        wheel.writestr(f"{info}/RECORD", f"{info}/METADATA,,\n{info}/WHEEL,,\n{info}/RECORD,,\n")


def _project_copy(directory: Path, torch_requirement: str) -> Path:
    """What setuptools needs to build the project's metadata, with torch's requirement as given."""
    directory.mkdir()
    for name in ("README.md", "LICENSE"):
        shutil.copy(ROOT / name, directory / name)
    shutil.copytree(ROOT / "src", directory / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert pyproject.count(DECLARED_TORCH) == 1, f"pyproject.toml no longer declares {DECLARED_TORCH}"
    (directory / "pyproject.toml").write_text(pyproject.replace(DECLARED_TORCH, f'"{torch_requirement}"'))
    return directory


def _pip(python: Path, *args: str) -> subprocess.CompletedProcess:
    """pip in the venv, deaf to this machine's pip configuration (indexes, find-links, constraints)."""
    environment = {key: value for key, value in os.environ.items() if not key.startswith("PIP_")}
    environment["PIP_CONFIG_FILE"] = os.devnull
    return subprocess.run([str(python), "-m", "pip", *args], capture_output=True, text=True, timeout=300,
                          env=environment)


def _planned_installs(python: Path, project: Path, wheels: Path, report: Path) -> dict[str, str]:
    """pip's plan for installing ``project`` in the venv: distribution name -> version."""
    result = _pip(python, "install", "--dry-run", "--no-index", "--find-links", str(wheels), "--no-build-isolation",
                  "--report", str(report), str(project))
    assert result.returncode == 0, result.stdout + result.stderr
    return {item["metadata"]["name"]: item["metadata"]["version"] for item in json.loads(report.read_text())["install"]}


def _installed_torch(python: Path) -> list[str]:
    """The torch versions pip lists in the venv."""
    result = _pip(python, "list", "--format", "json")
    assert result.returncode == 0, result.stderr
    return [item["version"] for item in json.loads(result.stdout) if item["name"].lower() == "torch"]


@pytest.fixture(scope="module")
def researchers_environment(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(the venv's python, the folder offering torch 2.13.0, a scratch folder)."""
    base = tmp_path_factory.mktemp("packaging")
    python = _researchers_venv(base / "venv")
    _offered_torch_wheel(base / "wheels")
    return python, base / "wheels", base


def test_the_environment_sees_exactly_one_torch_the_researchers(researchers_environment):
    python, _, _ = researchers_environment
    assert _installed_torch(python) == [RESEARCHERS_TORCH]


def test_installing_the_library_keeps_the_researchers_torch(researchers_environment):
    python, wheels, scratch = researchers_environment
    project = _project_copy(scratch / "declared", "torch>=2.4")
    plan = _planned_installs(python, project, wheels, scratch / "declared.json")
    assert list(plan) == [PROJECT], plan  # torch is not in the plan: 2.5.1 satisfies torch>=2.4
    assert _installed_torch(python) == [RESEARCHERS_TORCH]


def test_negative_control_an_exact_torch_pin_would_replace_it(researchers_environment):
    """The check can fail: with ``torch==2.13.0`` declared, the same resolution plans a torch install."""
    python, wheels, scratch = researchers_environment
    project = _project_copy(scratch / "pinned", f"torch=={OFFERED_TORCH}")
    plan = _planned_installs(python, project, wheels, scratch / "pinned.json")
    assert plan.get("torch") == OFFERED_TORCH and PROJECT in plan, plan


#: Blocks pandas and matplotlib (any of their modules) in a fresh interpreter before anything is imported.
BLOCK_REPORT_STACK = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("pandas", "matplotlib"):
            raise ImportError(f"{name} is blocked: the layer must not need it")
sys.meta_path.insert(0, Block())
"""


def _run_blocked(code: str) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHONPATH": str(ROOT / "src")}
    return subprocess.run([sys.executable, "-c", BLOCK_REPORT_STACK + code], capture_output=True, text=True,
                          env=env, timeout=300)


def test_the_layer_imports_and_trains_without_pandas_or_matplotlib():
    """`import sdm` and the README's quick start run with pandas and matplotlib blocked: the layer's own
    dependencies (pyproject.toml) are torch, numpy and tqdm."""
    readme = (ROOT / "README.md").read_text()
    quick_start = re.search(r"## Use the layer: quick start\n\n```python\n(.*?)```", readme, re.S).group(1)
    done = _run_blocked("import sdm, sdm.train, sdm.mapping, sdm.sharing, sdm.depth\n" + quick_start)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "(0.5" in done.stdout  # the quick start prints the recovered shift


def test_the_block_catches_a_module_that_needs_pandas():
    """The negative control: the experiments' drivers need pandas, and the block stops them."""
    done = _run_blocked("import sdm.experiments")
    assert done.returncode != 0 and "pandas is blocked" in done.stderr


def test_the_declared_dependencies_are_the_layers():
    """pyproject.toml: the core needs torch, numpy and tqdm; pandas and matplotlib come with `experiments`."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = {re.split(r"[<>=!~ ]", requirement)[0] for requirement in project["dependencies"]}
    assert core == {"torch", "numpy", "tqdm"}
    extra = {re.split(r"[<>=!~ ]", requirement)[0] for requirement in project["optional-dependencies"]["experiments"]}
    assert {"pandas", "matplotlib"} <= extra


def test_the_benchmarks_folder_holds_source_only():
    """Snakemake's benchmark files and logs go under the results root: every tracked file of benchmarks/ is a
    script (or its README)."""
    listed = subprocess.run(["git", "ls-files", "benchmarks"], cwd=ROOT, capture_output=True, text=True, check=True)
    files = listed.stdout.split()
    assert len(files) >= 10
    assert [name for name in files if not name.endswith((".py", ".md"))] == []
    # each script in the folder that says what it is: a speed benchmark, a study (measurements that chose a
    # setting or explain a result), or a tool
    assert [name for name in files if name.endswith(".py")
            and name.split("/")[1] not in ("speed", "studies", "tools")] == []
