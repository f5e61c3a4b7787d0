# -- the notebook-stage rule ----------------------------------------------------------------------------
# A stage is a jupytext notebook run by papermill and rendered to HTML, by workflow/scripts/stage.py.
# Its notebook's parameters are the rule's named inputs, named outputs (but `html`), params (but `stage`)
# and threads. Params are plain config values (or functions of the wildcards only), so that Snakemake's
# params trigger reruns the stages a config edit affects. The param `stage` holds what the stage depends
# on without reading it: its notebook's path and the fingerprint of the code it runs (and an ApolloCar3D
# folder's file listing), so that a code edit reruns the stages that run the edited file. The notebook is
# no input: its path would be absolute, or relative to a working directory that may lie outside the
# project, and a moved project would rerun every stage; its content is in the fingerprint instead.
# Each stage is one call of notebook_stage, which states only what is the stage's own; the rest (its
# notebook, rendering, log, benchmark, environment and resources) is the same for every stage.


def notebook_stage(
    name, doc, *, jobs=({},), job=None, input={}, output={}, params={}, tracked={}, runtime=10, priority=0
):
    """Add the stage `name`, described by `doc`, that runs notebooks/<name>.py, as its rule (one notebook per
    stage: a notebook serves no other stage, and switches on no parameter to choose what it does).

    jobs: the rule's jobs as their wildcards, a dict each (the default, one job without wildcards, or none
        when the stage is switched off); the target all asks for each job's rendered notebook, and
        `each(name, output)` lists a named output's files in this order, for the stages that gather them.
    job: the name of a job's rendered notebook, log and benchmark, with the rule's wildcards (default: name).
    input, output, params: the stage's own named inputs, outputs and params; runtime: minutes on a cluster.
    tracked: digests of what the stage reads without a file input (the annotation files), beside its code.
    priority: which ready jobs Snakemake starts first (higher first; 0 by default): the longest jobs, and those
        that gate them, start early, so that the cores are not left to one long job at the end.
    """
    if "html" in output or "stage" in params:
        raise WorkflowError(
            f"stage {name}: the output 'html' (the notebook's rendering) and the param 'stage' (its notebook and "
            f"code) are named by the stage"
        )
    job = job or name
    JOBS[name] = jobs

    rule:
        name:
            name
        input:
            **input,
        output:
            **output,
            html=result(f"notebooks/{job}.html"),
        log:
            # the executed notebook (kept when the stage fails) and the tools' messages
            notebook=result(f"notebooks/{job}.ipynb"),
            stderr=f"{LOGS}/{job}.log",
        benchmark:
            f"{BENCHMARKS}/{job}.tsv"
        priority: priority
        conda:
            "../envs/sdm.yaml"
        threads: 1
        resources:
            runtime=runtime,
        params:
            **params,
            # a function: computed for the jobs a run asks for, after the checks below
            stage=lambda wildcards: dict(notebook=f"notebooks/{name}.py", code=stage_code(name), **tracked),
        script:
            "../scripts/stage.py"

    made = workflow.get_rule(name)
    made.docstring = doc  # `snakemake --list-rules` shows it
    for wildcards in jobs:  # a job that names other wildcards than the files' would never be asked for
        if set(wildcards) != set(made.wildcard_names):
            raise WorkflowError(
                f"stage {name}: job {wildcards} must name the wildcards {sorted(made.wildcard_names)}"
            )
