"""The workflow's configuration (``config.yaml``): the checks that tie keys together.

``workflow/schemas/config.schema.yaml`` types every key and bounds each value;
:func:`check_config` adds the rules that tie keys together and that JSON Schema
cannot state. Every error is a :class:`ConfigError` whose message starts with
the dotted key it is about, e.g. ``config key 'split.n_train': ...``.

This module is workflow code: the Snakefile runs Snakemake's own schema
validation and then :func:`check_config`, before any job starts;
:func:`load_config` does both for the tests. It imports neither torch nor
``sdm``, so that parsing the workflow is fast and works where torch is not
installed (a cluster's login node).
"""
from __future__ import annotations

import copy
import functools
import math
from pathlib import Path
from typing import Any, Mapping

import yaml

#: The schema beside this file's folder.
SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "config.schema.yaml"


class ConfigError(ValueError):
    """A config value breaks a rule; the message starts with ``config key '<dotted key>'``."""


def load_config(path: str | Path, schema: str | Path = SCHEMA_PATH) -> dict:
    """Read a YAML config, validate it against ``schema`` (filling defaults) and :func:`check_config` it.

    Args:
        path: the YAML file.
        schema: JSON-Schema file in YAML (default: the workflow's); needs the ``jsonschema`` package
            (a dependency of Snakemake).

    Returns:
        The configuration as a plain dict, with the schema's defaults filled in.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        config = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ConfigError(f"{path}: not valid YAML: {error}") from None
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: the config must be a mapping of keys to values, got {type(config).__name__}")
    validate_schema(config, schema)
    check_config(config)
    return config


#: Keys that have a new name: old dotted key -> new dotted key (``*`` stands for any one key of a mapping or any
#: item of a list). A config that still uses an old name is refused with a message that gives the new one
#: (:func:`check_renamed`).
RENAMED = {
    "research.depth.flow": "research.depth.schedule",
    "research.network.refine.flow": "research.network.refine.rule",
    "research.depth.levels": "research.depth.noise_levels",
    "research.objects.levels": "research.objects.noise_levels",
    "research.objects.scaling.level": "research.objects.scaling.noise_level",
    "research.network.levels": "research.network.noise_levels",
    "research.objects.screens.*.levels": "research.objects.screens.*.noise_levels",
    "research.objects.rows.first_level": "research.objects.rows.first_zoom",
    "research.objects.screens.*.rows.first_level": "research.objects.screens.*.rows.first_zoom",
}


def check_renamed(config: Mapping[str, Any]) -> None:
    """Refuse a key that has a new name (:data:`RENAMED`), naming the new one.

    Raises:
        ConfigError: ``config key 'research.depth.flow' is now 'research.depth.schedule' ...``, a list item named
            by its index: ``config key 'research.objects.screens[1].rows.first_level' is now
            'research.objects.screens[1].rows.first_zoom' ...``.
    """
    for old, new in RENAMED.items():
        for found in _matching(config, old.split(".")):
            now = [part if wanted == "*" else wanted for part, wanted in zip(found, new.split("."))]
            raise ConfigError(f"config key '{_dotted(found)}' is now '{_dotted(now)}': rename it (the value stays as "
                              "it is)")


def _matching(value: Any, parts: list[str], prefix: tuple = ()) -> list[tuple]:
    """The key paths in ``value`` (as :func:`_dotted` reads them: an int for a list item) that ``parts`` names
    (``*`` for any one key of a mapping or any item of a list)."""
    if not parts:
        return [prefix]
    if isinstance(value, list) and parts[0] == "*":
        items = list(enumerate(value))
    elif isinstance(value, Mapping):
        items = ([(str(key), item) for key, item in value.items()] if parts[0] == "*"
                 else [(parts[0], value[parts[0]])] if parts[0] in value else [])
    else:
        return []
    return [found for key, item in items for found in _matching(item, parts[1:], (*prefix, key))]


def validate_schema(config: dict, schema: str | Path = SCHEMA_PATH) -> None:
    """Validate ``config`` against a JSON Schema written in YAML, filling in its defaults; the error names the key
    (a key that has a new name first: :func:`check_renamed`)."""
    if isinstance(config, Mapping):
        check_renamed(config)
    schema_data, validator = _validator(str(Path(schema).resolve()))
    errors = sorted(validator.iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        error = errors[0]
        raise ConfigError(f"config key '{_dotted(error.absolute_path) or '<top level>'}': {error.message}")
    _fill_defaults(config, schema_data)


@functools.lru_cache(maxsize=None)
def _validator(schema: str):
    """The parsed schema and its validator, once per process (the tests validate hundreds of configs)."""
    import jsonschema

    schema_data = yaml.safe_load(Path(schema).read_text())
    return schema_data, jsonschema.Draft202012Validator(schema_data)


def _fill_defaults(value: Any, schema: Mapping) -> None:
    """Set the schema's ``default`` values of missing keys, as Snakemake's ``validate`` does."""
    if not isinstance(value, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        if key not in value and "default" in sub:
            value[key] = copy.deepcopy(sub["default"])  # a copy: the parsed schema is cached and shared
        if key in value:
            _fill_defaults(value[key], sub)


def check_config(config: Mapping[str, Any]) -> None:
    """Check the rules that tie config keys together (the schema checks each key on its own).

    - ``split.n_train + split.n_dev == split.n_selected <= sky.n_images``;
    - with synthetic data, ``sky.n_images <= data.synthetic.n_images``;
    - ``figures.example < split.n_train`` (the example is a train configuration);
    - ``noise.chunk_size <= noise.runs``; ``baselines.runs`` and each of ``baselines.runs_by_method`` (a
      method of ``baselines.methods``) ``<= noise.runs``; ``floor.runs <= noise.runs``; the shift is finite (YAML's ``.inf`` is a number);
    - ``research.rules.runs <= noise.runs``, no ``paper`` among ``research.rules.names``, finite
      ``research.depth.shifts_c`` (when each part is enabled);
    - the data path for the chosen source is set;
    - every number is finite (:func:`check_finite`), first of all.

    What depends on the data (``sky.n_images`` against the number of real annotated images) is
    checked where the data is known: :func:`check_against_annotations` at parse time for a
    folder, the sample stage otherwise.

    Raises:
        ConfigError: naming the first key that breaks a rule.
    """
    if not isinstance(config, Mapping) or not config:
        raise ConfigError("the configuration is empty: pass a config file (config.yaml) with every section")
    check_finite(config)
    data, sky, split = _section(config, "data"), _section(config, "sky"), _section(config, "split")
    noise, figures = _section(config, "noise"), _section(config, "figures")

    n_selected, n_train, n_dev = (_int(split, "split", k) for k in ("n_selected", "n_train", "n_dev"))
    if n_train + n_dev != n_selected:
        raise ConfigError(
            f"config key 'split.n_selected': must equal split.n_train + split.n_dev "
            f"({n_train} + {n_dev} = {n_train + n_dev}), got {n_selected}"
        )
    n_sky = _int(sky, "sky", "n_images")
    if n_selected > n_sky:
        raise ConfigError(
            f"config key 'split.n_selected': {n_selected} configurations cannot be chosen from "
            f"sky.n_images = {n_sky}"
        )
    example = _int(figures, "figures", "example")
    if example >= n_train:
        raise ConfigError(
            f"config key 'figures.example': the example is an index into the {n_train} train configurations "
            f"(split.n_train), got {example}"
        )
    source = data.get("source")
    if source == "synthetic":
        n_synthetic = _int(_section(data, "synthetic", "data."), "data.synthetic", "n_images")
        if n_sky > n_synthetic:
            raise ConfigError(
                f"config key 'sky.n_images': {n_sky} images cannot be sampled from "
                f"data.synthetic.n_images = {n_synthetic}"
            )
    elif source in ("apollo", "pku"):
        key = "apollo_folder" if source == "apollo" else "pku_csv"
        if not data.get(key):
            raise ConfigError(f"config key 'data.{key}': required when data.source is {source!r}")
    else:
        raise ConfigError(f"config key 'data.source': must be synthetic, apollo or pku, got {source!r}")

    shift = sky.get("shift")
    if not (isinstance(shift, (list, tuple)) and len(shift) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in shift)):
        raise ConfigError(f"config key 'sky.shift': must be two finite numbers [a, b], got {shift!r}")

    runs, chunk = _int(noise, "noise", "runs"), _int(noise, "noise", "chunk_size")
    if chunk > runs:
        raise ConfigError(f"config key 'noise.chunk_size': must not exceed noise.runs = {runs}, got {chunk}")
    for section in ("baselines", "floor"):
        values = config.get(section) or {}
        if values.get("enabled"):
            _check_paired_runs(values, section, runs)
    baselines = config.get("baselines") or {}
    if baselines.get("enabled"):
        for method, count in (baselines.get("runs_by_method") or {}).items():
            if method not in (baselines.get("methods") or []):
                raise ConfigError(f"config key 'baselines.runs_by_method.{method}': {method} is not one of "
                                  f"baselines.methods {baselines.get('methods')}")
            _check_paired_runs(baselines["runs_by_method"], "baselines.runs_by_method", runs, key=method)
    _check_research(config, runs)


def _check_paired_runs(section: Mapping[str, Any], name: str, noise_runs: int, key: str = "runs") -> None:
    """``<name>.<key>`` pairs Table 2's runs 0..runs-1: a count of at most ``noise.runs``."""
    paired = _int(section, name, key)
    if paired > noise_runs:
        raise ConfigError(f"config key '{name}.{key}': the runs are paired with Table 2's, so at most "
                          f"noise.runs = {noise_runs}, got {paired}")


def check_finite(value: Any, key: str = "") -> None:
    """Every number anywhere in ``value`` (mappings and lists included) is finite.

    JSON Schema cannot refuse YAML's ``.nan``: every comparison with NaN is false, so a NaN passes
    ``type: number`` and any ``minimum``/``maximum``; ``.inf`` passes a bound on one side. A NaN
    learning rate would otherwise surface as a missing ``cell_1_nan.json``, a NaN ``train.lr_decay``
    or baseline setting as NaN results. Integers are exact and always finite; ``bool`` is not a number
    here.

    Raises:
        ConfigError: ``config key 'tuning.lr[0]': must be a finite number, got nan`` (the dotted key,
            list positions in brackets).
    """
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"config key '{key}': must be a finite number, got {value!r}")
    if isinstance(value, Mapping):
        for name, item in value.items():
            check_finite(item, _dotted([key, name]) if key else str(name))
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            check_finite(item, _dotted([key, index]))


