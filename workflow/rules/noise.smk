# Table 2: at each noise level, noise.runs independent runs with the tuned settings,
# split into chunks of noise.chunk_size runs so that jobs fan out over cores or nodes.


rule noise:
    """One chunk of noise runs at one level: noisy train targets, train, distance to theta*."""
    input:
        source=notebook("noise"),
        sky=SKY_FILE,
        split="results/split/split.json",
        best="results/tuning/best.json",
    output:
        chunk_file="results/noise/level{level}_chunk{chunk}.csv",
        html=html("noise_level{level}_chunk{chunk}"),
    log:
        **notebook_log("noise_level{level}_chunk{chunk}"),
    benchmark:
        "benchmarks/noise_level{level}_chunk{chunk}.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(
            level=lambda w: int(w.level),
            run_indices=lambda w: chunk_runs(config, int(w.chunk)),
            s=config["train"]["s"],
            batch_size=config["train"]["batch_size"],
            lr_decay=config["train"]["lr_decay"],
            seed=config["noise"]["seed"],
            shift=config["sky"]["shift"],
        ),
    threads: 1
    resources:
        runtime=15,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL
