# SDM: regenerate the paper's Tables 1-2 and Figures 1-4 with `snakemake -c2`.
# Stages are jupytext notebooks in notebooks/, run by papermill (workflow/rules/*.smk).
import sys

from snakemake.exceptions import WorkflowError
from snakemake.utils import min_version

sys.path.insert(0, f"{workflow.basedir}/workflow/scripts")
from config_check import ConfigError, check_against_annotations, check_config, validate_schema
from failure_causes import failure_causes

min_version("9.0")


configfile: "config.yaml"


try:
    validate_schema(config)  # every key, unknown keys refused, defaults filled in
    check_config(config)
except ConfigError as error:  # one line naming the key, no traceback
    raise WorkflowError(error) from None


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/stage.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/tuning.smk"
include: "workflow/rules/noise.smk"
include: "workflow/rules/baselines.smk"
include: "workflow/rules/research.smk"
include: "workflow/rules/objects.smk"
include: "workflow/rules/network.smk"
include: "workflow/rules/report.smk"


wildcard_constraints:
    n_epoch=r"\d+",
    lr=r"[0-9][0-9.e+-]*",
    noise_level=r"\d+",
    chunk=r"\d+",
    method=one_of(BASELINES),
    schedule=one_of(RULE_LABELS),
    c=one_of(DEPTH_SHIFTS),
    sharing=one_of(SHARING_LABELS),
    scale=r"\d+",
    cars=r"\d+",
    loss=one_of(NETWORK_LOSSES),


# Small jobs run on the submitting node on a cluster (no queue wait for seconds of work).
localrules:
    all,
    sample,
    split,
    best,
    tables,
    table3,
    table4,
    table5,
    table6,
    table7,


rule all:
    """Everything: tables, figures, the reproduction report and every rendered notebook."""
    default_target: True
    input:
        [
            getattr(rules, stage).output
            for stage in ("tables", "table3", "table4", "table5", "table6", "table7", "figures", "report")
            if JOBS[stage]
        ],
        [each(stage, "html") for stage in JOBS],


# A stage run as a cluster job prints its one-line cause into the job's cluster log, which Snakemake only
# names: print each failed stage's cause (the first line of its text log) at the end of the run's output.
onerror:
    causes = failure_causes(log)
    if causes:
        print("The failed stages' causes:", *causes, sep="\n", file=sys.stderr)
