# SDM: regenerate the paper's Tables 1-2 and Figures 1-4 with `snakemake -c2`.
# Stages are jupytext notebooks in notebooks/, run by papermill (workflow/rules/*.smk).
from snakemake.utils import min_version, validate

from sdm.config import check_config

min_version("9.0")


configfile: "config.yaml"


validate(config, schema="workflow/schemas/config.schema.yaml")
check_config(config)


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/tuning.smk"
include: "workflow/rules/noise.smk"
include: "workflow/rules/report.smk"


wildcard_constraints:
    n_epoch=r"\d+",
    lr=r"[0-9][0-9.e+-]*",
    level=r"\d+",
    chunk=r"\d+",


rule all:
    """Everything: tables, figures, the reproduction report and every rendered notebook."""
    default_target: True
    input:
        rules.tables.output,
        rules.figures.output,
        rules.report.output,
        notebook_html(),
