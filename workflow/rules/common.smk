# Shared helpers: paths derived from the config, what a stage depends on without reading it (its code,
# the annotation files), and what the stages' jobs range over (the tuning grid, the noise chunks, Table 3's
# methods, Tables 4-5's rules and c*); the rule every stage is made with is notebook_stage, in stage.smk.
# Nothing here imports torch or sdm: parsing the workflow stays fast and works without them. Nothing
# here writes a file either: a dry run or --lint works on a read-only results folder.
import hashlib
import json
import re
from pathlib import Path

from code_deps import CodeDepsError, fingerprint

# Every output lives under the results root (config key results_dir, "results" by default), so that
# runs on different data never overwrite each other. The jobs' logs and Snakemake's benchmark files go
# there too (<root>/logs/, <root>/benchmarks/): the project's benchmarks/ folder holds source only.
RESULTS = config["results_dir"].rstrip("/")
LOGS, BENCHMARKS = f"{RESULTS}/logs", f"{RESULTS}/benchmarks"

# The Sky dataset file written by sdm.experiments.data.write_sky_file.
SKY_FILE = f"{RESULTS}/sky/sky.bin"
SPLIT_FILE = f"{RESULTS}/split/split.json"
BEST_FILE = f"{RESULTS}/tuning/best.json"


def result(path):
    """A path under the results root."""
    return f"{RESULTS}/{path}"


def figure(name, caption):
    """A figure under results/figures/, flagged for `snakemake --report` with its caption."""
    return report(result(f"figures/{name}.png"), caption=f"../report/{caption}.rst", category="Figures")


def table_files(name):
    """A table's files under results/tables/ as named outputs: the CSV, the Markdown, the LaTeX and the HTML
    page (flagged for `snakemake --report` with its caption, workflow/report/<name>.rst: the report shows
    a page, and offers a CSV as a download only)."""
    return {
        f"{name}_csv": result(f"tables/{name}.csv"),
        f"{name}_md": result(f"tables/{name}.md"),
        f"{name}_tex": result(f"tables/{name}.tex"),
        f"{name}_html": report(result(f"tables/{name}.html"), caption=f"../report/{name}.rst", category="Tables"),
    }


# -- what a stage depends on without reading it ---------------------------------------------------------


def stage_code(notebook):
    """The fingerprint of the code a stage running notebooks/<notebook>.py runs: the notebook, the library
    modules it imports (directly or through others) and the runner (workflow/scripts/code_deps.py)."""
    try:
        return fingerprint(notebook)
    except CodeDepsError as error:  # one line naming the file, no traceback
        raise WorkflowError(error) from None


def annotation_files(folder):
    """Names, sizes and SHA-256 of every file an ApolloCar3D folder's reader uses: the number of annotation
    files and one SHA-256 over that list.

    The digest goes into the params of the stages that read the folder, so that adding, removing or editing
    a file reruns them (Snakemake sees only a folder's own timestamp); nothing is written.
    """
    root = Path(folder)
    if not (root / "car_poses").is_dir():
        raise WorkflowError(
            f"config key 'data.apollo_folder': {root} has no car_poses/ folder (expected car_poses/*.json "
            f"and camera/Camera_5.txt)"
        )
    files = sorted(root.glob("car_poses/*.json")) + sorted(root.glob("camera/*.txt"))
    entries = {}
    for path in files:
        content = path.read_bytes()
        entries[path.relative_to(root).as_posix()] = [len(content), hashlib.sha256(content).hexdigest()]
    listing = json.dumps({"files": entries}, indent=1, sort_keys=True) + "\n"
    count = sum(1 for name in entries if name.startswith("car_poses/"))
    return count, hashlib.sha256(listing.encode()).hexdigest()


def annotation_inputs():
    """The annotation-reading stages' inputs: the generated folder or the PKU csv (read as ``annotations``);
    none for an ApolloCar3D folder (a param: the stage reads the folder itself, tracked by annotation_tracked).
    """
    source = config["data"]["source"]
    if source == "synthetic":
        return {"annotations": result("data/synthetic_apollo")}
    if source == "apollo":
        return {}
    return {"annotations": config["data"]["pku_csv"]}


