"""The workflow's configuration (``config.yaml``): loading and checks.

``workflow/schemas/config.schema.yaml`` types every key and bounds each value;
:func:`check_config` adds the rules that tie keys together and that JSON
Schema cannot state. Every error is an :class:`~sdm.errors.SDMInputError`
whose message starts with the dotted key it is about, e.g.
``config key 'split.n_train': ...``.

The Snakefile runs Snakemake's own schema validation and then
:func:`check_config`; :func:`load_config` does both for use outside Snakemake
(tests, notebooks, a Python session).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import yaml

from .camera import APOLLO_CAMERA_5, Camera
from .errors import SDMInputError

#: The schema next to the workflow, relative to the project root.
SCHEMA_PATH = Path("workflow/schemas/config.schema.yaml")


def load_config(path: str | Path, schema: str | Path = SCHEMA_PATH) -> dict:
    """Read a YAML config, validate it against ``schema`` and :func:`check_config` it.

    Args:
        path: the YAML file.
        schema: JSON-Schema file in YAML (default: the workflow's, relative to the project root);
            needs the ``jsonschema`` package (installed with the ``workflow`` extra).

    Returns:
        The configuration as a plain dict.
    """
    path = Path(path)
    if not path.is_file():
        raise SDMInputError(f"{path}: config file not found")
    try:
        config = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise SDMInputError(f"{path}: not valid YAML: {error}") from None
    if not isinstance(config, dict):
        raise SDMInputError(f"{path}: the config must be a mapping of keys to values")
    validate_schema(config, schema)
    check_config(config)
    return config


def validate_schema(config: Mapping, schema: str | Path) -> None:
    """Validate ``config`` against a JSON Schema written in YAML; the error names the key."""
    import jsonschema  # installed with the workflow extra (Snakemake depends on it)

    schema_data = yaml.safe_load(Path(schema).read_text())
    validator = jsonschema.Draft202012Validator(schema_data)
    errors = sorted(validator.iter_errors(config), key=lambda e: list(e.absolute_path))
    if errors:
        error = errors[0]
        key = ".".join(str(part) for part in error.absolute_path) or "<top level>"
        raise SDMInputError(f"config key '{key}': {error.message}")


def check_config(config: Mapping[str, Any], camera: Camera = APOLLO_CAMERA_5) -> None:
    """Check the rules that tie config keys together (the schema checks each key on its own).

    - ``split.n_train + split.n_dev == split.n_selected <= sky.n_images``;
    - with synthetic data, ``sky.n_images <= data.synthetic.n_images``;
    - ``2**train.s`` divides both screen sides (128 and 256);
    - ``noise.chunk_size <= noise.runs``; the shift is finite (YAML's ``.inf`` is a number);
    - the data path for the chosen source is set.

    Raises:
        SDMInputError: naming the first key that breaks a rule.
    """
    data, sky, split = _section(config, "data"), _section(config, "sky"), _section(config, "split")
    train, noise = _section(config, "train"), _section(config, "noise")

    n_selected, n_train, n_dev = (_int(split, "split", k) for k in ("n_selected", "n_train", "n_dev"))
    if n_train + n_dev != n_selected:
        raise SDMInputError(
            f"config key 'split.n_selected': must equal split.n_train + split.n_dev "
            f"({n_train} + {n_dev} = {n_train + n_dev}), got {n_selected}"
        )
    n_sky = _int(sky, "sky", "n_images")
    if n_selected > n_sky:
        raise SDMInputError(
            f"config key 'split.n_selected': {n_selected} configurations cannot be chosen from "
            f"sky.n_images = {n_sky}"
        )
    source = data.get("source")
    if source == "synthetic":
        n_synthetic = _int(_section(data, "synthetic", "data."), "data.synthetic", "n_images")
        if n_sky > n_synthetic:
            raise SDMInputError(
                f"config key 'sky.n_images': {n_sky} images cannot be sampled from "
                f"data.synthetic.n_images = {n_synthetic}"
            )
    elif source in ("apollo", "pku"):
        key = "apollo_folder" if source == "apollo" else "pku_csv"
        if not data.get(key):
            raise SDMInputError(f"config key 'data.{key}': required when data.source is {source!r}")
    else:
        raise SDMInputError(f"config key 'data.source': must be synthetic, apollo or pku, got {source!r}")

    shift = sky.get("shift")
    if not (isinstance(shift, (list, tuple)) and len(shift) == 2
            and all(isinstance(v, (int, float)) and math.isfinite(v) for v in shift)):
        raise SDMInputError(f"config key 'sky.shift': must be two finite numbers [a, b], got {shift!r}")

    s = _int(train, "train", "s")
    if s < 0 or camera.screen_height % 2**s or camera.screen_width % 2**s:
        raise SDMInputError(
            f"config key 'train.s': 2^s must divide the {camera.screen_height} x {camera.screen_width} screen, got s = {s}"
        )
    runs, chunk = _int(noise, "noise", "runs"), _int(noise, "noise", "chunk_size")
    if chunk > runs:
        raise SDMInputError(f"config key 'noise.chunk_size': must not exceed noise.runs = {runs}, got {chunk}")


# -- what the workflow derives from the config ------------------------------------------------------

def lr_label(lr: float) -> str:
    """A learning rate as it appears in file names: ``3e-04``."""
    return f"{float(lr):.0e}" if float(f"{float(lr):.0e}") == float(lr) else repr(float(lr))


def tuning_cells(config: Mapping) -> list[tuple[int, str]]:
    """The tuning grid as ``(n_epoch, lr label)`` pairs, in config order (epochs outer)."""
    tuning = config["tuning"]
    return [(int(n), lr_label(lr)) for n in tuning["n_epoch"] for lr in tuning["lr"]]


def noise_chunks(config: Mapping) -> list[tuple[int, int]]:
    """The noise jobs as ``(level, chunk)`` pairs; chunk ``k`` holds runs ``k*size .. (k+1)*size - 1``."""
    noise = config["noise"]
    n_chunks = math.ceil(int(noise["runs"]) / int(noise["chunk_size"]))
    return [(int(level), k) for level in noise["levels"] for k in range(n_chunks)]


def chunk_runs(config: Mapping, chunk: int) -> list[int]:
    """Run indices of noise chunk ``chunk``."""
    runs, size = int(config["noise"]["runs"]), int(config["noise"]["chunk_size"])
    return list(range(chunk * size, min((chunk + 1) * size, runs)))


def _section(config: Mapping, name: str, prefix: str = "") -> Mapping:
    value = config.get(name) if isinstance(config, Mapping) else None
    if not isinstance(value, Mapping):
        raise SDMInputError(f"config key '{prefix}{name}': missing or not a mapping")
    return value


def _int(section: Mapping, prefix: str, key: str) -> int:
    value = section.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise SDMInputError(f"config key '{prefix}.{key}': must be an integer, got {value!r}")
    return value
