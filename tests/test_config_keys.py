"""Every key of the research sections is checked before the first job: unknown keys refused, sizes against the
split and the Sky set, batches against the sizes, rule names against the schema's (the registry's), each error
naming the key's path."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
from config_check import ConfigError, check_config, validate_schema  # noqa: E402


def _config() -> dict:
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["research"]["objects"]["enabled"] = True
    config["research"]["network"]["enabled"] = True
    return config


def _checked(config: dict) -> None:
    validate_schema(config)
    check_config(config)


def test_the_opt_in_sections_of_config_yaml_pass():
    _checked(_config())


def _set(config: dict, path: str, value) -> dict:
    *parents, last = path.split(".")
    node = config
    for key in parents:
        node = node[key]
    node[last] = value
    return config


@pytest.mark.parametrize("path, value, message", [
    ("research.objects.silhouette", {"lrr": 0.5}, r"config key 'research\.objects\.silhouette': Additional "
                                                  r"properties are not allowed \('lrr' was unexpected\)"),
    ("research.network.refine.flow", "nope_rule", r"config key 'research\.network\.refine\.flow': 'nope_rule' is "
                                                  r"not a rule name of \["),
    ("research.network.refine.flow", "closed_centred_r1+group_crossing:4",
     r"config key 'research\.network\.refine\.flow': 'closed_centred_r1\+group_crossing:4' is not a rule name"),
    ("research.network.sizes", [3000, 1000, 748], r"config key 'research\.network\.sizes': train \+ dev \+ test "
                                                  r"\[3000, 1000, 748\] ask for 4748 configurations; the Sky set has"),
    ("research.network.train.batch_size", 5000, r"config key 'research\.network\.train\.batch_size': at most the "
                                                r"train configurations"),
    ("research.network.refine.batch_size", 1000, r"config key 'research\.network\.refine\.batch_size': at most the "
                                                 r"test configurations"),
    ("research.objects.silhouette.batch_size", 500, r"config key 'research\.objects\.silhouette\.batch_size': at "
                                                    r"most research\.objects\.configurations"),
], ids=["unknown-key", "unknown-rule", "schedule-for-a-rule", "sizes", "train-batch", "refine-batch",
        "silhouette-batch"])
def test_a_bad_research_key_is_refused_naming_its_path(path, value, message):
    """On main each of these passed the checks before the run and failed (if at all) inside the stages."""
    config = _set(_config(), path, value)
    with pytest.raises(ConfigError, match=message):
        _checked(config)


def test_the_workflow_refuses_a_bad_key_before_any_job(tmp_path):
    """The Snakefile runs the same checks at parse time: a dry run names the key and schedules nothing."""
    config = _set(_config(), "research.objects.silhouette", {"lr": 0.1, "lrr": 0.5})
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(config))
    done = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "1", "--configfile",
                           str(tmp_path / "bad.yaml"), "--snakefile", str(ROOT / "Snakefile"), "--directory",
                           str(ROOT)], capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert "config key 'research.objects.silhouette': Additional properties are not allowed ('lrr' was " \
           "unexpected)" in done.stdout + done.stderr
