"""The Snakemake workflow: lint, format, dry runs, config errors that name the key, and end-to-end runs.

Every test runs Snakemake in a temporary directory of its own (``--directory``), with the
project's Snakefile, so nothing depends on what a previous run left in ``results/`` of the
working tree.

The end-to-end run of the tiny ``.test`` config is a session fixture (about a minute on
two cores); the tests that need a completed run share it.
"""
from __future__ import annotations

import ast
import atexit
import copy
import json
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
from config_check import ConfigError, check_config, load_config, validate_schema  # noqa: E402

SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"
APOLLO_SAMPLE = ROOT / "data" / "apollocar3d-sample"
STAGES = ["synthetic", "data", "sample", "sky", "split", "tune", "best", "noise", "tables", "baseline_tune",
          "baseline_runs", "floor_runs", "table3", "rule_runs", "rule_bias", "depth_runs", "objects_runs",
          "objects_scaling", "network_train", "network_test", "network_bias", "table4", "table5", "table6", "table7", "figures",
          "report"]

pytestmark = pytest.mark.workflow


def snakemake(*args: str, cwd: Path = ROOT, timeout: int = 900) -> subprocess.CompletedProcess:
    """Snakemake with the project's Snakefile, in ``cwd``, under the common umask 022."""
    return snakemakes((cwd, args), timeout=timeout)[0]


def snakemakes(*runs: tuple[Path, tuple[str, ...]], timeout: int = 900) -> list[subprocess.CompletedProcess]:
    """Snakemake runs, each ``(cwd, args)`` as in :func:`snakemake`, started together: independent chains of
    stages use both cores. See :func:`snakemake_commands`."""
    return snakemake_commands(*((cwd, ("--snakefile", str(ROOT / "Snakefile"), *args)) for cwd, args in runs),
                              timeout=timeout)


class _Server:
    """tests/snakemake_server.py, started on first use: each run is ``python -m snakemake`` less its import."""

    process: subprocess.Popen | None = None
    pending = b""  # read, not yet a whole line
    ended: dict[int, int] = {}  # pid -> returncode, until its run's caller takes it

    @classmethod
    def write(cls, request: dict) -> None:
        cls.process.stdin.write((json.dumps(request) + "\n").encode())
        cls.process.stdin.flush()

    @classmethod
    def send(cls, request: dict) -> int:
        if cls.process is None or cls.process.poll() is not None:
            cls.process = subprocess.Popen([sys.executable, str(ROOT / "tests" / "snakemake_server.py")],
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            cls.pending = b""
            atexit.register(cls.stop, cls.process)
        cls.write(request)
        while "started" not in (message := cls.receive(None)):  # an earlier run's end may come first
            pass
        return message["started"]

    @staticmethod
    def stop(process: subprocess.Popen) -> None:
        """End of stdin: the server kills what still runs and exits (waited for: its CPU time is counted)."""
        process.stdin.close()
        process.wait(timeout=60)

    @classmethod
    def receive(cls, deadline: float | None) -> dict:
        """The server's next message; TimeoutError past ``deadline`` (time.monotonic())."""
        fd = cls.process.stdout.fileno()
        while b"\n" not in cls.pending:
            wait = None if deadline is None else max(deadline - time.monotonic(), 0)
            if not select.select([fd], [], [], wait)[0]:
                raise TimeoutError
            chunk = os.read(fd, 65536)
            if not chunk:
                raise RuntimeError(f"tests/snakemake_server.py exited with {cls.process.wait()}")
            cls.pending += chunk
        line, cls.pending = cls.pending.split(b"\n", 1)
        message = json.loads(line)
        if "pid" in message:
            cls.ended[message["pid"]] = message["returncode"]
        return message


def snakemake_commands(*runs: tuple[Path, tuple[str, ...]], timeout: int = 900) -> list[subprocess.CompletedProcess]:
    """``python -m snakemake ARGS`` for each ``(cwd, args)``, in ``cwd`` under the common umask 022, all started
    together. Each run's stdout and stderr go to files (no pipe to fill); past ``timeout`` seconds every run is
    killed and TimeoutExpired raised, as subprocess.run does. The runs are forked by tests/snakemake_server.py
    from a process that has imported Snakemake once (a dry run is mostly that import)."""
    with tempfile.TemporaryDirectory() as folder:
        started = []
        try:
            for i, (cwd, args) in enumerate(runs):
                output = (f"{folder}/{i}.out", f"{folder}/{i}.err")
                pid = _Server.send({"cwd": str(cwd), "args": list(args), "env": dict(os.environ),
                                    "stdout": output[0], "stderr": output[1]})
                started.append(([sys.executable, "-m", "snakemake", *args], pid, output))
            deadline = time.monotonic() + timeout
            while any(pid not in _Server.ended for _, pid, _ in started):
                try:
                    _Server.receive(deadline)
                except TimeoutError:
                    raise subprocess.TimeoutExpired(started[0][0], timeout) from None
            return [subprocess.CompletedProcess(command, _Server.ended[pid], Path(output[0]).read_text(),
                                                Path(output[1]).read_text()) for command, pid, output in started]
        finally:
            for _, pid, _ in started:
                if pid not in _Server.ended:
                    _Server.write({"kill": pid})
            for _, pid, _ in started:
                while pid not in _Server.ended:
                    _Server.receive(time.monotonic() + 60)
                _Server.ended.pop(pid)


def default_config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text())


def dot_test_config() -> dict:
    return yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())


def workdir(path: Path, config: dict) -> Path:
    """A working directory holding ``config.yaml``: where Snakemake runs and writes."""
    path.mkdir(parents=True, exist_ok=True)
    (path / "config.yaml").write_text(yaml.safe_dump(config))
    return path


def planned(result: subprocess.CompletedProcess) -> dict[str, int]:
    """Jobs of a dry run (``-n --quiet rules``): rule -> count."""
    assert result.returncode == 0, result.stdout + result.stderr
    jobs = {}
    for line in (result.stdout + result.stderr).splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] in STAGES and parts[1].isdigit():
            jobs[parts[0]] = int(parts[1])
    return jobs


# -- static checks -----------------------------------------------------------------------------------------


