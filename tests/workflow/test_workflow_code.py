"""The workflow follows the code and can move: a library edit reruns exactly the stages that run the edited
file and what follows them; a copied project has nothing to do; parsing writes nothing.

The rerun checks are dry runs on a temporary copy of the project made "complete" without running a
stage: every output is created empty and ``snakemake --touch`` records the jobs' metadata (params,
inputs), which is all that Snakemake's rerun triggers compare. What each edit should rerun is derived
independently of workflow/scripts/code_deps.py (the rules' way): the files a notebook runs come from
the standard library's :mod:`modulefinder` (bytecode, not ``ast``), and what follows a stage from
Snakemake's own ``--forcerun``.
"""
from __future__ import annotations

import ast
import hashlib
import json
import modulefinder
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from test_workflow import (ROOT, STAGES, apollo_sample_config, dot_test_config, planned, snakemake,
                           snakemake_commands, workdir)

sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
import code_deps  # noqa: E402

pytestmark = pytest.mark.workflow

#: What a project copy needs to plan a run (no data: the .test config generates its annotations).
PROJECT_PARTS = ["Snakefile", "workflow", "notebooks", "src", "profiles"]


def copy_project(target: Path, config: dict) -> Path:
    target.mkdir(parents=True)
    for part in PROJECT_PARTS:
        source = ROOT / part
        if source.is_dir():
            shutil.copytree(source, target / part, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(source, target / part)
    (target / "config.yaml").write_text(yaml.safe_dump(config))
    return target


def in_project(project: Path, *args: str) -> subprocess.CompletedProcess:
    """Snakemake run in ``project`` with its own Snakefile (and, as there, its workflow profile)."""
    return snakemake_commands((project, args))[0]


def complete_without_running(project: Path) -> list[dict]:
    """Create every output and log of a planned run empty, then ``--touch``: the metadata of a finished run.

    Returns every job of the plan (workflow/scripts/dag_jobs.py), with its params.
    """
    out = project / ".jobs.jsonl"
    result = subprocess.run([sys.executable, str(ROOT / "workflow" / "scripts" / "dag_jobs.py"), "dump", str(out)],
                            cwd=project, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    jobs = [json.loads(line) for line in out.read_text().splitlines()]
    out.unlink()
    for job in jobs:
        for path in job["output"]["all"] + job["log"]["all"]:
            (project / path).parent.mkdir(parents=True, exist_ok=True)
            if "directory" in job["output"]["flags"].get(path, {}):
                (project / path).mkdir()
            else:
                (project / path).touch()
    result = in_project(project, "--touch", "--forceall", "-c1")  # every job: one whose outputs exist is skipped
    assert result.returncode == 0, result.stdout + result.stderr
    return jobs


def nothing_to_do(result: subprocess.CompletedProcess) -> bool:
    assert result.returncode == 0, result.stdout + result.stderr
    return "Nothing to be done" in result.stdout + result.stderr


@pytest.fixture(scope="module")
def touched_project(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """A project copy with the .test config, complete (touched); and each stage's notebook, as its jobs run it."""
    project = copy_project(tmp_path_factory.mktemp("code") / "project", dot_test_config())
    jobs = complete_without_running(project)
    assert nothing_to_do(in_project(project, "-n"))
    notebooks = {job["rule"]: ast.literal_eval(job["params"]["stage"])["notebook"] for job in jobs if job["rule"] != "all"}
    return project, notebooks


# -- the project can move ----------------------------------------------------------------------------------


def test_a_copied_project_has_nothing_to_do(touched_project, tmp_path):
    """`cp -a` of a finished project to another path: no job is planned (no input path names the old place)."""
    project, _ = touched_project
    moved = tmp_path / "elsewhere" / "deeper" / "project"
    moved.parent.mkdir(parents=True)
    subprocess.run(["cp", "-a", str(project), str(moved)], check=True)
    assert nothing_to_do(in_project(moved, "-n"))


# -- code is a rerun trigger ------------------------------------------------------------------------------


def _modulefinder_files(project: Path, notebook: str) -> set[str]:
    """The library files (relative to the project) that a notebook runs, by the standard library's modulefinder."""
    src = project / "src"
    finder = modulefinder.ModuleFinder(path=[str(src)])  # only the library is followed
    finder.run_script(str(project / notebook))
    files = {Path(module.__file__).relative_to(project).as_posix() for module in finder.modules.values()
             if module.__file__ and Path(module.__file__).is_relative_to(src)}
    for path in sorted(src.rglob("*")):  # a non-Python file counts for the modules that name it
        if path.is_file() and path.suffix not in {".py", ".pyc"}:
            readers = {f for f in files if path.name in (project / f).read_text()}
            if readers:
                files.add(path.relative_to(project).as_posix())
    return files


def _library_files() -> list[str]:
    return sorted(path.relative_to(ROOT).as_posix() for path in (ROOT / "src" / "sdm").rglob("*")
                  if path.is_file() and "__pycache__" not in path.parts)


@pytest.fixture(scope="module")
def expected_plans(touched_project):
    """For a library file: the jobs `--forcerun` of the stages whose notebook runs it plans (cached per set)."""
    project, notebooks = touched_project
    reached = {notebook: _modulefinder_files(project, notebook) for notebook in set(notebooks.values())}
    cache = {}

    def plan(library_file: str) -> dict[str, int]:
        stages = sorted(stage for stage, notebook in notebooks.items() if library_file in reached[notebook])
        if tuple(stages) not in cache:
            cache[tuple(stages)] = planned(in_project(project, "-n", "--quiet", "rules", "--forcerun", *stages)) \
                if stages else {}
        return cache[tuple(stages)]

    return plan


def _edited(path: Path, text: str):
    """A context: ``text`` appended to ``path``, the original content restored afterwards."""
    class Edit:
        def __enter__(self):
            self.original = path.read_bytes()
            path.write_bytes(self.original + text.encode())

        def __exit__(self, *exc):
            path.write_bytes(self.original)

    return Edit()


def _reaching_notebooks(project: Path) -> dict[str, tuple[str, ...]]:
    """Library file -> the stage notebooks that run it (modulefinder), for the project at ``project``."""
    notebooks = sorted(path.relative_to(project).as_posix() for path in (project / "notebooks").glob("*.py"))
    reached = {notebook: _modulefinder_files(project, notebook) for notebook in notebooks}
    return {file: tuple(n for n in notebooks if file in reached[n]) for file in _library_files()}


def _one_file_per_reach() -> list[str]:
    """A library file for each distinct set of notebooks that run it, and every non-Python file (hashed as bytes):
    the files whose edits Snakemake is asked to plan. Every file's own edit is checked against the stages'
    fingerprints by test_each_library_file_edit_changes_the_fingerprints_of_the_stages_that_run_it."""
    chosen = {}
    for file, notebooks in _reaching_notebooks(ROOT).items():
        chosen.setdefault(notebooks, file)
    return sorted(set(chosen.values()) | {f for f in _library_files() if not f.endswith(".py")})


def test_each_library_file_edit_changes_the_fingerprints_of_the_stages_that_run_it(tmp_path):
    """For every library file: a code edit changes the code fingerprint (code_deps, the stage param) of exactly the
    notebooks that run it by modulefinder's reckoning, and a comment leaves every fingerprint as it was. In one
    process, on a copy of the library, so that all files are checked in seconds (Snakemake itself plans from
    these fingerprints: test_a_library_edit_reruns_the_stages_that_run_it, one file per distinct set)."""
    import importlib.util

    for part in ("src", "notebooks", "workflow"):
        shutil.copytree(ROOT / part, tmp_path / part, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    shutil.copy2(ROOT / "Snakefile", tmp_path / "Snakefile")
    spec = importlib.util.spec_from_file_location("code_deps_copy", tmp_path / "workflow" / "scripts" / "code_deps.py")
    deps = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(deps)
    assert deps.ROOT == tmp_path
    notebooks = sorted(path.stem for path in (tmp_path / "notebooks").glob("*.py"))
    parse, parsed = deps._parsed.__wrapped__, {}

    def parse_by_content(path: Path):
        """code_deps' own parse, kept per file content: an edited file is parsed anew, the others once."""
        key = (path, path.read_bytes())
        if key not in parsed:
            parsed[key] = parse(path)
        return parsed[key]

    deps._parsed = parse_by_content

    def fingerprints() -> dict[str, str]:
        for cached in (deps.module_file, deps.imported, deps.reached, deps.file_digest, deps.fingerprint):
            cached.cache_clear()
        return {notebook: deps.fingerprint(notebook) for notebook in notebooks}

    before = fingerprints()
    reaching = _reaching_notebooks(tmp_path)
    for library_file, expected in reaching.items():
        code = "\n/* rerun probe */\n" if library_file.endswith(".c") else "\n_rerun_probe = 1\n"
        with _edited(tmp_path / library_file, code):
            changed = {notebook for notebook, value in fingerprints().items() if value != before[notebook]}
        assert changed == {Path(notebook).stem for notebook in expected}, library_file
        if library_file.endswith(".py"):
            with _edited(tmp_path / library_file, "\n# a comment\n"):
                assert fingerprints() == before, library_file


@pytest.mark.parametrize("library_file", _one_file_per_reach())
def test_a_library_edit_reruns_the_stages_that_run_it(touched_project, expected_plans, library_file):
    """A code edit of one library file plans exactly the jobs that `--forcerun` of the stages whose notebook
    runs it (modulefinder) plans: those stages and everything after them; nothing else. One file per distinct
    set of notebooks (the Snakemake side is the same for files of one set; every file's own fingerprint is
    checked above)."""
    project, _ = touched_project
    expected = expected_plans(library_file)
    probe = "\n/* rerun probe */\n" if library_file.endswith(".c") else "\n_rerun_probe = 1\n"
    with _edited(project / library_file, probe):
        jobs = planned(in_project(project, "-n", "--quiet", "rules"))
    assert jobs == expected, (library_file, jobs, expected)


def test_cmaes_and_flow_edits_rerun_what_docs_maintaining_md_says(touched_project, expected_plans):
    """The two edits docs/maintaining.md spells out: sdm/experiments/baselines/cmaes.py reruns Table 3's stages (every method's
    jobs: the notebook imports sdm.experiments.baselines, which imports every method), the floor (its search is CMA-ES's)
    and what reads them (Table 4, the report), Table 6's stages (their baselines per configuration search as
    CMA-ES does), Table 7's (sdm.experiments.network runs CMA-ES per configuration and the image losses), never Tables 1-2;
    sdm/mapping/flow.py reruns every stage (sdm/__init__.py imports the layer)."""
    project, _ = touched_project
    cmaes = expected_plans("src/sdm/experiments/baselines/cmaes.py")
    assert set(cmaes) == {"baseline_tune", "baseline_runs", "floor_runs", "table3", "table4", "objects_runs",
                          "objects_scaling", "table6", "network_train", "network_test", "network_bias", "table7",
                          "report"}, cmaes
    assert cmaes["baseline_tune"] == len(dot_test_config()["baselines"]["methods"])
    assert set(expected_plans("src/sdm/mapping/flow.py")) == set(STAGES)  # .test switches every stage on


@pytest.mark.parametrize("library_file, text", [
    ("src/sdm/train/engine.py", "\n# a comment only\n"),
    ("src/sdm/train/engine.py", "\n\n\n"),
    ("src/sdm/mapping/flow.py", None),  # a docstring edited
])
def test_comments_docstrings_and_layout_rerun_nothing(touched_project, library_file, text):
    """Only code counts (docs/maintaining.md): a comment, blank lines or a docstring edit plan no job."""
    project, _ = touched_project
    path = project / library_file
    original = path.read_text()
    if text is None:
        tree = ast.parse(original)
        docstring = ast.get_docstring(tree, clean=False)
        assert docstring
        path.write_text(original.replace(docstring, docstring + " Edited.", 1))
    else:
        path.write_text(original + text)
    try:
        assert nothing_to_do(in_project(project, "-n"))
    finally:
        path.write_text(original)


@pytest.mark.parametrize("stage", ["sample", "tables"])
def test_a_notebook_prose_edit_reruns_its_stage(touched_project, stage):
    """A notebook is tracked by its text (its prose is in the rendered page): a Markdown edit reruns it."""
    project, notebooks = touched_project
    with _edited(project / notebooks[stage], "\n# %% [markdown]\n# One more sentence.\n"):
        jobs = planned(in_project(project, "-n", "--quiet", "rules"))
    assert jobs == planned(in_project(project, "-n", "--quiet", "rules", "--forcerun", stage))
    assert stage in jobs


@pytest.mark.parametrize("script", ["workflow/scripts/run_notebook.py", "workflow/scripts/stage.py",
                                    "workflow/scripts/kernel.py", "workflow/scripts/code_deps.py"])
def test_a_runner_code_edit_reruns_every_stage(touched_project, script):
    project, _ = touched_project
    with _edited(project / script, "\n_rerun_probe = 1\n"):
        jobs = planned(in_project(project, "-n", "--quiet", "rules"))
    assert jobs == planned(in_project(project, "-n", "--quiet", "rules", "--forceall"))


def test_one_notebook_per_stage():
    """Each stage runs its own notebook, and every notebook in notebooks/ is one stage's: none serves several
    stages by a switch, and no analysis that no rule runs (nor writes what Snakemake does not know) sits there."""
    stages = code_deps.stage_notebooks()
    assert sorted(path.stem for path in (ROOT / "notebooks").glob("*.py")) == sorted(stages)
    assert sorted(stages) == sorted(STAGES)


def test_code_deps_agrees_with_modulefinder():
    """The rules' ast reading of the imports reaches the files modulefinder's bytecode scan finds, per notebook."""
    for notebook in sorted(set(code_deps.stage_notebooks().values())):
        ours = set(code_deps.reached(notebook))
        assert ours == _modulefinder_files(ROOT, f"notebooks/{notebook}.py"), notebook


def _fresh_code_deps(name: str):
    """workflow/scripts/code_deps.py loaded anew (its own caches empty), as a new Snakemake process has it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "workflow" / "scripts" / "code_deps.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_parse_cache_gives_what_a_parse_gives_and_a_damaged_one_is_parsed_anew(tmp_path, monkeypatch):
    """The fingerprints read back from the parse cache equal those of a parse (no file is parsed then); a cache
    that is garbage, cut short, of another parser or with entries of the wrong shape is ignored and written
    whole again; a cache folder that cannot be made changes nothing but the time."""
    monkeypatch.setenv("SDM_CACHE_DIR", str(tmp_path / "cache"))
    first = _fresh_code_deps("code_deps_cold")
    notebooks = sorted(first.stage_notebooks())
    expected = {notebook: first.fingerprint(notebook) for notebook in notebooks}
    assert expected == {notebook: code_deps.fingerprint(notebook) for notebook in notebooks}
    cache = tmp_path / "cache" / f"code_deps-py{sys.version_info[0]}.{sys.version_info[1]}.json"
    whole = cache.read_bytes()
    parsed = {f for n in notebooks for f in first.stage_files(n) if f.endswith(".py")}  # notebooks for imports
    assert sorted(json.loads(whole)["entries"]) == sorted({hashlib.sha256((ROOT / f).read_bytes()).hexdigest()
                                                           for f in parsed})  # one per content

    warm = _fresh_code_deps("code_deps_warm")
    monkeypatch.setattr(warm, "_parse", lambda *args: pytest.fail(f"parsed {args[0]} with a whole cache"))
    assert {notebook: warm.fingerprint(notebook) for notebook in notebooks} == expected

    entries = json.loads(whole)["entries"]
    key = sorted(entries)[0]
    damaged = {
        "garbage": b"\x00\xffnot json",
        "cut short": whole[: len(whole) // 2],
        "another parser": json.dumps({"parser": "0" * 64, "entries": entries}).encode(),
        "a wrong entry": json.dumps({"parser": json.loads(whole)["parser"],
                                     "entries": entries | {key: [[["sdm", "x", 0, 1]], entries[key][1]]}}).encode(),
        "not a mapping": b"[1, 2]",
    }
    for case, content in damaged.items():
        cache.write_bytes(content)
        again = _fresh_code_deps(f"code_deps_{case.replace(' ', '_')}")
        assert {notebook: again.fingerprint(notebook) for notebook in notebooks} == expected, case
        assert json.loads(cache.read_bytes())["entries"] == entries, case  # written whole again

    (tmp_path / "a file").write_text("")
    monkeypatch.setenv("SDM_CACHE_DIR", str(tmp_path / "a file" / "cache"))  # no folder can be made there
    unwritable = _fresh_code_deps("code_deps_unwritable")
    assert {notebook: unwritable.fingerprint(notebook) for notebook in notebooks} == expected


def test_every_non_python_library_file_is_a_declared_resource():
    """A file a module reads beside itself changes results too: it must be in code_deps.RESOURCES."""
    declared = {resource for resources in code_deps.RESOURCES.values() for resource in resources}
    assert {f for f in _library_files() if not f.endswith(".py")} == declared


def test_no_library_code_reads_a_docstring():
    """Docstring edits rerun nothing, which is right only while no library code reads one."""
    offenders = [path for path in _library_files() if path.endswith(".py") and
                 any(word in (ROOT / path).read_text() for word in ("__doc__", "getdoc("))]
    assert not offenders


def test_the_module_table_of_docs_maintaining_md_is_current():
    """docs/maintaining.md's module-to-stages table is what `python workflow/scripts/code_deps.py table` prints."""
    docs = (ROOT / "docs" / "maintaining.md").read_text()
    table = code_deps.module_table()
    assert table in docs, "regenerate it: python workflow/scripts/code_deps.py table"


# -- parsing writes nothing ------------------------------------------------------------------------------


def _tree_state(folder: Path) -> dict[str, tuple[int, int]]:
    return {path.relative_to(folder).as_posix(): (path.stat().st_mtime_ns, path.stat().st_size)
            for path in sorted(folder.rglob("*"))}


def _read_only_run(directory: Path, folder: Path, *args: str) -> subprocess.CompletedProcess:
    """Snakemake in ``directory`` with ``folder`` read-only: a read-only bind mount where this process may make
    one (root in a mount namespace of its own; root passes any chmod), else ``chmod -R a-w``."""
    command = [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile"), *args]
    if os.geteuid() == 0 and shutil.which("unshare") and \
            subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode == 0:
        script = 'mount --bind "$1" "$1" && mount -o remount,bind,ro "$1" && shift && exec "$@"'
        command = ["unshare", "-m", "sh", "-c", script, "sh", str(folder), *command]
        return subprocess.run(command, cwd=directory, capture_output=True, text=True, timeout=600)
    subprocess.run(["chmod", "-R", "a-w", str(folder)], check=True)
    try:
        return subprocess.run(command, cwd=directory, capture_output=True, text=True, timeout=600)
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(folder)], check=True)


@pytest.mark.parametrize("args, message", [
    (("-n", "--quiet", "rules"), "This was a dry-run"),
    (("--lint",), "Congratulations, your workflow is in a good condition"),
])
def test_dry_run_and_lint_work_with_a_read_only_results_folder(tmp_path, args, message):
    """With the ApolloCar3D source (the one whose files are listed at parse time) nothing is written under
    the results folder: a dry run and --lint work when it is read-only, and leave it as it was."""
    config = apollo_sample_config()
    directory = workdir(tmp_path / "run", config)
    results = directory / "results"
    (directory / config["results_dir"]).mkdir(parents=True)
    before = _tree_state(results)
    result = _read_only_run(directory, results, *args)
    output = result.stdout + result.stderr
    assert result.returncode == 0 and message in output and "Traceback" not in output, output[-3000:]
    assert _tree_state(results) == before
