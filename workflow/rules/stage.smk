# -- the notebook-stage rule ----------------------------------------------------------------------------
# A stage is a jupytext notebook run by papermill and rendered to HTML, by workflow/scripts/stage.py.
# Its notebook's parameters are the rule's named inputs (but `source`, the notebook itself, and `tracked`),
# named outputs (but `html`), params and threads. Params are plain config values (or functions of the
# wildcards only), so that Snakemake's params trigger reruns the stages a config edit affects.
# Each stage is one call of notebook_stage, which states only what is the stage's own; the rest (its
# notebook, rendering, log, benchmark, environment and resources) is the same for every stage.


def notebook_stage(name, doc, *, jobs=({},), notebook=None, job=None, input={}, output={}, params={}, runtime=10):
    """Add the stage `name`, described by `doc`, that runs notebooks/<notebook>.py (default: name), as its rule.

    jobs: the rule's jobs as their wildcards, a dict each (the default, one job without wildcards, or none
        when the stage is switched off); the target all asks for each job's rendered notebook, and
        `each(name, output)` lists a named output's files in this order, for the stages that gather them.
    job: the name of a job's rendered notebook, log and benchmark, with the rule's wildcards (default: name).
    input, output, params: the stage's own named inputs, outputs and params; runtime: minutes on a cluster.
    """
    if "source" in input or "html" in output:
        raise WorkflowError(f"stage {name}: 'source' and 'html' are the notebook and its rendering, named by the stage")
    job = job or name
    JOBS[name] = jobs

    rule:
        name:
            name
        input:
            **input,
            source=str(NOTEBOOKS / f"{notebook or name}.py"),
        output:
            **output,
            html=result(f"notebooks/{job}.html"),
        log:
            # the executed notebook (kept when the stage fails) and the tools' messages
            notebook=result(f"notebooks/{job}.ipynb"),
            stderr=f"{LOGS}/{job}.log",
        benchmark:
            f"{BENCHMARKS}/{job}.tsv"
        conda:
            "../envs/sdm.yaml"
        threads: 1
        resources:
            runtime=runtime,
        params:
            **params,
        script:
            "../scripts/stage.py"

    made = workflow.get_rule(name)
    made.docstring = doc  # `snakemake --list-rules` shows it
    for wildcards in jobs:  # a job that names other wildcards than the files' would never be asked for
        if set(wildcards) != set(made.wildcard_names):
            raise WorkflowError(
                f"stage {name}: job {wildcards} must name the wildcards {sorted(made.wildcard_names)}"
            )
