# Shared helpers: paths derived from the config, the annotation manifest, the tuning grid, the noise
# chunks and Table 3's methods (the notebook-stage template is in stage.smk).
# Nothing here imports torch or sdm: parsing the workflow stays fast and works without them.
import hashlib
import json
import os
from pathlib import Path

NOTEBOOKS = Path(workflow.basedir) / "notebooks"

# Every output lives under the results root (config key results_dir, "results" by default), so that
# runs on different data never overwrite each other. Logs and benchmarks of the default run stay in
# logs/ and benchmarks/; another results root gets its own beside its results.
RESULTS = config["results_dir"].rstrip("/")
if RESULTS == "results":
    LOGS, BENCHMARKS = "logs", "benchmarks"
else:
    LOGS, BENCHMARKS = f"{RESULTS}/logs", f"{RESULTS}/benchmarks"

# The Sky dataset file written by sdm.data.write_sky_file.
SKY_FILE = f"{RESULTS}/sky/sky.bin"
SPLIT_FILE = f"{RESULTS}/split/split.json"
BEST_FILE = f"{RESULTS}/tuning/best.json"


def result(path):
    """A path under the results root."""
    return f"{RESULTS}/{path}"


def notebook(stage):
    """The jupytext source of a stage."""
    return str(NOTEBOOKS / f"{stage}.py")


def notebook_log(name):
    """A stage's logs: the executed notebook (kept when the stage fails) and the tools' messages."""
    return {
        "notebook": result(f"notebooks/{name}.ipynb"),
        "stderr": f"{LOGS}/{name}.log",
    }


def html(name):
    """The HTML rendering of a stage's executed notebook."""
    return result(f"notebooks/{name}.html")


def figure(name, caption, category="Figures"):
    """A figure under results/figures/, flagged for `snakemake --report` with its caption."""
    return report(
        result(f"figures/{name}.png"),
        caption=f"../report/{caption}.rst",
        category=category,
    )


def table(name, caption):
    """A table's CSV under results/tables/, flagged for `snakemake --report` with its caption."""
    return report(
        result(f"tables/{name}.csv"),
        caption=f"../report/{caption}.rst",
        category="Tables",
    )


def benchmark_file(name):
    """Wall time and memory of a job (Snakemake's benchmark TSV)."""
    return f"{BENCHMARKS}/{name}.tsv"


# -- the annotations -----------------------------------------------------------------------------------

ANNOTATION_MANIFEST = result("data/annotations.manifest.json")


def annotation_manifest(folder):
    """Names, sizes and SHA-256 of every file an ApolloCar3D folder's reader uses.

    Written to ANNOTATION_MANIFEST at parse time, and only when it differs from what is there, so
    that its timestamp changes exactly when a file is added, removed or edited: the data stage
    takes it as an input and reruns then (Snakemake sees only a folder's own timestamp).
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
        entries[path.relative_to(root).as_posix()] = [
            len(content),
            hashlib.sha256(content).hexdigest(),
        ]
    text = json.dumps({"files": entries}, indent=1, sort_keys=True) + "\n"
    target = Path(ANNOTATION_MANIFEST)
    if not target.is_file() or target.read_text() != text:
        target.parent.mkdir(parents=True, exist_ok=True)
        temporary = target.with_name(f".{target.name}.{os.getpid()}")
        temporary.write_text(text)
        os.replace(temporary, target)
    return sum(1 for name in entries if name.startswith("car_poses/"))


def annotation_inputs():
    """The annotation-reading stages' inputs: the generated folder or the PKU csv (read as ``annotations``),
    or, for an ApolloCar3D folder, its manifest (``tracked``: the stage reads the folder itself).
    """
    source = config["data"]["source"]
    if source == "synthetic":
        return {"annotations": result("data/synthetic_apollo")}
    if source == "apollo":
        return {"tracked": ANNOTATION_MANIFEST}
    return {"annotations": config["data"]["pku_csv"]}


def annotation_params():
    """The ApolloCar3D folder as a plain param (a different folder reruns the stages); none otherwise."""
    if config["data"]["source"] == "apollo":
        return {"annotations": config["data"]["apollo_folder"]}
    return {}


def annotation_keys():
    """The config key of the data path the current source reads (none for synthetic data)."""
    return {"synthetic": [], "apollo": ["data.apollo_folder"], "pku": ["data.pku_csv"]}[
        config["data"]["source"]
    ]


if config["data"]["source"] == "apollo":
    try:
        check_against_annotations(
            config,
            annotation_manifest(config["data"]["apollo_folder"]),
            config["data"]["apollo_folder"],
        )
    except ConfigError as error:  # one line naming the key, no traceback
        raise WorkflowError(error) from None


# -- the tuning grid and the noise chunks --------------------------------------------------------------


def lr_label(lr):
    """A learning rate as it appears in file names: ``3e-04`` (only a label: the value comes from the config)."""
    return (
        f"{float(lr):.0e}"
        if float(f"{float(lr):.0e}") == float(lr)
        else repr(float(lr))
    )


# (n_epoch, lr label) -> the cell's values, in config order (epochs outer).
TUNING_CELLS = {
    (str(n_epoch), lr_label(lr)): {"n_epoch": int(n_epoch), "lr": float(lr)}
    for n_epoch in config["tuning"]["n_epoch"]
    for lr in config["tuning"]["lr"]
}


def tuning_value(key):
    """A params function: the tuning cell's n_epoch or lr, looked up from the wildcards (never parsed back)."""
    return lambda wildcards: TUNING_CELLS[(wildcards.n_epoch, wildcards.lr)][key]