def annotation_params():
    """The source's kind, and the ApolloCar3D folder as a plain param (a different folder reruns the stages)."""
    if config["data"]["source"] == "apollo":
        return {"source_kind": "apollo", "annotations": config["data"]["apollo_folder"]}
    return {"source_kind": config["data"]["source"]}


def annotation_keys():
    """The config key of the data path the current source reads (none for synthetic data)."""
    return {"synthetic": [], "apollo": ["data.apollo_folder"], "pku": ["data.pku_csv"]}[config["data"]["source"]]


ANNOTATION_FILES = None  # (number of annotation files, SHA-256 of their listing) of an ApolloCar3D folder
if config["data"]["source"] == "apollo":
    try:
        folder = config["data"]["apollo_folder"]
        ANNOTATION_FILES = annotation_files(folder)
        check_against_annotations(config, ANNOTATION_FILES[0], folder)
    except ConfigError as error:  # one line naming the key, no traceback
        raise WorkflowError(error) from None


def annotation_tracked():
    """What the annotation-reading stages track without reading it: an ApolloCar3D folder's file listing."""
    return {"annotations": ANNOTATION_FILES[1]} if ANNOTATION_FILES else {}


# -- the jobs of each stage ---------------------------------------------------------------------------


def lr_label(lr):
    """A learning rate as it appears in file names: ``3e-04`` (only a label: the value comes from the config)."""
    return f"{float(lr):.0e}" if float(f"{float(lr):.0e}") == float(lr) else repr(float(lr))


def c_label(c):
    """A depth shift c* as it appears in file names: ``-1.0`` (only a label: the value comes from the config)."""
    return repr(float(c))


# Table 1: (n_epoch, lr label) -> the cell's values, in config order (epochs outer).
TUNING_CELLS = {
    (str(n_epoch), lr_label(lr)): {"n_epoch": int(n_epoch), "lr": float(lr)}
    for n_epoch in config["tuning"]["n_epoch"]
    for lr in config["tuning"]["lr"]
}
# Table 2: noise.runs runs per level in chunks of noise.chunk_size, one job per (level, chunk).
N_RUNS, CHUNK_SIZE = int(config["noise"]["runs"]), int(config["noise"]["chunk_size"])
NOISE_LEVELS = [int(level) for level in config["noise"]["levels"]]

# Table 3: the baselines beside SDM (config section baselines), each with its settings grid. Per
# baseline one tuning job, then one job per noise level (its paired runs 0..baselines.runs-1). SDM is
# not rerun: its rows are Table 2's runs, its time per run the noise jobs' own (their timing_file).
# A method's settings are passed in name order: the order of keys in a YAML mapping means nothing, and
# Snakemake compares params as written, so a reordered (or re-dumped) config must not rerun the tuning.
BASELINES = {
    name: dict(sorted(config["baselines"].get(name, {}).items()))
    for name in (config["baselines"]["methods"] if config["baselines"]["enabled"] else [])
}
BASELINE_RUNS = int(config["baselines"]["runs"])  # a count: the stages run 0..BASELINE_RUNS-1
# Per method: its own count where baselines.runs_by_method gives one (Table 3 pairs each with SDM's runs).
METHOD_RUNS = {name: int(config["baselines"].get("runs_by_method", {}).get(name, BASELINE_RUNS)) for name in BASELINES}
# The floor of Tables 3 and 4 (config section floor): one job per noise level, runs 0..FLOOR_RUNS-1.
FLOOR = config.get("floor", {"enabled": False})
FLOOR_RUNS = int(FLOOR.get("runs", 1))
FLOOR_SETTINGS = dict(sorted(FLOOR.get("settings", {}).items()))  # name order, as BASELINES'