def _dotted(path) -> str:
    """A key path as the messages name it: ``tuning.lr[0]`` for ``["tuning", "lr", 0]``."""
    return "".join(f"[{part}]" if isinstance(part, int) else f".{part}" for part in path).lstrip(".")


def _rule_names() -> list[str]:
    """The rule names of the schema (``research.rules.names``' enum, held to the library's registry ``sdm.RULES``
    by tests/experiments/test_research.py)."""
    names = _validator(str(SCHEMA_PATH.resolve()))[0]["properties"]["research"]["properties"]["rules"][
        "properties"]["names"]
    return names["items"]["anyOf"][0]["enum"]  # the plain rule names a schedule may combine


def _check_schedule(name: str, key: str) -> None:
    """Both rules of a schedule ``RULE+REFINE:E`` (whose form the schema checks) must be rule names of the schema."""
    known = _rule_names()
    parts = name.split(":")[0].split("+") if "+" in name else []
    unknown = [part for part in parts if part not in known]
    if unknown:
        raise ConfigError(f"config key '{key}': schedule {name!r} names {unknown[0]!r}, not a rule of {known}")


def _check_rule(name: Any, key: str) -> None:
    """``name`` must be a plain rule name of the schema (a key whose library call takes a rule, not a schedule)."""
    known = _rule_names()
    if name not in known:
        raise ConfigError(f"config key '{key}': {name!r} is not a rule name of {known}")


