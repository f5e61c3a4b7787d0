# Table 3: SDM against the losses a researcher would use instead, on Table 2's noisy targets
# (the same run seeds: a paired comparison). Per baseline, one tuning job (its grid on the dev set,
# like Table 1), then one job per noise level (that level's paired runs), like the noise stage;
# then the table. SDM is not rerun: its rows are Table 2's runs (noise/distances.csv), its time
# per run the one the noise jobs record.

notebook_stage(
    "baseline_tune",
    "Tune one baseline on the dev set, noise-free, by Table 1's criterion (the dev loss).",
    jobs=[{"method": method} for method in BASELINES],
    job="baselines_tune_{method}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(tuning_file=result("baselines/tuning_{method}.csv")),
    params=dict(
        method=wildcard("method"),
        settings=lambda wildcards: BASELINES[wildcards.method],
        s=config["train"]["s"],
        train_seed=config["train"]["seed"],
        shift=config["sky"]["shift"],
    ),
)

notebook_stage(
    "baseline_runs",
    "One baseline's paired runs at one noise level, with its tuned settings.",
    jobs=[{"method": method, "level": level} for method in BASELINES for level in LEVELS],
    job="baselines_{method}_level{level}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, tuning_file=result("baselines/tuning_{method}.csv")),
    output=dict(runs_file=result("baselines/runs_{method}_level{level}.csv")),
    params=dict(
        method=wildcard("method"),
        level=wildcard("level", int),
        runs=BASELINE_RUNS,
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
    runtime=15,
)

notebook_stage(
    "floor_runs",
    "The floor at one noise level: per paired run, the theta minimising the exact pixel mismatch.",
    jobs=[{"level": level} for level in LEVELS] if FLOOR["enabled"] else [],
    job="floor_level{level}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(runs_file=result("floor/level{level}.csv")),
    params=dict(
        level=wildcard("level", int),
        runs=FLOOR_RUNS,
        settings=FLOOR_SETTINGS,
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
    runtime=20,
)

notebook_stage(
    "table3",
    "Table 3 (SDM's rows from Table 2's runs), the tuning table, the figure, the answer in words.",
    jobs=[{}] if config["baselines"]["enabled"] else [],
    input=dict(
        tuning_files=each("baseline_tune", "tuning_file"),
        run_files=each("baseline_runs", "runs_file"),
        table2_distances=result("noise/distances.csv"),
        sdm_timings=each("noise", "timing_file"),
        floor_files=each("floor_runs", "runs_file"),
    ),
    output=dict(
        **table_files("table3"),
        tuning_csv=result("tables/table3_tuning.csv"),
        tuning_md=result("tables/table3_tuning.md"),
        summary=result("tables/table3_summary.md"),
        figure=figure("baselines", "baselines"),
    ),
    params=dict(
        methods=[*BASELINES],
        floor_settings=FLOOR_SETTINGS,
        levels=config["noise"]["levels"],
        runs=BASELINE_RUNS,
        shift=config["sky"]["shift"],
    ),
)
