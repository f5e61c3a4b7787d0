# Table 3: SDM against the losses a researcher would use instead, on Table 2's noisy targets
# (the same run seeds: a paired comparison). Per baseline, one tuning job (its grid on the dev set,
# like Table 1), then one job per noise level (that level's paired runs), like the noise stage;
# then the table. SDM is not rerun: its rows are Table 2's runs (noise/distances.csv), its time
# per run the one the noise jobs record.


use rule notebook_stage as baseline_tune with:
    """Tune one baseline on the dev set, noise-free, by Table 1's criterion (the dev loss)."""
    input:
        source=notebook("baselines"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
    output:
        tuning_files=[result("baselines/tuning_{method}.csv")],
        html=html("baselines_tune_{method}"),
    log:
        **notebook_log("baselines_tune_{method}"),
    benchmark:
        benchmark_file("baselines_tune_{method}")
    params:
        part="tune",
        methods=lambda wildcards: [wildcards.method],
        settings=lambda wildcards: {wildcards.method: BASELINES[wildcards.method]},
        s=config["train"]["s"],
        train_seed=config["train"]["seed"],
        shift=config["sky"]["shift"],


use rule notebook_stage as baseline_runs with:
    """One baseline's paired runs at one noise level, with its tuned settings."""
    input:
        source=notebook("baselines"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        tuning_files=[result("baselines/tuning_{method}.csv")],
    output:
        runs_file=result("baselines/runs_{method}_level{level}.csv"),
        html=html("baselines_{method}_level{level}"),
    log:
        **notebook_log("baselines_{method}_level{level}"),
    benchmark:
        benchmark_file("baselines_{method}_level{level}")
    resources:
        runtime=15,
    params:
        part="runs",
        methods=lambda wildcards: [wildcards.method],
        levels=lambda wildcards: [int(wildcards.level)],
        run_indices=BASELINE_RUNS,
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],


use rule notebook_stage as table3 with:
    """Table 3 (SDM's rows from Table 2's runs), the tuning table, the figure, the answer in words."""
    input:
        source=notebook("baselines"),
        tuning_files=each("baseline_tune", "tuning_files"),
        run_files=each("baseline_runs", "runs_file"),
        table2_distances=result("noise/distances.csv"),
        sdm_timings=each("noise", "timing_file"),
    output:
        **table_files("table3"),
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
        methods=[*BASELINES],
        levels=config["noise"]["levels"],
        run_indices=BASELINE_RUNS,
        shift=config["sky"]["shift"],