def tuning_files(kind):
    """Per-cell outputs of the tuning grid: kind is 'cell' (json) or 'history' (csv)."""
    ext = "json" if kind == "cell" else "csv"
    return [result(f"tuning/{kind}_{n}_{lr}.{ext}") for n, lr in TUNING_CELLS]


N_RUNS, CHUNK_SIZE = int(config["noise"]["runs"]), int(config["noise"]["chunk_size"])
NOISE_CHUNKS = [
    (int(level), chunk)
    for level in config["noise"]["levels"]
    for chunk in range(-(-N_RUNS // CHUNK_SIZE))
]


def chunk_runs(wildcards):
    """Run indices of a noise chunk: chunk k holds runs k*chunk_size .. (k+1)*chunk_size - 1."""
    chunk = int(wildcards.chunk)
    return list(range(chunk * CHUNK_SIZE, min((chunk + 1) * CHUNK_SIZE, N_RUNS)))


def noise_files():
    """The chunk files of the noise runs, one per (level, chunk) job."""
    return [
        result(f"noise/level{level}_chunk{chunk}.csv") for level, chunk in NOISE_CHUNKS
    ]


def noise_timing_files():
    """The noise jobs' timings (wall seconds of their runs; SDM's time per run in Table 3)."""
    return [
        result(f"noise/level{level}_chunk{chunk}_seconds.json")
        for level, chunk in NOISE_CHUNKS
    ]


# Table 3: the baselines beside SDM (config section baselines), each with its settings grid. Per
# baseline one tuning job, then one job per noise level (its paired runs 0..baselines.runs-1). SDM is
# not rerun: its rows are Table 2's runs, its time per run the noise stage's own (noise_timing_files).
# A method's settings are passed in name order: the order of keys in a YAML mapping means nothing, and
# Snakemake compares params as written, so a reordered (or re-dumped) config must not rerun the tuning.
BASELINES = (
    {
        name: dict(sorted(config["baselines"].get(name, {}).items()))
        for name in config["baselines"]["methods"]
    }
    if config["baselines"]["enabled"]
    else {}
)
BASELINE_RUNS = list(range(int(config["baselines"]["runs"])))
BASELINE_PATTERN = "|".join(BASELINES) or "(?!)"  # "(?!)" matches nothing
BASELINE_LEVELS = [int(level) for level in config["noise"]["levels"]]


def table3_report_inputs():
    """What the report reads of Table 3 (nothing when the baselines are off)."""
    if not config["baselines"]["enabled"]:
        return {}
    return {
        "table3": result("tables/table3.md"),
        "table3_summary": result("tables/table3_summary.md"),
    }


def baseline_tuning_files():
    """One tuning CSV per baseline (its grid on the dev set)."""
    return [result(f"baselines/tuning_{name}.csv") for name in BASELINES]


def baseline_run_files():
    """One runs CSV per (baseline, noise level)."""
    return [
        result(f"baselines/runs_{name}_level{level}.csv")
        for name in BASELINES
        for level in BASELINE_LEVELS
    ]


def baseline_html():
    """The rendered notebooks of the baseline jobs and of Table 3."""
    return [
        *(f"baselines_tune_{name}" for name in BASELINES),
        *(
            f"baselines_{name}_level{level}"
            for name in BASELINES
            for level in BASELINE_LEVELS
        ),
        "table3",
    ]


def table3_outputs():
    """Table 3's files when the baselines are on, else nothing."""
    return rules.table3.output if config["baselines"]["enabled"] else []


def notebook_html():
    """Every rendered notebook of the run."""
    names = ["data", "sample", "sky", "split", "best", "tables", "figures", "report"]
    if config["data"]["source"] == "synthetic":
        names.insert(0, "synthetic")
    names += [f"tune_{n}_{lr}" for n, lr in TUNING_CELLS]
    names += [f"noise_level{level}_chunk{chunk}" for level, chunk in NOISE_CHUNKS]
    if config["baselines"]["enabled"]:
        names += baseline_html()
    return [html(name) for name in names]


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


# -- beyond the paper (config section research): Table 4 (rules) and Table 5 (depth) -----------------------

RESEARCH = config.get("research", {})
RESEARCH_RULES = RESEARCH.get("rules", {"enabled": False})
RESEARCH_DEPTH = RESEARCH.get("depth", {"enabled": False})
# Table 4: the rules beside the paper's, each run at every noise level with Table 2's runs 0..runs-1.
RULE_NAMES = list(RESEARCH_RULES["names"]) if RESEARCH_RULES["enabled"] else []
RULE_PATTERN = "|".join(RULE_NAMES) or "(?!)"  # "(?!)" matches nothing
RULE_RUNS = list(range(int(RESEARCH_RULES.get("runs", 1))))


def c_label(c):
    """A depth shift c* as it appears in file names: ``-1.0`` (only a label: the value comes from the config)."""
    return repr(float(c))


# Table 5: c* label -> its value, in config order.
DEPTH_SHIFTS = (
    {c_label(c): float(c) for c in RESEARCH_DEPTH["shifts_c"]}
    if RESEARCH_DEPTH["enabled"]
    else {}
)
DEPTH_PATTERN = "|".join(label.replace(".", r"\.") for label in DEPTH_SHIFTS) or "(?!)"
DEPTH_LEVELS = [int(level) for level in RESEARCH_DEPTH.get("levels", [])]
DEPTH_RUNS = list(range(int(RESEARCH_DEPTH.get("runs", 1))))


def depth_shift(wildcards):
    """A params function: the c* of a depth job, looked up from its label (never parsed back)."""
    return DEPTH_SHIFTS[wildcards.c]


def rule_files():
    """Table 4's run files, one per (rule, noise level) job."""
    return [
        result(f"research/rules/{name}_level{level}.csv")
        for name in RULE_NAMES
        for level in config["noise"]["levels"]
    ]


def depth_files():
    """Table 5's run files, one per (c*, noise level) job."""
    return [
        result(f"research/depth/c{label}_level{level}.csv")
        for label in DEPTH_SHIFTS
        for level in DEPTH_LEVELS
    ]


def research_report_inputs():
    """What the report reads of Tables 4 and 5 (only the enabled ones)."""
    inputs = {}
    if RESEARCH_RULES["enabled"]:
        inputs |= {
            "table4": result("tables/table4.md"),
            "table4_summary": result("tables/table4_summary.md"),
        }
    if RESEARCH_DEPTH["enabled"]:
        inputs |= {
            "table5": result("tables/table5.md"),
            "table5_summary": result("tables/table5_summary.md"),
        }
    return inputs


def research_outputs():
    """Tables 4 and 5 with their figures and every rendered research notebook (only the enabled parts)."""
    outputs = []
    if RESEARCH_RULES["enabled"]:
        outputs += list(rules.table4.output)
        outputs += [
            html(f"research_rules_{name}_level{level}")
            for name in RULE_NAMES
            for level in config["noise"]["levels"]
        ]
    if RESEARCH_DEPTH["enabled"]:
        outputs += list(rules.table5.output)
        outputs += [
            html(f"research_depth_c{label}_level{level}")
            for label in DEPTH_SHIFTS
            for level in DEPTH_LEVELS
        ]
    return outputs
