"""One workflow stage, run by Snakemake's ``script:`` directive (the rule ``notebook_stage`` makes).

The notebook, ``params.stage["notebook"]`` (relative to the project root: the
project can move), gets as papermill parameters the rule's named inputs, named
outputs (but ``html``), params (but ``stage``, what the stage depends on without
reading it: its notebook and the fingerprint of its code) and ``threads``.
The job's threads cap torch/OpenMP; the project's ``src/`` goes on the kernel's
PYTHONPATH so that a conda environment works without installing ``sdm``. The
tools' own messages go to ``log.stderr``; on failure, the first line Snakemake
shows is the cause (see :func:`run_notebook.main`).
"""
import os
import sys
from pathlib import Path

smk = snakemake  # noqa: F821 -- injected by Snakemake's script directive

sys.path.insert(0, str(Path(smk.scriptdir)))
from run_notebook import main  # noqa: E402


def _named(items, skip):
    return {key: (str(value) if isinstance(value, str) else [str(v) for v in value])
            for key, value in items.items() if key not in skip}


parameters = _named(smk.input, set()) | _named(smk.output, {"html"})
parameters |= {key: value for key, value in smk.params.items() if key != "stage"}
parameters["threads"] = smk.threads

project = Path(smk.scriptdir).resolve().parents[1]  # scriptdir is workflow/rules/../scripts: resolve the ..
notebook = project / smk.params.stage["notebook"]
# Shown in messages relative to where Snakemake runs when the project is there (notebooks/sample.py).
source = os.path.relpath(notebook) if not os.path.relpath(notebook).startswith("..") else str(notebook)
src = str(project / "src")
threads = str(smk.threads)
os.environ.update(OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads,
                  PYTHONPATH=os.pathsep.join(filter(None, [src, os.environ.get("PYTHONPATH")])))
os.environ.pop("MPLBACKEND", None)  # the kernel's inline backend puts every plot in the rendered notebook

# The stage's name and the fingerprint of the code it runs, kept in the executed notebook (a snapshot's provenance).
stage = {"name": smk.rule, "code": smk.params.stage["code"]}
sys.exit(main(source, smk.log.notebook, smk.output.html, parameters, stderr_log=smk.log.stderr, stage=stage))
