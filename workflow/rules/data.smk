# Data: annotations (generated or read) -> sampled images -> Sky dataset -> train/dev split.


rule synthetic:
    """Generate the synthetic annotation set in ApolloCar3D's layout (data.source: synthetic)."""
    input:
        source=notebook("synthetic"),
    output:
        folder=directory("results/data/synthetic_apollo"),
        html=html("synthetic"),
    log:
        **notebook_log("synthetic"),
    benchmark:
        "benchmarks/synthetic.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(
            n_images=config["data"]["synthetic"]["n_images"],
            seed=config["data"]["synthetic"]["seed"],
        ),
    threads: 1
    resources:
        runtime=20,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule data:
    """Read the annotations (synthetic, ApolloCar3D folder or PKU csv) and describe them."""
    input:
        source=notebook("data"),
        annotations=annotations(),
    output:
        images="results/data/images.csv",
        summary="results/data/summary.json",
        html=html("data"),
    log:
        **notebook_log("data"),
    benchmark:
        "benchmarks/data.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(source_kind=config["data"]["source"]),
    threads: 1
    resources:
        runtime=20,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule sample:
    """Sample the images of the Sky dataset (4,248 in the paper)."""
    input:
        source=notebook("sample"),
        images="results/data/images.csv",
    output:
        sample="results/sample/sample.csv",
        html=html("sample"),
    log:
        **notebook_log("sample"),
    benchmark:
        "benchmarks/sample.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(n_images=config["sky"]["n_images"], seed=config["sky"]["seed"]),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule sky:
    """Build one Sky configuration per sampled image."""
    input:
        source=notebook("sky"),
        annotations=annotations(),
        sample="results/sample/sample.csv",
    output:
        sky=SKY_FILE,
        stats="results/sky/stats.json",
        html=html("sky"),
    log:
        **notebook_log("sky"),
    benchmark:
        "benchmarks/sky.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(source_kind=config["data"]["source"], shift=config["sky"]["shift"]),
    threads: 1
    resources:
        runtime=30,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule split:
    """Choose 768 configurations and split them 512 train / 256 dev."""
    input:
        source=notebook("split"),
        sky=SKY_FILE,
    output:
        split="results/split/split.json",
        html=html("split"),
    log:
        **notebook_log("split"),
    benchmark:
        "benchmarks/split.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(
            n_selected=config["split"]["n_selected"],
            n_train=config["split"]["n_train"],
            n_dev=config["split"]["n_dev"],
            seed=config["split"]["seed"],
        ),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL
