"""Every key of the research sections is checked before the first job: unknown keys refused, sizes against the
split and the Sky set, batches against the sizes, rule names against the schema's (the registry's), each error
naming the key's path."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
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
    ("research.network.refine.rule", "nope_rule", r"config key 'research\.network\.refine\.rule': 'nope_rule' is "
                                                  r"not a rule name of \["),
    ("research.network.refine.rule", "closed_centred_r1+group_crossing:4",
     r"config key 'research\.network\.refine\.rule': 'closed_centred_r1\+group_crossing:4' is not a rule name"),
    ("research.network.sizes", [3000, 1000, 748], r"config key 'research\.network\.sizes': train \+ dev \+ test "
                                                  r"\[3000, 1000, 748\] ask for 4748 configurations; the Sky set has"),
    ("research.network.train.batch_size", 5000, r"config key 'research\.network\.train\.batch_size': at most the "
                                                r"train configurations"),
    ("research.network.train.per_epoch", 4000, r"config key 'research\.network\.train\.per_epoch': at most the "
                                               r"train configurations, research\.network\.sizes\[0\] \(3000\)"),
    ("research.network.train.per_epoch", 8, r"config key 'research\.network\.train\.per_epoch': 0 \(every "
                                            r"training configuration\) or at least one batch"),
    ("research.network.train.per_epoch", -1, r"config key 'research\.network\.train\.per_epoch': -1 is less than "
                                             r"the minimum of 0"),
    ("research.network.runs", 0, r"config key 'research\.network\.runs': 0 is less than the minimum of 1"),
    ("research.network.refine.batch_size", 1000, r"config key 'research\.network\.refine\.batch_size': at most the "
                                                 r"test configurations"),
    ("research.objects.silhouette.batch_size", 500, r"config key 'research\.objects\.silhouette\.batch_size': at "
                                                    r"most research\.objects\.configurations"),
    ("research.objects.screens", [{"scale": 12}, {"scale": 1}, {"scale": 12, "disc": "metres"}],
     r"config key 'research\.objects\.screens': each scale once \(a scale names its rows and its files\), got 12 2 "
     r"times in \[12, 1, 12\]"),
    ("research.objects.scaling.scale", 4, r"config key 'research\.objects\.scaling\.scale': one of "
                                          r"research\.objects\.screens' scales \[12, 1\] .*got 4"),
    ("research.objects.screens", [{"disc": "pixels"}], r"config key 'research\.objects\.screens\[0\]': 'scale' is a "
                                                       r"required property"),
    ("research.objects.screens", [{"scale": 0}], r"config key 'research\.objects\.screens\[0\]\.scale': 0 is less "
                                                 r"than the minimum of 1"),
    ("research.objects.screens", [{"scale": 2, "methods": ["adam"]}],
     r"config key 'research\.objects\.screens\[0\]\.methods\[0\]': 'adam' is not one of"),
    ("research.objects.screens", [{"scale": 2, "zoom": 3}],
     r"config key 'research\.objects\.screens\[0\]': Additional properties are not allowed \('zoom' was unexpected\)"),
    ("research.objects.methods", [], r"config key 'research\.objects\.methods': \[\] should be non-empty"),
    ("research.objects.identifiability.step", 0, r"config key 'research\.objects\.identifiability\.step': 0 is less "
                                                 r"than or equal to the minimum of 0"),
    ("research.objects.rows.first_zoom", "zero", r"config key 'research\.objects\.rows\.first_zoom': 'zero' is "
                                                 r"not one of \['s', 'prior'\]"),
], ids=["unknown-key", "unknown-rule", "schedule-for-a-rule", "sizes", "train-batch", "per-epoch-over-train",
        "per-epoch-under-batch", "per-epoch-negative", "no-runs", "refine-batch",
        "silhouette-batch", "screen-twice", "scaling-off-screen", "screen-without-scale", "screen-scale-0",
        "screen-method", "screen-key", "no-methods", "scan-step", "first-zoom"])
def test_a_bad_research_key_is_refused_naming_its_path(path, value, message):
    """On main each of these passed the checks before the run and failed (if at all) inside the stages."""
    config = _set(_config(), path, value)
    with pytest.raises(ConfigError, match=message):
        _checked(config)


def test_config_yaml_runs_table6_on_two_screens_the_scaling_on_the_first():
    """The chosen screen (scale 12, its dev-chosen settings) and the paper's (scale 1) beside it."""
    objects = _config()["research"]["objects"]
    screens = objects["screens"]
    assert [screen["scale"] for screen in screens] == [12, 1]
    assert objects["scaling"]["scale"] == 12
    assert screens[0]["rows"] == {"lr": 2.5e-3, "n_epoch": 16, "s": 6, "first_zoom": "prior"}
    assert screens[0]["cmaes"]["car_step"] == 0.1 and screens[0]["cmaes"]["step"] == 0.03
    assert 0 in objects["noise_levels"] and 2 in objects["noise_levels"] and objects["runs"] >= 20


