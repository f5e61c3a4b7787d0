# Beyond the paper (config section research). Table 4: Table 2 again with other gradient
# rules, one job per rule (a file per noise level), on Table 2's noise draws (the same run seeds: paired),
# and one job measuring where each rule's flow vanishes (rule_bias: it needs no run, so it runs beside them).
# Table 5: the shift (a, b, c) with depth, one job per (c*, noise level). Each has its gathering stage;
# every stage runs its own notebook, notebooks/<stage>.py;
# the report states both in plain words when they are enabled.

notebook_stage(
    "rule_runs",
    "One rule's runs at every noise level (one file per level): Table 2's noisy targets and shuffling, the "
    "rule's flow.",
    jobs=[{"schedule": label} for label in RULE_LABELS],
    job="research_rules_{schedule}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, best=BEST_FILE),
    output=dict(
        runs_files=[result(f"research/rules/{{schedule}}_level{noise_level}.csv") for noise_level in NOISE_LEVELS]
    ),
    params=dict(
        **training(seed=config["noise"]["seed"]),
        schedule=lambda wildcards: RULE_LABELS[wildcards.schedule],
        noise_levels=NOISE_LEVELS,
        runs=RULE_RUNS,
    ),
    runtime=20 * len(NOISE_LEVELS),
)

notebook_stage(
    "depth_runs",
    "The depth runs of one c* at one noise level: targets moved by (a*, b*, c*), noise, fit (a, b, c).",
    jobs=[{"c": label, "noise_level": level} for label in DEPTH_SHIFTS for level in DEPTH_NOISE_LEVELS],
    job="research_depth_c{c}_level{noise_level}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, best=BEST_FILE),
    output=dict(runs_file=result("research/depth/c{c}_level{noise_level}.csv")),
    params=dict(
        **training(seed=config["noise"]["seed"]),
        # the schema's defaults fill these in whenever the section is there (no jobs when it is not)
        schedule=RESEARCH_DEPTH.get("schedule"),
        depth_lr_scale=RESEARCH_DEPTH.get("lr_scale"),
        c=lambda wildcards: DEPTH_SHIFTS[wildcards.c],
        noise_level=wildcard("noise_level", int),
        runs=DEPTH_RUNS,
    ),
    runtime=30,
)

notebook_stage(
    "rule_bias",
    "Where each rule's flow vanishes near theta* (bias under noise over stiffness), the paper's rule beside Table 4's.",
    jobs=[{}] if RESEARCH_RULES["enabled"] else [],
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(table4_bias=result("tables/table4_bias.csv")),
    params=dict(
        names=RULE_NAMES,
        noise_levels=config["noise"]["levels"],
        s=config["train"]["s"],
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
)

notebook_stage(
    "table4",
    "Table 4: Table 2 per rule beside the paper's rule on the same draws, the paper and its half (the bar).",
    jobs=[{}] if RESEARCH_RULES["enabled"] else [],
    input=dict(
        rule_files=each("rule_runs", "runs_files"),
        table4_bias=rules.rule_bias.output.table4_bias,
        table2_distances=result("noise/distances.csv"),
        baseline_run_files=each("baseline_runs", "runs_files"),
        floor_files=each("floor_runs", "runs_files"),
        sdm_timings=each("noise", "timing_file"),
    ),
    output=dict(
        **table_files("table4"),
        table4_summary=result("tables/table4_summary.md"),
        figure=figure("research_rules", "research_rules"),
    ),
    params=dict(
        names=RULE_NAMES,
        noise_levels=config["noise"]["levels"],
        runs=RULE_RUNS,
    ),
)

notebook_stage(
    "table5",
    "Table 5: the depth runs' mean errors of a, b, c and distances per c* and noise level, and c's bias at theta*.",
    jobs=[{}] if RESEARCH_DEPTH["enabled"] else [],
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, depth_files=each("depth_runs", "runs_file")),
    output=dict(
        **table_files("table5"),
        table5_summary=result("tables/table5_summary.md"),
        table5_bias=result("tables/table5_bias.csv"),
        figure=figure("research_depth", "research_depth"),
    ),
    params=dict(
        shifts_c=list(DEPTH_SHIFTS.values()),
        noise_levels=DEPTH_NOISE_LEVELS,
        runs=DEPTH_RUNS,
        schedule=RESEARCH_DEPTH.get("schedule"),
        s=config["train"]["s"],
        seed=config["noise"]["seed"],
        shift=config["sky"]["shift"],
    ),
)