def _at_most(value: Any, bound: int, key: str, what: str) -> None:
    """:class:`ConfigError` naming ``key`` unless ``value`` (an integer, when the schema has typed it) is at most
    ``bound`` (``what`` says which bound)."""
    if isinstance(value, int) and not isinstance(value, bool) and value > bound:
        raise ConfigError(f"config key '{key}': at most {what} ({bound}), got {value}")


def _check_research(config: Mapping[str, Any], noise_runs: int) -> None:
    """The research section: Table 4's runs are paired with Table 2's; Table 5's c* are finite.

    The rule names are the schema's enum (the library's registry ``sdm.RULES``, which this module does not
    import); the paper's own rule is refused here with the reason, and both rules of a schedule
    ``RULE+REFINE:E`` (the schema checks its form) must be of that enum.
    """
    research = config.get("research") or {}
    rules = research.get("rules") or {}
    if rules.get("enabled"):
        if "paper" in (rules.get("names") or []):
            raise ConfigError("config key 'research.rules.names': 'paper' is Table 2 itself, always beside the "
                              "other rules in Table 4; list only the others")
        for index, name in enumerate(rules.get("names") or []):
            _check_schedule(name, f"research.rules.names[{index}]")
        _check_paired_runs(rules, "research.rules", noise_runs)
    depth = research.get("depth") or {}
    if depth.get("enabled"):
        _check_schedule(depth.get("schedule", ""), "research.depth.schedule")
        shifts = depth.get("shifts_c")
        if not (isinstance(shifts, (list, tuple)) and shifts and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in shifts)):
            raise ConfigError(f"config key 'research.depth.shifts_c': must be finite numbers (metres), got {shifts!r}")
        if len({float(v) for v in shifts}) != len(shifts):
            raise ConfigError(f"config key 'research.depth.shifts_c': each c* once, got {shifts!r}")
    objects = research.get("objects") or {}
    if objects.get("enabled"):
        _check_schedule(objects.get("schedule", ""), "research.objects.schedule")
        n_train = int(config["split"]["n_train"])
        if int(objects.get("configurations", 1)) > n_train:
            raise ConfigError(f"config key 'research.objects.configurations': at most split.n_train ({n_train}), "
                              f"got {objects.get('configurations')}")
        if int(objects.get("batch_size", 1)) > int(objects.get("configurations", 1)):
            raise ConfigError(f"config key 'research.objects.batch_size': at most research.objects.configurations "
                              f"({objects.get('configurations')}): a run's batch, got {objects.get('batch_size')}")
        scaling = objects.get("scaling") or {}
        if int(scaling.get("n_images", 16)) < int(objects.get("batch_size", 1)):
            raise ConfigError(f"config key 'research.objects.scaling.n_images': at least research.objects.batch_size "
                              f"({objects.get('batch_size')}), got {scaling.get('n_images')}")
        _at_most((objects.get("silhouette") or {}).get("batch_size"), int(objects.get("configurations", 1)),
                 "research.objects.silhouette.batch_size", "research.objects.configurations, a run's configurations")
        _check_screens(objects)
    network = research.get("network") or {}
    if network.get("enabled"):
        _check_network(network, int(config["sky"]["n_images"]))