def test_a_good_screen_list_passes():
    config = _set(_config(), "research.objects.screens", [{"scale": 2, "disc": "metres", "noise_levels": [1],
                                                            "sharings": ["car"], "methods": ["floor"],
                                                            "rows": {"lr": 1e-3, "n_epoch": 2, "s": 1},
                                                            "cmaes": {"evaluations_per_unknown": 5}}])
    _checked(_set(config, "research.objects.scaling.scale", 2))


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


def _schema_node(path: str) -> dict:
    """The schema's node of a dotted key (``*``: the items of a list)."""
    import config_check

    node = yaml.safe_load(config_check.SCHEMA_PATH.read_text())
    for key in path.split("."):
        node = node["items"] if key == "*" else node["properties"][key]
    return node


def _allowed(schema: dict):
    """A value the schema node allows: its first enum value, or for a list of integers ``[0]``."""
    return schema["enum"][0] if "enum" in schema else [0] if schema.get("type") == "array" else 0


@pytest.mark.parametrize("old, new", sorted(__import__("config_check").RENAMED.items()))
def test_a_key_under_its_old_name_is_refused_naming_the_new_one(old, new):
    """Each renamed key (config_check.RENAMED), written under its old name where config.yaml has the new one (``*``:
    the list's first item; where config.yaml leaves the key out, the first value its schema allows), is refused
    before the schema runs, with the new name in the message (a list item named by its index)."""
    config = _config()
    node = config
    *parents, last = new.split(".")
    for key in parents:
        node = node[0 if key == "*" else key]
    node[old.split(".")[-1]] = node.pop(last) if last in node else _allowed(_schema_node(new))
    shown = {name: re.escape(name.replace(".*.", "[0].")) for name in (old, new)}
    with pytest.raises(ConfigError, match=rf"^config key '{shown[old]}' is now '{shown[new]}'"):
        _checked(config)


def test_an_old_key_in_a_list_item_is_refused_naming_the_item():
    """A renamed key in an item of a list (a screen's rows) is named with the item's index, in both names."""
    config = _config()
    config["research"]["objects"]["screens"][1]["rows"] = {"lr": 1e-3, "n_epoch": 2, "s": 3, "first_level": "prior"}
    with pytest.raises(ConfigError, match=r"^config key 'research\.objects\.screens\[1\]\.rows\.first_level' is now "
                                          r"'research\.objects\.screens\[1\]\.rows\.first_zoom'"):
        _checked(config)


def test_the_renamed_keys_exist_under_their_new_name_in_the_schema():
    """A rename's new key is a key of the schema: the message never points to a key that does not exist."""
    import config_check

    for new in config_check.RENAMED.values():
        node = _schema_node(new)
        assert "description" in node or "type" in node or "allOf" in node or "enum" in node, new
