# -- the notebook-stage template -----------------------------------------------------------------------
# A stage is a jupytext notebook run by papermill and rendered to HTML, by workflow/scripts/stage.py.
# Its notebook's parameters are the rule's named inputs (but `source`, the notebook itself, and `tracked`), named
# outputs (but `html`), params and threads. Params are plain config values (or functions of the
# wildcards only), so that Snakemake's params trigger reruns the stages a config edit affects.
# Each stage's rule is `use rule notebook_stage as NAME with:` and states only its own inputs, outputs,
# params, log and benchmark.


rule notebook_stage:
    log:
        # every stage names its own logs (notebook_log); this only satisfies the linter
        "logs/notebook_stage.log",
    conda:
        "../envs/sdm.yaml"
    threads: 1
    resources:
        runtime=10,
    script:
        "../scripts/stage.py"
