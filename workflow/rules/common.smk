# Shared helpers: file names derived from the config, and how a notebook stage runs.
import json
import sys
from pathlib import Path

from snakemake.settings.types import DeploymentMethod

from sdm.config import chunk_runs, noise_chunks, tuning_cells

NOTEBOOKS = Path(workflow.basedir) / "notebooks"
SRC = Path(workflow.basedir) / "src"

# Jobs find jupytext, papermill and jupyter in the Python environment Snakemake runs in (even when
# that environment is not activated); with --software-deployment-method conda, in the rule's env.
if DeploymentMethod.CONDA in workflow.deployment_settings.deployment_method:
    TOOLS = "${CONDA_PREFIX:-}/bin"  # expanded by the job's shell, inside the activated env
else:
    TOOLS = str(Path(sys.executable).parent)

# The Sky dataset file written by sdm.data.write_sky_file.
SKY_FILE = "results/sky/sky.bin"


def notebook(stage):
    """The jupytext source of a stage."""
    return str(NOTEBOOKS / f"{stage}.py")


def notebook_log(name):
    """A stage's logs: the executed notebook (kept when the stage fails) and the tools' stderr."""
    return {"notebook": f"results/notebooks/{name}.ipynb", "stderr": f"logs/{name}.log"}


def html(name):
    """The HTML rendering of a stage's executed notebook."""
    return f"results/notebooks/{name}.html"


def annotations():
    """The annotation source the data stage reads: a folder (synthetic, apollo) or the PKU csv."""
    source = config["data"]["source"]
    if source == "synthetic":
        return "results/data/synthetic_apollo"
    if source == "apollo":
        return config["data"]["apollo_folder"]
    return config["data"]["pku_csv"]


def tuning_files(kind):
    """Per-cell outputs of the tuning grid: kind is 'cell' (json) or 'history' (csv)."""
    ext = "json" if kind == "cell" else "csv"
    return [f"results/tuning/{kind}_{n}_{lr}.{ext}" for n, lr in tuning_cells(config)]


def noise_files():
    """The chunk files of the noise runs, one per (level, chunk) job."""
    return [f"results/noise/level{level}_chunk{chunk}.csv" for level, chunk in noise_chunks(config)]


def notebook_html():
    """Every rendered notebook of the run."""
    names = ["data", "sample", "sky", "split", "best", "tables", "figures", "report"]
    if config["data"]["source"] == "synthetic":
        names.insert(0, "synthetic")
    names += [f"tune_{n}_{lr}" for n, lr in tuning_cells(config)]
    names += [f"noise_level{level}_chunk{chunk}" for level, chunk in noise_chunks(config)]
    return [html(name) for name in names]


def parameters(**extra):
    """A params function: the notebook's papermill parameters as JSON.

    Every named input (but the notebook itself) and output becomes a parameter of the
    same name, plus ``threads`` and the given extra values (callables get the wildcards).
    """

    def build(wildcards, input, output, threads):
        values = {key: _path(path) for key, path in input.items() if key != "source"}
        values.update({key: _path(path) for key, path in output.items() if key != "html"})
        values["threads"] = threads
        for key, value in extra.items():
            values[key] = value(wildcards) if callable(value) else value
        return json.dumps(values)

    return build


def _path(value):
    """A named input or output: one path, or a list of paths."""
    return str(value) if isinstance(value, str) else [str(path) for path in value]


# A stage: jupytext source -> papermill (executed notebook = the rule's log, kept on failure)
# -> HTML, in one process (workflow/scripts/run_notebook.py). One thread per job; the job puts
# src/ on PYTHONPATH so that a conda env works too.
RUNNER = str(Path(workflow.basedir) / "workflow" / "scripts" / "run_notebook.py")

NOTEBOOK_SHELL = (
    "export OMP_NUM_THREADS={threads} MKL_NUM_THREADS={threads} MPLBACKEND=Agg "
    "PYTHONPATH={params.src}${{PYTHONPATH:+:$PYTHONPATH}} PATH={params.tools}${{PATH:+:$PATH}}; "
    "python {params.runner:q} {input.source:q} {log.notebook:q} {output.html:q} {params.nb:q} "
    "> {log.stderr:q} 2>&1"
)