def test_lint_is_clean():
    result = snakemake("--lint", cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Congratulations, your workflow is in a good condition" in result.stdout + result.stderr


def test_rule_files_are_snakefmt_formatted():
    files = [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]
    result = subprocess.run([sys.executable, "-m", "snakefmt", "--check", *map(str, files)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("call, message", [
    ('notebook_stage("extra", "A stage.", jobs=[{"level": 0}], output=dict(table=result("extra.csv")))',
     "stage extra: job {'level': 0} must name the wildcards []"),
    ('notebook_stage("extra", "A stage.", output=dict(html=result("extra.html")))',
     "stage extra: the output 'html' (the notebook's rendering) and the param 'stage'"),
])
def test_a_misdeclared_stage_is_refused_when_the_workflow_is_parsed(tmp_path, call, message):
    """notebook_stage checks each job's wildcards against its files' and keeps `html`/`stage` its own."""
    shutil.copytree(ROOT / "workflow", tmp_path / "workflow")
    shutil.copy(ROOT / "Snakefile", tmp_path)
    shutil.copy(ROOT / "config.yaml", tmp_path)
    with (tmp_path / "workflow" / "rules" / "report.smk").open("a") as rules_file:
        rules_file.write(f"\n{call}\n")
    result = snakemake_commands((tmp_path, ("-n", "--quiet", "rules")), timeout=300)[0]
    assert result.returncode != 0
    assert message in result.stdout + result.stderr


def test_dag_jobs_finds_a_changed_param_and_nothing_else(tmp_path):
    """workflow/scripts/dag_jobs.py (the same-DAG check for refactoring the rule files) dumps every job and
    tells an identical plan from one where a single config value reaches the jobs that read it."""
    tool = [sys.executable, str(ROOT / "workflow" / "scripts" / "dag_jobs.py")]
    config = default_config()
    for name, seed in (("before", 0), ("again", 0), ("changed", 1)):
        config["split"]["seed"] = seed
        workdir(tmp_path, config)
        dumped = subprocess.run([*tool, "dump", f"{name}.jsonl", "--snakefile", str(ROOT / "Snakefile")],
                                cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert dumped.returncode == 0, dumped.stdout + dumped.stderr
    # the DAG's longest chain, printed by the dump: the data stages, tuning, Table 2 and the tables after it
    chain = next(line for line in dumped.stdout.splitlines() if line.startswith("longest chain: "))
    assert chain.startswith("longest chain: 11 jobs: synthetic -> data -> sample -> sky -> split -> tune_"), chain
    assert chain.endswith(" -> best -> noise_level0_chunk0 -> tables -> table3 -> report"), chain
    jobs = (tmp_path / "before.jsonl").read_text().splitlines()
    assert len(jobs) == sum(planned(snakemake("-n", "--quiet", "rules", cwd=tmp_path)).values()) + 1  # + all
    # the longest jobs, and the tuning that gates them, are started first of the ready ones
    first = {json.loads(line)["rule"] for line in jobs if json.loads(line)["priority"] > 0}
    assert first == {"baseline_tune", "baseline_runs", "floor_runs"}, first
    same = subprocess.run([*tool, "compare", "before.jsonl", "again.jsonl"], cwd=tmp_path, capture_output=True,
                          text=True)
    assert same.returncode == 0 and same.stdout.strip() == f"SAME {len(jobs)} jobs"
    changed = subprocess.run([*tool, "compare", "before.jsonl", "changed.jsonl"], cwd=tmp_path,
                             capture_output=True, text=True)
    assert changed.returncode == 1 and changed.stdout.splitlines()[-1] == "DIFFERENT"
    differing = {line.split()[0] for line in changed.stdout.splitlines() if line and not line.startswith(" ")}
    assert differing == {"split", "DIFFERENT"}, changed.stdout


def test_parameter_cells_are_short(tmp_path):
    """No stage gets a long list as a param: papermill's injected cell shows a list one value a line (black's
    layout), so run indices go as a count (and a first index), never as the list of 20-60 indices."""
    config = default_config()
    config["research"]["depth"]["enabled"] = True  # every stage planned
    workdir(tmp_path, config)
    dumped = subprocess.run([sys.executable, str(ROOT / "workflow" / "scripts" / "dag_jobs.py"), "dump", "jobs.jsonl",
                             "--snakefile", str(ROOT / "Snakefile")], cwd=tmp_path, capture_output=True, text=True,
                            timeout=300)
    assert dumped.returncode == 0, dumped.stdout + dumped.stderr
    long_lists = set()
    for line in (tmp_path / "jobs.jsonl").read_text().splitlines():
        job = json.loads(line)
        for name, value in job["params"].items():
            if name != "stage" and value.startswith("[") and len(ast.literal_eval(value)) > 10:
                long_lists.add((job["rule"], name))
    assert not long_lists, sorted(long_lists)


def test_dry_run_works_with_torch_and_sdm_unimportable(tmp_path):
    """A login node without torch can plan a run: the Snakefile and rules import neither torch nor sdm."""
    probe = ("import sys\n"
             "sys.modules['torch'] = None; sys.modules['sdm'] = None  # any import of them raises ImportError\n"
             "sys.argv = ['snakemake', '--snakefile', sys.argv[1], '-n', '--quiet', 'rules']\n"
             "from snakemake.cli import main\n"
             "main()\n")
    workdir(tmp_path, default_config())
    result = subprocess.run([sys.executable, "-c", probe, str(ROOT / "Snakefile")], cwd=tmp_path,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "report" in result.stdout + result.stderr


def test_dry_run_default_config_plans_every_stage(tmp_path):
    config = default_config()
    jobs = planned(snakemake("-n", "--quiet", "rules", cwd=workdir(tmp_path, config)))
    cells = len(config["tuning"]["n_epoch"]) * len(config["tuning"]["lr"])
    chunks = len(config["noise"]["levels"]) * -(-config["noise"]["runs"] // config["noise"]["chunk_size"])
    methods = config["baselines"]["methods"]
    assert jobs == {"synthetic": 1, "data": 1, "sample": 1, "sky": 1, "split": 1, "tune": cells, "best": 1,
                    "noise": chunks, "tables": 1, "figures": 1, "report": 1,
                    "baseline_tune": len(methods), "baseline_runs": len(methods),
                    "table3": 1, "floor_runs": 1, **_research_jobs(config)}


def _research_jobs(config: dict) -> dict[str, int]:
    """The research stages' job counts (Tables 4, 5 and 6): per rule (every noise level), per (c*, level), then a table."""
    rules, depth = config["research"]["rules"], config["research"]["depth"]
    jobs = {}
    if rules["enabled"]:
        jobs |= {"rule_runs": len(rules["names"]), "rule_bias": 1, "table4": 1}
    if depth["enabled"]:
        jobs |= {"depth_runs": len(depth["shifts_c"]) * len(depth["noise_levels"]), "table5": 1}
    objects = config["research"].get("objects", {})
    if objects.get("enabled"):
        screens = objects.get("screens") or [{"scale": 1}]
        jobs |= {"objects_runs": sum(len(screen.get("sharings", objects["sharings"]))
                                     * len(screen.get("noise_levels", objects["noise_levels"])) for screen in screens),
                 "objects_scaling": len(objects["scaling"]["cars"]), "table6": 1}
    network = config["research"].get("network", {})
    if network.get("enabled"):
        jobs |= {"network_train": len(network["losses"]) * network["runs"], "network_test": len(network["noise_levels"]),
                 "table7": 1, "network_bias": int(any(loss in ("sdm_paper", "sdm_closed_centred_r1", "silhouette")  # BIAS_LOSSES
                                                      for loss in network["losses"]))}
    return jobs


def test_a_figure_waits_only_for_its_own_inputs(tmp_path):
    """Figures 1-4 need one configuration of the split: asking for Figure 2 plans the data stages and the
    figures, no tuning, noise run, baseline or research job (theta's path and Table 2's distances are drawn
    by the stages that make their data)."""
    jobs = planned(snakemake("results/figures/fig2_forward.png", "-n", "--quiet", "rules",
                             cwd=workdir(tmp_path, default_config())))
    assert jobs == {"synthetic": 1, "data": 1, "sample": 1, "sky": 1, "split": 1, "figures": 1}
    jobs = planned(snakemake("results/figures/theta_path.png", "-n", "--quiet", "rules", cwd=tmp_path))
    assert set(jobs) == {"synthetic", "data", "sample", "sky", "split", "tune", "best"}


def test_dry_run_with_the_depth_table_switched_on_by_an_overlay(tmp_path):
    """docs/workflow.md's way to switch Table 5 on for one run: an overlay file merged key by key."""
    config = default_config()
    overlay = tmp_path / "depth-on.yaml"
    overlay.write_text("research:\n  depth:\n    enabled: true\n")
    jobs = planned(snakemake("-n", "--quiet", "rules", "--configfile", str(overlay), cwd=workdir(tmp_path / "run", config)))
    config["research"]["depth"]["enabled"] = True
    assert {key: jobs.get(key) for key in ("rule_runs", "rule_bias", "depth_runs", "table4", "table5")} == (
        _research_jobs(config))


@pytest.mark.parametrize("name", ["default", "depth", "objects", "network", "sample"])
def test_each_snapshots_stages_are_those_that_make_its_files(tmp_path, name):
    """A snapshot's provenance records the code of every stage its files come from (PARTS in
    workflow/scripts/provenance.py): from scratch, a dry run of its files with the config `make run-<name>` uses
    plans exactly those stages."""
    from provenance import PARTS

    part = PARTS[name]
    if name == "sample":
        directory, overlay = workdir(tmp_path, apollo_sample_config()), []
    else:
        directory = workdir(tmp_path, default_config())
        overlay = [argument for path in part.config[1:] for argument in ("--configfile", str(ROOT / path))]
    results = yaml.safe_load((ROOT / part.config[-1]).read_text()).get("results_dir", "results")
    targets = sorted({f"{results}/{source}" for source in part.files.values()})
    jobs = planned(snakemake("-n", "--quiet", "rules", *overlay, "--", *targets, cwd=directory))
    assert set(jobs) == set(part.stages)
    assert part.results == results


@pytest.mark.parametrize("flag", ["--workflow-profile", "--profile"])
def test_dry_run_slurm_profile(tmp_path, flag):
    result = snakemake("-n", flag, str(ROOT / "profiles" / "slurm"), cwd=workdir(tmp_path, default_config()))
    assert result.returncode == 0, result.stdout + result.stderr


def apollo_sample_config() -> dict:
    """The default config with the shipped real-data config over it, its folder made absolute."""
    config = _merge(default_config(), yaml.safe_load((APOLLO_SAMPLE / "config.yaml").read_text()))
    config["data"]["apollo_folder"] = str(ROOT / config["data"]["apollo_folder"])
    return config


def test_apollo_sample_config_plans_every_stage_under_its_own_results_root(tmp_path):
    """The shipped real-data config: data stage first (no synthetic), every output under its results root."""
    directory = workdir(tmp_path, apollo_sample_config())
    jobs = planned(snakemake("-n", "--quiet", "rules", cwd=directory))
    assert "synthetic" not in jobs and jobs["data"] == 1 and jobs["report"] == 1 and jobs["noise"] == 10
    listing = snakemake("-n", "--summary", cwd=directory)
    outputs = [line.split("\t")[0] for line in listing.stdout.splitlines() if "\t" in line][1:]
    assert len(outputs) > 50
    assert all(path.startswith("results/apollocar3d-sample/") for path in outputs), outputs


@pytest.mark.parametrize(
    "change, key",
    [
        ({"train": {"s": 9}}, "train.s"),
        ({"noise": {"levels": [0, -1]}}, "noise.levels"),
        ({"data": {"source": "kitti"}}, "data.source"),
        ({"split": {"n_train": 500}}, "split.n_selected"),
        ({"sky": {"n_images": 6000}}, "sky.n_images"),
        ({"noise": {"runs": 0}}, "noise.runs"),
        ({"figures": {"example": 600}}, "figures.example"),
        ({"results_dir": "/etc"}, "results_dir"),
    ],
)
def test_bad_config_fails_before_any_job_naming_the_key(tmp_path, change, key):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(change))
    result = snakemake("-n", "--configfile", str(bad), cwd=workdir(tmp_path / "run", default_config()))
    assert result.returncode != 0
    output = result.stdout + result.stderr
    # config_check names the key's path: 'train.s', or 'noise.levels[1]' for an entry of a list.
    assert re.search(rf"'{re.escape(key)}(\[\d+\])?'", output), output
    assert not (tmp_path / "run" / "results").exists()


def test_empty_configuration_is_refused_naming_it(tmp_path):
    (tmp_path / "config.yaml").write_text("# nothing\n")
    result = snakemake("-n", cwd=tmp_path)
    assert result.returncode != 0
    assert "config" in (result.stdout + result.stderr).lower()


def test_apollo_folder_with_fewer_images_than_sky_n_images_is_refused_at_parse_time(tmp_path):
    config = dot_test_config()
    config["data"] = {"source": "apollo", "apollo_folder": str(APOLLO_SAMPLE),
                      "synthetic": config["data"]["synthetic"]}
    result = snakemake("-n", cwd=workdir(tmp_path, config))
    assert result.returncode != 0
    output = result.stdout + result.stderr
    assert "config key 'sky.n_images'" in output and "57 annotated images" in output, output
    assert "Traceback" not in output and "config_check.py" not in output


# -- the config checks, without Snakemake ----------------------------------------------------------------


def write(tmp_path: Path, config: dict) -> Path:
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_default_config_loads():
    config = load_config(ROOT / "config.yaml", SCHEMA)
    assert config["sky"]["n_images"] == 4248 and config["results_dir"] == "results"
    assert config["split"] == {"n_selected": 768, "n_train": 512, "n_dev": 256, "seed": 0}
    assert config["noise"]["runs"] == 60 and config["noise"]["levels"] == [0, 1, 2, 3, 4]
    load_config(ROOT / ".test" / "config.yaml", SCHEMA)
    real = apollo_sample_config()  # an override of config.yaml, as --configfile uses it
    validate_schema(real)
    check_config(real)
    assert real["results_dir"] == "results/apollocar3d-sample"


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("train", "s", 0, "config key 'train.s'"),
        ("train", "s", "4", "config key 'train.s'"),
        ("train", "batch_size", 0, "config key 'train.batch_size'"),
        ("tuning", "lr", [0.0], "config key 'tuning.lr[0]'"),
        ("noise", "chunk_size", 0, "config key 'noise.chunk_size'"),
        ("sky", "shift", [0.5], "config key 'sky.shift'"),
        ("split", "n_dev", 300, "config key 'split.n_selected'"),
        ("figures", "example", 512, "config key 'figures.example'"),
    ],
)
def test_schema_and_cross_checks_name_the_key(tmp_path, section, key, value, message):
    config = default_config()
    config[section][key] = value
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(write(tmp_path, config), SCHEMA)


def test_unknown_key_is_rejected(tmp_path):
    config = default_config()
    config["train"]["epochs"] = 3
    with pytest.raises(ConfigError, match="config key 'train'.*epochs"):
        load_config(write(tmp_path, config), SCHEMA)


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("noise", "chunk_size", 61, "noise.chunk_size"),
        ("split", "n_selected", 5000, "split.n_selected"),
        ("sky", "shift", [0.5, float("inf")], "sky.shift[1]"),
    ],
)
def test_cross_key_rules(section, key, value, message):
    config = default_config()
    config[section][key] = value
    if key == "n_selected":
        config["split"]["n_train"] = 4000
        config["split"]["n_dev"] = 1000
    with pytest.raises(ConfigError, match=re.escape(f"config key '{message}'")):
        check_config(config)


def test_real_sources_need_their_path():
    config = default_config()
    config["data"] = {"source": "pku", "synthetic": config["data"]["synthetic"]}
    with pytest.raises(ConfigError, match="config key 'data.pku_csv'"):
        check_config(config)


def test_empty_config_is_refused():
    with pytest.raises(ConfigError, match="empty"):
        check_config({})


# -- a completed .test run --------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def completed_run(tmp_path_factory) -> Path:
    """The ``.test`` config run end to end in a temporary directory."""
    directory = workdir(tmp_path_factory.mktemp("test_run"), dot_test_config())
    result = snakemake("-c2", cwd=directory)
    assert result.returncode == 0, (result.stdout + result.stderr)[-5000:]
    return directory


def test_completed_run_has_every_output_and_nothing_left_to_do(completed_run):
    for path in ["results/tables/table1.csv", "results/tables/table1.md", "results/tables/table1.tex",
                 "results/tables/table2.csv", "results/tables/table2.md", "results/tables/table2.tex",
                 "results/noise/distances.csv", "results/report/reproduction.md", "results/report/verdict.json",
                 "results/notebooks/report.html",
                 *(f"results/figures/{name}.png" for name in ["fig1_configuration", "fig2_forward", "fig3_backward",
                                                              "fig4_noise", "theta_path", "distances"])]:
        assert (completed_run / path).stat().st_size > 0, path
    result = snakemake("-n", cwd=completed_run)
    assert "Nothing to be done" in result.stdout + result.stderr, result.stdout + result.stderr


def test_each_executed_notebook_records_its_stage_and_code(completed_run):
    """The runner keeps each stage's name and code fingerprint in its executed notebook: what a snapshot's provenance
    records (workflow/scripts/snapshot.py); the verdict's facts of the run read as the README's verdict."""
    from code_deps import fingerprint
    from snapshot import run_stages
    from verdict_text import render, verdict

    ran = run_stages(completed_run / "results")
    assert {"tables", "noise", "table4", "report"} <= set(ran)
    assert {stage: codes for stage, codes in ran.items() if codes != {fingerprint(stage)}} == {}
    facts = json.loads((completed_run / "results" / "report" / "verdict.json").read_text())
    text = render(verdict({"default": {"facts": facts, "folder": "docs/results/", "commit": "0000000", "stale": False}}))
    assert "in mm" in text and len(facts["levels"]) == len(dot_test_config()["noise"]["levels"])


def test_completed_run_outputs_speak_of_the_method_alone(completed_run):
    """Tables, summaries, the report, the verdict and the rendered notebooks: no issue, stop or session
    numbers and no document outside the repository (tests/wording.py; the tracked files: test_wording.py)."""
    from wording import offences

    outputs = [path for path in (completed_run / "results").rglob("*") if path.is_file()]
    assert any(path.name == "table4_summary.md" for path in outputs)
    assert offences(outputs, completed_run) == []


def test_completed_run_has_the_research_tables_and_the_report_section(completed_run):
    """.test switches both research parts on: Tables 4 and 5, their figures, and "Beyond the paper" in the report."""
    tables = completed_run / "results" / "tables"
    for name in ["table4", "table5"]:
        for suffix in [".csv", ".md", ".tex"]:
            assert (tables / f"{name}{suffix}").stat().st_size > 0, (name, suffix)
        assert (tables / f"{name}_summary.md").stat().st_size > 0, name
    config = dot_test_config()["research"]
    table4 = pd_read_csv(tables / "table4.csv")
    levels = dot_test_config()["noise"]["levels"]
    # the rules, then Table 3's CMA-ES and the floor beside them, each compared with CMA-ES
    rows = [*config["rules"]["names"], "CMA-ES (Table 3)", "floor (exact-mismatch minimiser)"]
    assert sorted(set(zip(table4["rule"], table4["noise_level"]))) == sorted((name, level) for name in rows for level in levels)
    rules = table4[table4["rule"].isin(config["rules"]["names"])]
    assert (rules["runs"] == config["rules"]["runs"]).all() and (rules["paper_rule_runs"] == rules["runs"]).all()
    assert (table4["cmaes_runs"] == dot_test_config()["baselines"]["runs"]).all()
    table5 = pd_read_csv(tables / "table5.csv")
    assert sorted(set(zip(table5["c_true"], table5["noise_level"]))) == sorted(
        (c, level) for c in config["depth"]["shifts_c"] for level in config["depth"]["noise_levels"])
    report = (completed_run / "results" / "report" / "reproduction.md").read_text()
    section = report[report.index("## Beyond the paper"):]
    assert "(Table 4)" in section and "(Table 5)" in section
    assert (tables / "table4_summary.md").read_text().strip() in section
    for name in ["table4", "table5"]:
        assert _rendered_images(completed_run / "results" / "notebooks" / f"{name}.html") >= 1, name
    for figure in ["research_rules", "research_depth"]:
        assert (completed_run / "results" / "figures" / f"{figure}.png").stat().st_size > 0, figure


def test_every_rendered_page_is_titled_by_its_job(completed_run):
    """Each stage's page in results/notebooks/ carries its job's name as its title."""
    pages = sorted((completed_run / "results" / "notebooks").glob("*.html"))
    assert len(pages) > 10
    for page in pages:
        assert f"<title>{page.stem}</title>" in page.read_text(), page.name


def test_every_page_shows_its_jobs_values_and_no_log_holds_a_traceback(completed_run):
    """Each page's parameters cell shows the values its job ran with (papermill's injected cell left out of the page,
    kept in the executed notebook), and no job of the completed run left a traceback in its log."""
    pages = sorted((completed_run / "results" / "notebooks").glob("*.html"))
    for page in pages:
        text = page.read_text()
        assert "celltag_parameters" in text and "celltag_injected-parameters" not in text, page.name
        executed = page.with_suffix(".ipynb")
        assert "injected-parameters" in executed.read_text(), executed.name
    logs = sorted((completed_run / "results" / "logs").glob("*.log"))
    assert {log.stem for log in logs} >= {page.stem for page in pages}
    assert [log.name for log in logs if "Traceback" in log.read_text()] == []


def pd_read_csv(path: Path):
    import pandas as pd

    return pd.read_csv(path)


def report_results(html: Path) -> dict[str, bytes]:
    """The results a ``snakemake --report`` page embeds (its ``var results = {...}`` object): path -> content."""
    import base64

    text = html.read_text()
    start = text.index("var results = {") + len("var results = ")  # not the page's script code's own `results`
    results, _ = json.JSONDecoder().raw_decode(text[start:])
    return {path: base64.b64decode(entry["data_uri"].split(";base64,", 1)[1]) for path, entry in results.items()}


def test_snakemake_report_collects_the_results(completed_run, tmp_path):
    """`make report`'s page embeds every figure and table the run flags for it, each as the file itself: the
    page a browser shows has nothing to fetch (what a browser draws of it: the README, "Install and platform")."""
    result = snakemake("--report", str(tmp_path / "report.html"), cwd=completed_run)
    assert result.returncode == 0, result.stdout + result.stderr
    embedded = report_results(tmp_path / "report.html")
    run = completed_run / "results"
    expected = {f"results/{path.relative_to(run).as_posix()}" for path in [*(run / "figures").glob("*.png"),
                                                                            *(run / "tables").glob("table?.html")]}
    expected.add("results/report/reproduction.html")
    assert len(expected) == 12 + 7 + 1 and expected <= set(embedded), sorted(expected - set(embedded))  # Tables 1-7
    # the report shows images and HTML pages in place, and offers anything else (a CSV) as a download only
    assert {path.rsplit(".", 1)[1] for path in embedded} <= {"png", "html"}, sorted(embedded)
    for path in expected:
        assert embedded[path] == (completed_run / path).read_bytes(), path
    assert all(embedded[path].startswith(b"\x89PNG\r\n\x1a\n") for path in expected if path.endswith(".png"))
    assert all(b"<table>" in embedded[path] for path in expected if path.endswith(".html"))


def test_every_output_is_readable_by_others(completed_run):
    """Files honour the usual umask (022 in the test run): readable by group and others."""
    for path in (completed_run / "results").rglob("*"):
        if path.is_file():
            assert path.stat().st_mode & 0o044 == 0o044, (path, oct(path.stat().st_mode))


def _rendered_images(html: Path) -> int:
    return len(re.findall(r'<img[^>]+src="data:image/png', html.read_text()))


@pytest.mark.parametrize("stage, page", [("data", "data"), ("sky", "sky"), ("tune", "tune_*"), ("best", "best"),
                                         ("tables", "tables"), ("figures", "figures"), ("table3", "table3"),
                                         ("table4", "table4"), ("table5", "table5")])
def test_notebooks_that_plot_show_their_plots(completed_run, stage, page):
    """The stages that draw show each plot inline in their rendered HTML."""
    pages = sorted((completed_run / "results" / "notebooks").glob(f"{page}.html"))
    assert pages
    source = (ROOT / "notebooks" / f"{stage}.py").read_text()
    expected = source.count("plt.show()") + source.count("show(figures.") + source.count("show_figure(")
    assert expected > 0
    for page in pages:
        assert _rendered_images(page) >= expected, page
        assert "TqdmWarning" not in page.read_text(), page


def test_table3_takes_sdm_from_table2_and_its_time_from_the_noise_jobs(completed_run):
    """SDM is not retrained for Table 3: its rows are Table 2's runs 0..baselines.runs-1, its seconds the
    noise jobs' own timing; every baseline has one runs file per noise level (one job each)."""
    import pandas as pd

    config = dot_test_config()
    results = completed_run / "results"
    paired = config["baselines"]["runs"]
    table3 = pd.read_csv(results / "tables" / "table3.csv")
    sdm_rows = table3[table3["method"] == "sdm"].set_index("noise_level")
    distances = pd.read_csv(results / "noise" / "distances.csv")
    timings = [json.loads(path.read_text()) for path in sorted((results / "noise").glob("level*_chunk*_seconds.json"))]
    assert len(timings) == len(config["noise"]["levels"]) * -(-config["noise"]["runs"] // config["noise"]["chunk_size"])
    assert sorted(sdm_rows.index) == sorted(config["noise"]["levels"])
    for level in config["noise"]["levels"]:
        runs = distances[(distances["noise_level"] == level) & (distances["run"] < paired)]
        assert sdm_rows.loc[level, "runs"] == paired == len(runs)
        assert sdm_rows.loc[level, "mean_m"] == pytest.approx(runs["distance"].mean(), rel=1e-12)
        recorded = [timing for timing in timings if timing["noise_level"] == level]
        seconds = sum(timing["seconds"] for timing in recorded) / sum(timing["runs"] for timing in recorded)
        assert sdm_rows.loc[level, "seconds_per_run"] == pytest.approx(seconds, rel=1e-12)
    for method in config["baselines"]["methods"]:
        for level in config["noise"]["levels"]:
            runs = pd.read_csv(results / "baselines" / f"runs_{method}_level{level}.csv")
            assert sorted(runs["run"]) == list(range(paired)) and set(runs["noise_level"]) == {level}, (method, level)
    assert not list((results / "baselines").glob("runs_sdm*"))


def _key_cases() -> dict[str, tuple[dict, str | None]]:
    """Every schema key of the .test config: (config change, first stage expected to rerun)."""
    return {
        "results_dir": ({"results_dir": "results_elsewhere"}, "synthetic"),
        "data.source": (None, "data"),  # built in the test: needs a real folder
        "data.apollo_folder": ({"data": {"apollo_folder": "/somewhere/else"}}, None),
        "data.pku_csv": ({"data": {"pku_csv": "/somewhere/else.csv"}}, None),
        "data.synthetic.n_images": ({"data": {"synthetic": {"n_images": 161}}}, "synthetic"),
        "data.synthetic.seed": ({"data": {"synthetic": {"seed": 1}}}, "synthetic"),
        "sky.n_images": ({"sky": {"n_images": 127}}, "sample"),
        "sky.shift": ({"sky": {"shift": [0.4, 0.2]}}, "sky"),
        "sky.seed": ({"sky": {"seed": 1}}, "sample"),
        "split.n_selected": ({"split": {"n_selected": 97, "n_dev": 33}}, "split"),
        "split.n_train": ({"split": {"n_selected": 97, "n_train": 65}}, "split"),
        "split.n_dev": ({"split": {"n_selected": 95, "n_dev": 31}}, "split"),
        "split.seed": ({"split": {"seed": 1}}, "split"),
        "train.s": ({"train": {"s": 3}}, "tune"),
        "train.batch_size": ({"train": {"batch_size": 8}}, "tune"),
        "train.lr_decay": ({"train": {"lr_decay": 0.25}}, "tune"),
        "train.seed": ({"train": {"seed": 1}}, "tune"),
        "tuning.n_epoch": ({"tuning": {"n_epoch": [1, 2]}}, "tune"),
        "tuning.lr": ({"tuning": {"lr": [3.0e-4, 1.0e-3, 2.0e-3]}}, "tune"),
        "noise.levels": ({"noise": {"levels": [0, 1, 2, 3, 4, 5]}}, "noise"),
        "noise.runs": ({"noise": {"runs": 3}}, "noise"),
        "noise.chunk_size": ({"noise": {"chunk_size": 1}}, "noise"),
        "noise.seed": ({"noise": {"seed": 1}}, "noise"),
        "figures.example": ({"figures": {"example": 1}}, "figures"),
        "figures.seed": ({"figures": {"seed": 1}}, "figures"),
        "baselines.enabled": ({"baselines": {"enabled": False}}, "table4"),
        "baselines.methods": ({"baselines": {"methods": ["silhouette", "chamfer", "sinkhorn"]}}, "table3"),
        "baselines.runs": ({"baselines": {"runs": 1}}, "baseline_runs"),
        "baselines.runs_by_method": ({"baselines": {"runs_by_method": {"cmaes": 1}}}, "baseline_runs"),
        "baselines.silhouette": ({"baselines": {"silhouette": {"lr": 0.2, "steps": 12}}}, "baseline_tune"),
        "baselines.chamfer": ({"baselines": {"chamfer": {"lr": 0.2, "steps": 12}}}, "baseline_tune"),
        "baselines.sinkhorn": ({"baselines": {"sinkhorn": {"lr": 0.2, "steps": 8}}}, "baseline_tune"),
        "baselines.cmaes": ({"baselines": {"cmaes": {"sigma0": 0.2, "budget": 120}}}, "baseline_tune"),
        "floor.enabled": ({"floor": {"enabled": False}}, "table3"),
        "floor.runs": ({"floor": {"runs": 1}}, "floor_runs"),
        "floor.settings": ({"floor": {"settings": {"restarts": 2, "budget": 60}}}, "floor_runs"),
        "research.rules.enabled": ({"research": {"rules": {"enabled": False}}}, "report"),
        "research.rules.names": ({"research": {"rules": {"names": ["closed", "closed_r2"]}}}, "rule_runs"),
        "research.rules.runs": ({"research": {"rules": {"runs": 1}}}, "rule_runs"),
        "research.depth.enabled": ({"research": {"depth": {"enabled": False}}}, "report"),
        "research.depth.shifts_c": ({"research": {"depth": {"shifts_c": [-1.0, 0.5, 1.0]}}}, "depth_runs"),
        "research.depth.noise_levels": ({"research": {"depth": {"noise_levels": [0, 1, 2]}}}, "depth_runs"),
        "research.depth.runs": ({"research": {"depth": {"runs": 1}}}, "depth_runs"),
        "research.depth.schedule": ({"research": {"depth": {"schedule": "paper"}}}, "depth_runs"),
        "research.depth.lr_scale": ({"research": {"depth": {"lr_scale": 3}}}, "depth_runs"),
        **_objects_cases(),
        **_network_cases(),
    }


def _nested_cases(section: str, cases: dict[str, tuple]) -> dict[str, tuple[dict, str | None]]:
    """``research.<section>``'s cases by dotted key (``train.lr``) as whole config changes, by full key."""
    changes = {}
    for key, (value, stage) in cases.items():
        change = value
        for part in reversed(["research", section, *key.split(".")]):
            change = {part: change}
        changes[f"research.{section}.{key}"] = (change, stage)
    return changes


def _network_cases() -> dict[str, tuple[dict, str | None]]:
    """The Table 7 keys' cases: (config change, first stage expected to rerun); the .test config runs Table 7."""
    cases = {
        "enabled": (False, None),  # Table 7's stages go; no other stage reads them
        "sizes": ([40, 16, 16], "network_train"),
        "seed": (1, "network_train"),
        "runs": (3, "network_train"),  # run 2's networks are new; runs 0 and 1 stay
        "noise_levels": ([0, 1], "network_train"),
        "camera_sd": (0.1, "network_train"),
        "losses": (["supervised"], "network_test"),  # the trained networks stay; every test job reads fewer
        "train.epochs": (1, "network_train"),
        "train.per_epoch": (16, "network_train"),
        "train.batch_size": (4, "network_train"),
        "train.lr": (1.0e-3, "network_train"),
        "train.s": (1, "network_train"),
        "train.sigma": (1.0, "network_train"),
        "train.max_points": (32, "network_train"),
        "refine.s": (2, "network_test"),
        "refine.n_epoch": (2, "network_test"),
        "refine.lr": (1.0e-3, "network_test"),
        "refine.rule": ("paper", "network_test"),
        "refine.batch_size": (2, "network_test"),
    }
    return _nested_cases("network", cases)


def _objects_cases() -> dict[str, tuple[dict, str | None]]:
    """The Table 6 keys' cases: (config change, first stage expected to rerun); the .test config runs Table 6."""
    cases = {
        "enabled": (False, None),  # Table 6's stages go; no other stage reads them
        "sharings": (["camera+car"], "objects_runs"),
        "noise_levels": ([0, 1], "objects_runs"),
        "runs": (2, "objects_runs"),
        "configurations": (32, "objects_runs"),
        "batch_size": (4, "objects_runs"),
        "screens": ([{"scale": 1}, {"scale": 3, "sharings": ["car"], "noise_levels": [0]}], "objects_runs"),
        "methods": (["sdm_paper", "floor"], "objects_runs"),
        "gate": (2.5, "objects_runs"),
        "identifiability.reach": (0.3, "objects_runs"),
        "identifiability.step": (0.02, "objects_runs"),
        "truth.camera_sd": (0.1, "objects_runs"),
        "truth.car_sd": (0.1, "objects_runs"),
        "truth.residual_sd": (0.01, "objects_runs"),
        "warm.lr": (0.0003, "objects_runs"),
        "warm.n_epoch": (3, "objects_runs"),
        "rows.lr": (0.001, "objects_runs"),
        "rows.n_epoch": (2, "objects_runs"),
        "rows.s": (3, "objects_runs"),
        "rows.first_zoom": ("prior", "objects_runs"),
        "schedule": ('paper', "objects_runs"),
        "cmaes.evaluations_per_unknown": (20, "objects_runs"),
        "cmaes.penalty": (2.0, "objects_runs"),
        "cmaes.step": (0.05, "objects_runs"),
        "cmaes.car_step": (0.05, "objects_runs"),
        "floor.evaluations_per_unknown": (20, "objects_runs"),
        "floor.restarts": (4, "objects_runs"),
        "silhouette.lr": (0.2, "objects_runs"),
        "silhouette.sigma": (1.0, "objects_runs"),
        "silhouette.batch_size": (16, "objects_runs"),
        "silhouette.steps": (4, "objects_runs"),
        "scaling.scale": (2, "objects_scaling"),  # the .test config's second screen
        "scaling.cars": ([4], "objects_scaling"),
        "scaling.n_images": (17, "objects_scaling"),
        "scaling.seed": (1, "objects_scaling"),
        "scaling.runs": (2, "objects_scaling"),
        "scaling.noise_level": (1, "objects_scaling"),
        "scaling.epochs": ([2], "objects_scaling"),
        "scaling.budgets": ([7], "objects_scaling"),
    }
    return _nested_cases("objects", cases)


def _schema_keys(schema: dict, prefix: str = "") -> list[str]:
    keys = []
    for name, sub in schema.get("properties", {}).items():
        dotted = f"{prefix}{name}"
        nested = sub.get("type") == "object" and "properties" in sub
        keys += _schema_keys(sub, dotted + ".") if nested else [dotted]
    return keys


def _documented_first_stages() -> dict[str, str | None]:
    """The table "Which config key reruns which stage" of docs/workflow.md."""
    table = {}
    for line in (ROOT / "docs" / "workflow.md").read_text().splitlines():
        match = re.match(r"\| `([a-z_.]+)` \| ([^|]+) \|", line)
        if match:
            stage = match.group(2).strip()
            table[match.group(1)] = None if stage.startswith("none") else stage.split()[0]
    return table


def _merge(base: dict, change: dict) -> dict:
    merged = copy.deepcopy(base)
    for key, value in change.items():
        merged[key] = _merge(merged[key], value) if isinstance(value, dict) and key in merged else value
    return merged


def test_every_schema_key_has_a_case_and_a_documented_stage():
    keys = _schema_keys(yaml.safe_load(SCHEMA.read_text()))
    assert sorted(keys) == sorted(_key_cases()), set(keys) ^ set(_key_cases())
    documented = _documented_first_stages()
    assert {key: documented.get(key, "missing") for key in keys} == {key: stage for key, (_, stage) in
                                                                     _key_cases().items()}


@pytest.fixture(scope="module")
def key_case_dry_runs(completed_run, tmp_path_factory, request) -> dict[str, subprocess.CompletedProcess]:
    """The dry run of the completed .test run with each collected key case's config (an override file), per key.
    Two at a time, side by side: a dry run takes one core, mostly Snakemake's start."""
    keys = sorted({item.callspec.params["key"] for item in request.session.items
                   if getattr(item, "originalname", None) == "test_each_config_key_reruns_its_first_stage"})
    folder = tmp_path_factory.mktemp("key_cases")
    runs = []
    for key in keys:
        change, _ = _key_cases()[key]
        if change is None:  # data.source: the shipped real sample instead of the synthetic set
            change = {"data": {"source": "apollo", "apollo_folder": str(APOLLO_SAMPLE)},
                      "sky": {"n_images": 57}, "split": {"n_selected": 48, "n_train": 32, "n_dev": 16},
                      "research": {"network": {"sizes": [32, 8, 8]}}}  # Table 7's sizes within the 57
        override = folder / f"{key}.yaml"
        override.write_text(yaml.safe_dump(_merge(dot_test_config(), change)))
        runs.append((completed_run, ("-n", "--quiet", "rules", "--configfile", str(override))))
    results = [result for i in range(0, len(runs), 2) for result in snakemakes(*runs[i:i + 2])]
    return dict(zip(keys, results))


@pytest.mark.parametrize("key", sorted(_key_cases()))
def test_each_config_key_reruns_its_first_stage(key_case_dry_runs, key):
    _, expected = _key_cases()[key]
    jobs = planned(key_case_dry_runs[key])
    first = next((stage for stage in STAGES if stage in jobs), None)
    assert first == expected, (key, jobs)


def test_a_failed_stage_names_the_cause_first(tmp_path):
    """A stage failing at run time prints its one-line cause, naming the key, and keeps its executed notebook.

    A PKU csv's image count is known only to the data stage, so ``sky.n_images`` beyond it fails in the
    sample stage (an ApolloCar3D folder is counted at parse time instead).
    """
    csv = tmp_path / "train.csv"
    rows = [f"ID_{i:03d},0 0.1 -3.1 0.0 {i % 3 - 1.0} 1.7 {20.0 + 3 * i}" for i in range(6)]
    csv.write_text("ImageId,PredictionString\n" + "\n".join(rows) + "\n")
    config = _merge(dot_test_config(), {"data": {"source": "pku", "pku_csv": str(csv)}})
    result = snakemake("-c1", cwd=workdir(tmp_path / "run", config))
    output = result.stdout + result.stderr
    assert result.returncode != 0
    causes = [line for line in output.splitlines() if " failed: " in line]
    assert causes and "SDMInputError: config key 'sky.n_images'" in causes[0], output[-3000:]
    # and again at the end, read from the stage's log (the way a cluster job's cause reaches the console)
    assert output[output.index("The failed stages' causes:"):].splitlines()[1] == causes[0]
    assert "results/notebooks/sample.ipynb" in output
    assert (tmp_path / "run" / "results" / "notebooks" / "sample.ipynb").is_file()
    assert '"cell_type"' not in output  # no notebook JSON on the console


def test_a_damaged_sky_file_is_refused_and_a_rebuilt_one_gives_the_same_tables(completed_run, tmp_path):
    """One flipped byte in sky.bin: the next stage that reads it fails naming the file; rebuilt, the tables are
    byte-identical to the undamaged run's."""
    directory = tmp_path / "run"
    shutil.copytree(completed_run, directory, symlinks=True, ignore=shutil.ignore_patterns("locks", "incomplete"))
    sky = directory / "results" / "sky" / "sky.bin"
    data = bytearray(sky.read_bytes())
    data[len(data) // 2] ^= 0x10  # inside the arrays (the header is at the start)
    sky.write_bytes(bytes(data))
    result = snakemake("-c1", cwd=directory)
    output = result.stdout + result.stderr
    assert result.returncode != 0
    causes = [line for line in output.splitlines() if " failed: " in line]
    assert causes and "sky.bin" in causes[0] and "SDMInputError" in causes[0], output[-3000:]
    sky.unlink()
    result = snakemake("-c2", "tables", cwd=directory)  # up to Tables 1-2, the tables this test compares
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    for table in ["table1.csv", "table2.csv", "table2.md", "table1.tex"]:
        assert (directory / "results" / "tables" / table).read_bytes() == \
            (completed_run / "results" / "tables" / table).read_bytes(), table


def test_table7_run_twice_on_one_machine_gives_the_same_table(completed_run, tmp_path):
    """Every Table 7 stage run again on the same config (every network trained anew, every test job and the
    gradients' bias measured again): the same weights, the same bias file, and Table 7 the same to the bit but
    for the CPU seconds it measures (and the count of configurations computed from them)."""
    import pandas as pd
    import torch

    directory = tmp_path / "run"
    shutil.copytree(completed_run, directory, symlinks=True, ignore=shutil.ignore_patterns("locks", "incomplete"))
    result = snakemake("-c2", "--forcerun", "network_train", "network_bias", "--", "results/tables/table7.csv",
                       cwd=directory)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-3000:]
    network = Path("results") / "research" / "network"
    weights = sorted(path.relative_to(completed_run) for path in (completed_run / network).glob("*.pt"))
    assert len(weights) == 10  # five losses, two runs
    for path in weights:
        assert (directory / path).stat().st_mtime > (completed_run / path).stat().st_mtime, path  # trained anew
        stored = [torch.load(run / path, weights_only=True) for run in (completed_run, directory)]
        assert all(torch.equal(stored[0]["state"][name], stored[1]["state"][name]) for name in stored[0]["state"])
    assert (directory / network / "bias.csv").read_bytes() == (completed_run / network / "bias.csv").read_bytes()
    first, again = (pd.read_csv(run / "results" / "tables" / "table7.csv") for run in (completed_run, directory))
    measured = ["cpu_ms", "train_s", "pays_off"]
    assert first["runs"].max() == 2 and first["diff_m"].notna().any()
    pd.testing.assert_frame_equal(first.drop(columns=measured), again.drop(columns=measured), check_exact=True)


def test_conda_environment_pins_the_tested_versions():
    """workflow/envs/sdm.yaml (used with --software-deployment-method conda) pins what constraints.txt pins."""
    tested = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.split("==")
            tested[name.lower()] = version.strip()
    environment = yaml.safe_load((ROOT / "workflow" / "envs" / "sdm.yaml").read_text())
    pip = next(item["pip"] for item in environment["dependencies"] if isinstance(item, dict))
    assert len(pip) >= 10
    for requirement in pip:
        name, version = requirement.split("==")
        assert tested.get(name.lower()) == version, (requirement, tested.get(name.lower()))
