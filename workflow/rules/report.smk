# Tables 1-2, the paper's figures and the reproduction report.


rule tables:
    """Merge the noise runs; write Tables 1 and 2 with the paper's values beside ours."""
    input:
        source=notebook("tables"),
        grid="results/tuning/grid.csv",
        best="results/tuning/best.json",
        stats="results/sky/stats.json",
        chunks=noise_files(),
    output:
        distances="results/noise/distances.csv",
        table1_csv=report("results/tables/table1.csv", caption="../report/table1.rst", category="Tables"),
        table1_md="results/tables/table1.md",
        table1_tex="results/tables/table1.tex",
        table2_csv=report("results/tables/table2.csv", caption="../report/table2.rst", category="Tables"),
        table2_md="results/tables/table2.md",
        table2_tex="results/tables/table2.tex",
        html=html("tables"),
    log:
        **notebook_log("tables"),
    benchmark:
        "benchmarks/tables.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(levels=config["noise"]["levels"], runs=config["noise"]["runs"]),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule figures:
    """Figures 1-4 of the paper, theta's path per zoom level, distances per noise level."""
    input:
        source=notebook("figures"),
        sky=SKY_FILE,
        split="results/split/split.json",
        best="results/tuning/best.json",
        histories=tuning_files("history"),
        distances="results/noise/distances.csv",
    output:
        fig1=report("results/figures/fig1_configuration.png", caption="../report/fig1.rst", category="Figures"),
        fig2=report("results/figures/fig2_forward.png", caption="../report/fig2.rst", category="Figures"),
        fig3=report("results/figures/fig3_backward.png", caption="../report/fig3.rst", category="Figures"),
        fig4=report("results/figures/fig4_noise.png", caption="../report/fig4.rst", category="Figures"),
        theta_path=report("results/figures/theta_path.png", caption="../report/theta_path.rst", category="Figures"),
        distances_plot=report("results/figures/distances.png", caption="../report/distances.rst", category="Figures"),
        html=html("figures"),
    log:
        **notebook_log("figures"),
    benchmark:
        "benchmarks/figures.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(
            example=config["figures"]["example"],
            noise_seed=config["figures"]["seed"],
            levels=config["noise"]["levels"],
            s=config["train"]["s"],
            shift=config["sky"]["shift"],
        ),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL


rule report:
    """Compare every number with the paper and explain each gap."""
    input:
        source=notebook("report"),
        table1="results/tables/table1.csv",
        table2="results/tables/table2.csv",
        distances="results/noise/distances.csv",
        stats="results/sky/stats.json",
        summary="results/data/summary.json",
        sky="results/sky/sky.bin",
        split="results/split/split.json",
    output:
        report=report("results/report/reproduction.md", caption="../report/reproduction.rst", category="Report"),
        html=html("report"),
    log:
        **notebook_log("report"),
    benchmark:
        "benchmarks/report.tsv"
    params:
        src=str(SRC),
        tools=TOOLS,
        runner=RUNNER,
        nb=parameters(config=config),
    threads: 1
    resources:
        runtime=10,
    conda:
        "../envs/sdm.yaml"
    shell:
        NOTEBOOK_SHELL