# Beyond the paper (config section research). Table 4: the rules beside the paper's, each run at every
# noise level with Table 2's runs 0..runs-1. Table 5: c* label -> its value, in config order.
RESEARCH = config.get("research", {})
RESEARCH_RULES = RESEARCH.get("rules", {"enabled": False})
RESEARCH_DEPTH = RESEARCH.get("depth", {"enabled": False})
RULE_NAMES = list(RESEARCH_RULES["names"]) if RESEARCH_RULES["enabled"] else []
# A schedule's name in file names: "closed_centred_r1+group_crossing:4" -> "closed_centred_r1_then_group_crossing_x4"
# (only a label: the notebook gets the name itself).
RULE_LABELS = {name.replace("+", "_then_").replace(":", "_x"): name for name in RULE_NAMES}
RULE_RUNS = int(RESEARCH_RULES.get("runs", 1))  # counts, as BASELINE_RUNS
DEPTH_SHIFTS = {c_label(c): float(c) for c in RESEARCH_DEPTH["shifts_c"]} if RESEARCH_DEPTH["enabled"] else {}
DEPTH_NOISE_LEVELS = [int(level) for level in RESEARCH_DEPTH.get("noise_levels", [])]
DEPTH_RUNS = int(RESEARCH_DEPTH.get("runs", 1))


# Every stage's jobs, as their wildcards (filled in by notebook_stage, in include order): a stage without
# wildcards has the one job {}, a stage switched off none.
JOBS = {}


def each(stage, output):
    """The files of a named output of `stage`, one per job of JOBS[stage] (its wildcards filled in), in order."""
    patterns = getattr(rules, stage).output[output]
    patterns = [patterns] if isinstance(patterns, str) else patterns  # a named output may hold a list
    return [str(pattern).format(**wildcards) for wildcards in JOBS[stage] for pattern in patterns]


def one_of(values):
    """A wildcard constraint matching exactly the given labels ("(?!)", matching nothing, when none)."""
    return "|".join(re.escape(str(value)) for value in values) or "(?!)"


def tuning_value(key):
    """A params function: the tuning cell's n_epoch or lr, looked up from the wildcards (never parsed back)."""
    return lambda wildcards: TUNING_CELLS[(wildcards.n_epoch, wildcards.lr)][key]


def wildcard(name, convert=str):
    """A params function: the job's wildcard `name`, converted (a value the file name carries itself)."""
    return lambda wildcards: convert(wildcards[name])


def chunk_runs():
    """The params first_run and runs of a noise chunk: chunk k holds runs k*chunk_size .. (k+1)*chunk_size - 1
    (a first index and a count rather than the list, which the notebook's parameter cell would show one a line)."""

    def first(wildcards):
        return int(wildcards.chunk) * CHUNK_SIZE

    return dict(first_run=first, runs=lambda wildcards: min(CHUNK_SIZE, N_RUNS - first(wildcards)))


def training(seed):
    """The training settings every training stage reads (train.s, batch_size, lr_decay, sky.shift), and its seed."""
    train = config["train"]
    return dict(
        s=train["s"],
        batch_size=train["batch_size"],
        lr_decay=train["lr_decay"],
        seed=seed,
        shift=config["sky"]["shift"],
    )


def extra_tables_read_by_report():
    """What the report reads of Tables 3-5: each enabled table's Markdown and summary, and the CSVs of
    Tables 3 and 4 (the verdict's best method and recommended schedule)."""
    enabled = [stage for stage in ("table3", "table4", "table5") if JOBS[stage]]
    files = {key: result(f"tables/{key}.md") for stage in enabled for key in (stage, f"{stage}_summary")}
    return files | {f"{stage}_csv": result(f"tables/{stage}.csv") for stage in enabled if stage != "table5"}


def config_values(*keys):
    """The named config values (dotted keys) as a nested dict: the part of the config a stage reads."""
    picked = {}
    for key in keys:
        *parents, last = key.split(".")
        source, target = config, picked
        for part in parents:
            source, target = source[part], target.setdefault(part, {})
        if last in source:
            target[last] = source[last]
    return picked
