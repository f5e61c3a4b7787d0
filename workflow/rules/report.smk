# Tables 1-2 (with Table 2's figure), the paper's Figures 1-4 (they need the split only: a figure waits for
# nothing but its own inputs) and the reproduction report.

notebook_stage(
    "tables",
    "Merge the noise runs; write Tables 1 and 2 with the paper's values beside ours.",
    input=dict(
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        stats=result("sky/stats.json"),
        chunks=each("noise", "chunk_file"),
    ),
    output=dict(
        **table_files("table1"),
        **table_files("table2"),
        distances=result("noise/distances.csv"),
        distances_plot=figure("distances", "distances"),
    ),
    params=dict(noise_levels=config["noise"]["levels"], runs=config["noise"]["runs"]),
)

notebook_stage(
    "figures",
    "Figures 1-4 of the paper: one configuration of the split, nothing trained.",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(
        fig1=figure("fig1_configuration", "fig1"),
        fig2=figure("fig2_forward", "fig2"),
        fig3=figure("fig3_backward", "fig3"),
        fig4=figure("fig4_noise", "fig4"),
    ),
    params=dict(
        example=config["figures"]["example"],
        noise_seed=config["figures"]["seed"],
        noise_levels=config["noise"]["levels"],
        s=config["train"]["s"],
        shift=config["sky"]["shift"],
    ),
)

notebook_stage(
    "report",
    "Compare every number with the paper and explain each gap; the verdict's facts of Tables 1-4 (make snapshot words them).",
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
        "report": result("report/reproduction.md"),
        "report_html": report(
            result("report/reproduction.html"), caption="../report/reproduction.rst", category="Report"
        ),
        "verdict": result("report/verdict.json"),
    },
    params=dict(
        # the methods and rules the verdict compares: the configured ones (a table's other rows are no method)
        methods=["sdm", *BASELINES],
        rules=RULE_NAMES,
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
