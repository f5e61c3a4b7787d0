# Tables 1-2, the paper's figures and the reproduction report.

notebook_stage(
    "tables",
    "Merge the noise runs; write Tables 1 and 2 with the paper's values beside ours.",
    input=dict(
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        stats=result("sky/stats.json"),
        chunks=each("noise", "chunk_file"),
    ),
    output=dict(**table_files("table1"), **table_files("table2"), distances=result("noise/distances.csv")),
    params=dict(levels=config["noise"]["levels"], runs=config["noise"]["runs"]),
)

notebook_stage(
    "figures",
    "Figures 1-4 of the paper, theta's path per zoom level, distances per noise level.",
    input=dict(
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
        best_history=result("tuning/best_history.csv"),
        distances=result("noise/distances.csv"),
    ),
    output=dict(
        fig1=figure("fig1_configuration", "fig1"),
        fig2=figure("fig2_forward", "fig2"),
        fig3=figure("fig3_backward", "fig3"),
        fig4=figure("fig4_noise", "fig4"),
        theta_path=figure("theta_path", "theta_path"),
        distances_plot=figure("distances", "distances"),
    ),
    params=dict(
        example=config["figures"]["example"],
        noise_seed=config["figures"]["seed"],
        levels=config["noise"]["levels"],
        s=config["train"]["s"],
        shift=config["sky"]["shift"],
    ),
)

notebook_stage(
    "report",
    "Compare every number with the paper and explain each gap.",
    input=dict(
        **extra_tables_read_by_report(),
        table1=result("tables/table1.csv"),
        table2=result("tables/table2.csv"),
        distances=result("noise/distances.csv"),
        stats=result("sky/stats.json"),
        summary=result("data/summary.json"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
    ),
    # a dict literal: a line that starts with the word report is Snakemake's report directive
    output={
        "report": report(result("report/reproduction.md"), caption="../report/reproduction.rst", category="Report")
    },
    params=dict(
        config=config_values(
            "data.source",
            *annotation_keys(),
            "sky.shift",
            "split.n_selected",
            "split.n_train",
            "split.n_dev",
            "train.s",
            "train.batch_size",
            "noise.levels",
            "noise.runs",
            "noise.seed",
        ),
    ),
)
