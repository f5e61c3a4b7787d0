# Table 1: one training run per (n_epoch, lr) cell, scored by the dev loss; then the best cell.


rule tune:
    """Train on the train set with one cell of the grid; score it on the dev set."""
    input:
        source=notebook("tune"),
        sky=SKY_FILE,
        split="results/split/split.json",
    output:
        cell="results/tuning/cell_{n_epoch}_{lr}.json",
        history="results/tuning/history_{n_epoch}_{lr}.csv",
        html=html("tune_{n_epoch}_{lr}"),
    log:
        **notebook_log("tune_{n_epoch}_{lr}"),
    benchmark:
        "benchmarks/tune_{n_epoch}_{lr}.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(
            n_epoch=lambda w: int(w.n_epoch),
            lr=lambda w: float(w.lr),
            s=config["train"]["s"],
            batch_size=config["train"]["batch_size"],
            lr_decay=config["train"]["lr_decay"],
            seed=config["train"]["seed"],
            shift=config["sky"]["shift"],
        ),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule best:
    """Collect the grid (Table 1) and pick the cell with the lowest dev loss."""
    input:
        source=notebook("best"),
        cells=tuning_files("cell"),
    output:
        grid="results/tuning/grid.csv",
        best="results/tuning/best.json",
        html=html("best"),
    log:
        **notebook_log("best"),
    benchmark:
        "benchmarks/best.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL
