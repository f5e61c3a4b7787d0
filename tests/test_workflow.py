"""The Snakemake workflow: lint, dry runs (default, .test, SLURM) and config errors that name the key.

The end-to-end run of ``.test/config.yaml`` is ``scripts/ci_workflow.sh`` (called by ``.ci/run``).
"""
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sdm.config import check_config, chunk_runs, load_config, lr_label, noise_chunks, tuning_cells
from sdm.errors import SDMInputError

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / "workflow" / "schemas" / "config.schema.yaml"


def snakemake(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "snakemake", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def default_config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text())


def test_lint_is_clean():
    result = snakemake("--lint")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Congratulations, your workflow is in a good condition" in result.stdout + result.stderr


def test_dry_run_default_config_plans_every_stage():
    result = snakemake("-n", "--quiet", "rules")
    assert result.returncode == 0, result.stdout + result.stderr
    output = result.stdout + result.stderr
    config = default_config()
    cells = len(config["tuning"]["n_epoch"]) * len(config["tuning"]["lr"])
    for rule, count in {"synthetic": 1, "data": 1, "sample": 1, "sky": 1, "split": 1, "tune": cells,
                        "best": 1, "noise": len(noise_chunks(config)), "tables": 1, "figures": 1, "report": 1}.items():
        assert any(line.split() == [rule, str(count)] for line in output.splitlines()), (rule, output)


def test_dry_run_test_config():
    result = snakemake("-n", "--directory", ".test")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("flag", ["--workflow-profile", "--profile"])
def test_dry_run_slurm_profile(flag):
    result = snakemake("-n", flag, "profiles/slurm")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(
    "change, key",
    [
        ({"train": {"s": 9}}, "train.s"),
        ({"noise": {"levels": [0, -1]}}, "noise.levels"),
        ({"data": {"source": "kitti"}}, "data.source"),
        ({"split": {"n_train": 500}}, "split.n_selected"),
        ({"sky": {"n_images": 6000}}, "sky.n_images"),
        ({"noise": {"runs": 0}}, "noise.runs"),
    ],
)
def test_bad_config_fails_naming_the_key(tmp_path, change, key):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(change))
    result = snakemake("-n", "--configfile", str(bad))
    assert result.returncode != 0
    output = result.stdout + result.stderr
    dotted = key.split(".")
    # Snakemake's schema check prints the path as ['train']['s']; sdm.config.check_config as 'train.s'.
    assert f"'{key}'" in output or "".join(f"['{part}']" for part in dotted) in output, output


# -- sdm.config, without Snakemake ------------------------------------------------------------------


def write(tmp_path: Path, config: dict) -> Path:
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_default_config_loads():
    config = load_config(ROOT / "config.yaml", SCHEMA)
    assert config["sky"]["n_images"] == 4248
    assert config["split"] == {"n_selected": 768, "n_train": 512, "n_dev": 256, "seed": 0}
    assert config["noise"]["runs"] == 60 and config["noise"]["levels"] == [0, 1, 2, 3, 4]
    load_config(ROOT / ".test" / "config.yaml", SCHEMA)


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("train", "s", 0, "config key 'train.s'"),
        ("train", "s", "4", "config key 'train.s'"),
        ("train", "batch_size", 0, "config key 'train.batch_size'"),
        ("tuning", "lr", [0.0], "config key 'tuning.lr.0'"),
        ("noise", "chunk_size", 0, "config key 'noise.chunk_size'"),
        ("sky", "shift", [0.5], "config key 'sky.shift'"),
        ("split", "n_dev", 300, "config key 'split.n_selected'"),
    ],
)
def test_schema_and_cross_checks_name_the_key(tmp_path, section, key, value, message):
    config = default_config()
    config[section][key] = value
    with pytest.raises(SDMInputError, match=message.replace(".", r"\.")):
        load_config(write(tmp_path, config), SCHEMA)


def test_unknown_key_is_rejected(tmp_path):
    config = default_config()
    config["train"]["epochs"] = 3
    with pytest.raises(SDMInputError, match="config key 'train'.*epochs"):
        load_config(write(tmp_path, config), SCHEMA)


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("noise", "chunk_size", 61, "noise.chunk_size"),
        ("train", "s", 8, "train.s"),
        ("split", "n_selected", 5000, "split.n_selected"),
    ],
)
def test_cross_key_rules(section, key, value, message):
    config = default_config()
    config[section][key] = value
    if key == "n_selected":
        config["split"]["n_train"] = 4000
        config["split"]["n_dev"] = 1000
    with pytest.raises(SDMInputError, match=f"config key '{message}'"):
        check_config(config)


def test_real_sources_need_their_path():
    config = default_config()
    config["data"] = {"source": "pku", "synthetic": config["data"]["synthetic"]}
    with pytest.raises(SDMInputError, match="config key 'data.pku_csv'"):
        check_config(config)


def test_grid_and_chunks_follow_the_config():
    config = default_config()
    assert tuning_cells(config) == [(1, "1e-04"), (1, "3e-04"), (1, "1e-03"), (2, "1e-04"), (2, "3e-04"), (2, "1e-03")]
    chunks = noise_chunks(config)
    assert len(chunks) == 10 and chunks[0] == (0, 0) and chunks[-1] == (4, 1)
    runs = sorted(run for chunk in range(2) for run in chunk_runs(config, chunk))
    assert runs == list(range(60))
    config["noise"]["chunk_size"] = 25
    assert [len(chunk_runs(config, k)) for k in range(3)] == [25, 25, 10]
    assert float(lr_label(3e-4)) == 3e-4 and float(lr_label(2.5e-4)) == 2.5e-4
