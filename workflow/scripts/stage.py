"""One workflow stage, run by Snakemake's ``script:`` directive (the rule ``notebook_stage`` makes).

The notebook's papermill parameters are the rule's named inputs (but ``source``,
the notebook itself, and ``tracked``, a file the stage depends on without reading
it), named outputs (but ``html``), params and ``threads``.
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


parameters = _named(smk.input, {"source", "tracked"}) | _named(smk.output, {"html"}) | dict(smk.params.items())
parameters["threads"] = smk.threads

src = str(Path(smk.scriptdir).parents[1] / "src")
threads = str(smk.threads)
os.environ.update(OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads,
                  PYTHONPATH=os.pathsep.join(filter(None, [src, os.environ.get("PYTHONPATH")])))
os.environ.pop("MPLBACKEND", None)  # the kernel's inline backend puts every plot in the rendered notebook

sys.exit(main(smk.input.source, smk.log.notebook, smk.output.html, parameters, stderr_log=smk.log.stderr))
