# Table 3: SDM against the losses a researcher would use instead, on Table 2's noisy targets
# (the same run seeds: a paired comparison). Per baseline, one tuning job (its grid on the dev set,
# like Table 1), then one job for its paired runs at every noise level (one job, not one per level: a
# job's start-up, about 4-5 CPU seconds for the interpreter, torch and the notebook kernel, cost as much
# as a level's runs; each level keeps its own file); then the table. SDM is not rerun: its rows are Table 2's runs (noise/distances.csv), its time
# per run the one the noise jobs record. The tuning, the runs and the floor start before the other stages'
# ready jobs (priority 1): they are the run's longest jobs, and on few cores one of them left to the end
# would run alone.

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
    priority=1,
)

notebook_stage(
    "baseline_runs",
    "One baseline's paired runs at every noise level, with its tuned settings (one file per level).",
    jobs=[{"method": method} for method in BASELINES],
    job="baselines_{method}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, tuning_file=result("baselines/tuning_{method}.csv")),
    output=dict(
        runs_files=[result(f"baselines/runs_{{method}}_level{noise_level}.csv") for noise_level in NOISE_LEVELS]
    ),
    params=dict(
        method=wildcard("method"),
        noise_levels=NOISE_LEVELS,
        runs=lambda wildcards: METHOD_RUNS[wildcards.method],
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
    runtime=15 * len(NOISE_LEVELS),
    priority=1,
)

notebook_stage(
    "floor_runs",
    "The floor at every noise level (one file per level): per paired run, the theta minimising the exact pixel "
    "mismatch.",
    jobs=[{}] if FLOOR["enabled"] else [],
    job="floor",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(runs_files=[result(f"floor/level{noise_level}.csv") for noise_level in NOISE_LEVELS]),
    params=dict(
        noise_levels=NOISE_LEVELS,
        runs=FLOOR_RUNS,
        settings=FLOOR_SETTINGS,
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
    runtime=20 * len(NOISE_LEVELS),
    priority=1,
)

notebook_stage(
    "table3",
    "Table 3 (SDM's rows from Table 2's runs), the tuning table, the figure, the answer in words.",
    jobs=[{}] if config["baselines"]["enabled"] else [],
    input=dict(
        tuning_files=each("baseline_tune", "tuning_file"),
        run_files=each("baseline_runs", "runs_files"),
        table2_distances=result("noise/distances.csv"),
        sdm_timings=each("noise", "timing_file"),
        floor_files=each("floor_runs", "runs_files"),
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
        noise_levels=config["noise"]["levels"],
        runs=BASELINE_RUNS,
        shift=config["sky"]["shift"],
    ),
)
