# Table 3: SDM against the losses a researcher would use instead, on Table 2's noisy targets
# (the same run seeds: a paired comparison). One job per baseline (tune, then the runs), one for
# SDM's own runs (timed like the others, and checked equal to Table 2's), then the table.


use rule notebook_stage as baseline_fit with:
    """Tune one baseline on the dev set (like Table 1), then its paired noise runs."""
    input:
        source=notebook("baselines"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
    output:
        tuning_files=[result("baselines/tuning_{method}.csv")],
        runs_file=result("baselines/runs_{method}.csv"),
        html=html("baselines_{method}"),
    log:
        **notebook_log("baselines_{method}"),
    benchmark:
        benchmark_file("baselines_{method}")
    wildcard_constraints:
        method=BASELINE_PATTERN,
    resources:
        runtime=30,
    params:
        part="fit",
        methods=lambda wildcards: [wildcards.method],
        settings=lambda wildcards: {wildcards.method: BASELINES[wildcards.method]},
        levels=config["noise"]["levels"],
        run_indices=BASELINE_RUNS,
        s=config["train"]["s"],
        batch_size=config["train"]["batch_size"],
        lr_decay=config["train"]["lr_decay"],
        train_seed=config["train"]["seed"],
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],


use rule notebook_stage as baseline_sdm with:
    """SDM's paired runs, timed one by one like the baselines'; each must equal Table 2's run."""
    input:
        source=notebook("baselines"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
        tuning_files=[BEST_FILE],
        table2_distances=result("noise/distances.csv"),
    output:
        runs_file=result("baselines/runs_sdm.csv"),
        html=html("baselines_sdm"),
    log:
        **notebook_log("baselines_sdm"),
    benchmark:
        benchmark_file("baselines_sdm")
    params:
        part="runs",
        methods=["sdm"],
        levels=config["noise"]["levels"],
        run_indices=BASELINE_RUNS,
        s=config["train"]["s"],
        batch_size=config["train"]["batch_size"],
        lr_decay=config["train"]["lr_decay"],
        train_seed=config["train"]["seed"],
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],


use rule notebook_stage as table3 with:
    """Table 3, the baselines' tuning table, the figure and the answer in plain words."""
    input:
        source=notebook("baselines"),
        tuning_files=[BEST_FILE, *baseline_files("tuning_{method}.csv")],
        run_files=[
            result("baselines/runs_sdm.csv"),
            *baseline_files("runs_{method}.csv"),
        ],
    output:
        table3_csv=table("table3", "table3"),
        table3_md=result("tables/table3.md"),
        table3_tex=result("tables/table3.tex"),
        tuning_csv=result("tables/table3_tuning.csv"),
        tuning_md=result("tables/table3_tuning.md"),
        summary=result("tables/table3_summary.md"),
        figure=figure("baselines", "baselines"),
        html=html("table3"),
    log:
        **notebook_log("table3"),
    benchmark:
        benchmark_file("table3")
    params:
        part="table",
        methods=["sdm", *BASELINES],
        shift=config["sky"]["shift"],