def _check_screens(objects: Mapping[str, Any]) -> None:
    """Table 6's screens: each scale once (a scale names its rows and its files), and the scaling on one of them."""
    scales = [screen.get("scale") for screen in objects.get("screens") or [{"scale": 1}]]
    twice = sorted({scale for scale in scales if scales.count(scale) > 1})
    if twice:
        raise ConfigError(f"config key 'research.objects.screens': each scale once (a scale names its rows and its "
                          f"files), got {twice[0]} {scales.count(twice[0])} times in {scales}")
    for index, screen in enumerate(objects.get("screens") or []):
        if "configurations" in screen and int(screen["configurations"]) > int(objects.get("configurations", 1)):
            raise ConfigError(f"config key 'research.objects.screens[{index}].configurations': at most "
                              f"research.objects.configurations ({objects.get('configurations')}), got "
                              f"{screen['configurations']}")
    scale = (objects.get("scaling") or {}).get("scale", 1)
    if scale not in scales:
        raise ConfigError(f"config key 'research.objects.scaling.scale': one of research.objects.screens' scales "
                          f"{scales} (the scaling runs on that screen's disc, rows and cmaes), got {scale!r}")


def _check_network(network: Mapping[str, Any], n_sky: int) -> None:
    """Table 7's sizes against the Sky set, its batches and configurations per epoch against the sizes, its
    refinement's rule against the schema's rule names."""
    sizes = network.get("sizes") or []
    if len(sizes) == 3 and all(isinstance(v, int) and not isinstance(v, bool) for v in sizes):
        if sum(sizes) > n_sky:
            raise ConfigError(f"config key 'research.network.sizes': train + dev + test {sizes} ask for {sum(sizes)} "
                              f"configurations; the Sky set has sky.n_images = {n_sky}")
        train, _, test = sizes
        _at_most((network.get("train") or {}).get("batch_size"), train, "research.network.train.batch_size",
                 "the train configurations, research.network.sizes[0]")
        _at_most((network.get("train") or {}).get("per_epoch"), train, "research.network.train.per_epoch",
                 "the train configurations, research.network.sizes[0]")
        _at_most((network.get("refine") or {}).get("batch_size"), test, "research.network.refine.batch_size",
                 "the test configurations, research.network.sizes[2]")
    train_settings = network.get("train") or {}
    per_epoch, batch = train_settings.get("per_epoch"), train_settings.get("batch_size")
    if isinstance(per_epoch, int) and isinstance(batch, int) and 0 < per_epoch < batch:
        raise ConfigError(f"config key 'research.network.train.per_epoch': 0 (every training configuration) or at "
                          f"least one batch, research.network.train.batch_size ({batch}), got {per_epoch}")
    refine = network.get("refine") or {}
    if "rule" in refine:
        _check_rule(refine["rule"], "research.network.refine.rule")


def check_against_annotations(config: Mapping[str, Any], n_annotated: int, where: str) -> None:
    """``sky.n_images`` must not exceed the number of annotated images found at ``where``."""
    n_sky = int(config["sky"]["n_images"])
    if n_annotated == 0:
        raise ConfigError(f"{where}: no annotation files found (config key 'data.{_path_key(config)}')")
    if n_sky > n_annotated:
        raise ConfigError(
            f"config key 'sky.n_images': {n_sky} images cannot be sampled from the {n_annotated} annotated "
            f"images of {where}"
        )


def _path_key(config: Mapping) -> str:
    return "apollo_folder" if config["data"]["source"] == "apollo" else "pku_csv"


def _section(config: Mapping, name: str, prefix: str = "") -> Mapping:
    value = config.get(name) if isinstance(config, Mapping) else None
    if not isinstance(value, Mapping):
        raise ConfigError(f"config key '{prefix}{name}': missing or not a mapping")
    return value


def _int(section: Mapping, prefix: str, key: str) -> int:
    value = section.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"config key '{prefix}.{key}': must be an integer, got {value!r}")
    return value
