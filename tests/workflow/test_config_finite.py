"""Every number of the workflow's configuration is finite: a NaN or an infinity anywhere is refused naming its key.

JSON Schema cannot refuse YAML's ``.nan`` (every comparison with NaN is false), so
``workflow/scripts/config_check.py`` walks the whole config; the integer keys the schema refuses
itself. The numeric keys are enumerated from the shipped configs (with the schema's defaults filled
in), and every numeric key of the schema must be among them, so a key added later is covered.
Everything runs in-process (the schema check and ``check_config`` are what the Snakefile runs);
one dry run checks the Snakefile's own path.
"""
from __future__ import annotations

import copy
import math
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "workflow" / "scripts"))
from config_check import ConfigError, check_config, validate_schema  # noqa: E402
from test_workflow import apollo_sample_config, default_config, dot_test_config, snakemake, workdir  # noqa: E402

SCHEMA = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text())
BAD = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def filled(config: dict) -> dict:
    config = copy.deepcopy(config)
    validate_schema(config)  # fills the schema's defaults (research.depth.lr_scale, ...)
    return config


CONFIGS = {"default": filled(default_config()), ".test": filled(dot_test_config()),
           "apollocar3d-sample": filled(apollo_sample_config())}


def numeric_paths(value, path=()) -> list[tuple]:
    """Paths (keys and list positions) of every int or float (not bool) in a config."""
    if isinstance(value, dict):
        return [p for key, item in value.items() for p in numeric_paths(item, (*path, key))]
    if isinstance(value, list):
        return [p for index, item in enumerate(value) for p in numeric_paths(item, (*path, index))]
    return [path] if isinstance(value, (int, float)) and not isinstance(value, bool) else []


def dotted(path: tuple) -> str:
    return "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in path).lstrip(".")


def schema_numeric_keys(schema: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose value (or list items) the schema types as number or integer."""
    keys = []
    for name, sub in schema.get("properties", {}).items():
        key = f"{prefix}{name}"
        types = sub.get("type"), (sub.get("items") or {}).get("type")
        if any(t in ("number", "integer") for t in types):
            keys.append(key)
        keys += schema_numeric_keys(sub, key + ".")
    return keys


#: Each numeric key once, in the first config that has it: (config name, path).
PATHS = list({dotted(path): (name, path) for name, config in reversed(CONFIGS.items())
              for path in numeric_paths(config)}.values())


def test_every_numeric_schema_key_is_enumerated():
    """The enumeration below reaches every numeric key of the schema (and the baselines' settings)."""
    found = {dotted(path) for _, path in PATHS}
    stems = {key.split("[")[0] for key in found}
    missing = [key for key in schema_numeric_keys(SCHEMA) if key not in stems]
    assert not missing, missing
    assert {"baselines.cmaes.sigma0[0]", "train.lr_decay", "tuning.lr[0]", "research.depth.lr_scale"} <= found
    assert len(found) > 50


def refusal(config: dict) -> str:
    """The message the workflow's checks (schema, then check_config, as the Snakefile runs them) give."""
    with pytest.raises(ConfigError) as error:
        validate_schema(config)
        check_config(config)
    return str(error.value)


@pytest.mark.parametrize("bad", list(BAD))
def test_a_non_finite_number_anywhere_is_refused_naming_its_key(bad):
    """Each numeric key of each shipped config, set to NaN, +inf and -inf in turn: the error names that key.

    A float key is refused by check_config ('must be a finite number'); an integer key already by the
    schema (not an integer), under the same key name.
    """
    for name, path in PATHS:
        config = copy.deepcopy(CONFIGS[name])
        *parents, last = path
        holder = config
        for part in parents:
            holder = holder[part]
        holder[last] = BAD[bad]
        message = refusal(config)
        assert message.startswith(f"config key '{dotted(path)}'"), (name, dotted(path), message)


def test_the_finite_check_names_float_keys_in_its_own_words():
    config = copy.deepcopy(CONFIGS["default"])
    config["train"]["lr_decay"] = math.nan
    assert refusal(config) == "config key 'train.lr_decay': must be a finite number, got nan"
    config = copy.deepcopy(CONFIGS["default"])
    config["tuning"]["lr"] = [1e-4, math.inf]
    assert refusal(config) == "config key 'tuning.lr[1]': must be a finite number, got inf"
    config = copy.deepcopy(CONFIGS["default"])
    config["baselines"]["cmaes"] = {"sigma0": -math.inf}
    assert refusal(config) == "config key 'baselines.cmaes.sigma0': must be a finite number, got -inf"


@pytest.mark.slow
def test_a_nan_learning_rate_fails_before_any_job_naming_the_key(tmp_path):
    """The Snakefile's path: `tuning: {lr: [.nan]}` once ended in a MissingInputException for cell_1_nan.json."""
    overlay = tmp_path / "bad.yaml"
    overlay.write_text("tuning: {lr: [.nan]}\n")
    result = snakemake("-n", "--configfile", str(overlay), cwd=workdir(tmp_path / "run", default_config()))
    output = result.stdout + result.stderr
    assert result.returncode != 0
    assert "config key 'tuning.lr[0]': must be a finite number, got nan" in output, output
    assert "MissingInputException" not in output and "Traceback" not in output
