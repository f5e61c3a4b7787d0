# Beyond the paper (issue 12; config section research). Table 4: Table 2 again with other gradient
# rules, one job per (rule, noise level), on Table 2's noise draws (the same run seeds: paired).
# Table 5: the shift (a, b, c) with depth, one job per (c*, noise level). Each has its gathering stage;
# the report states both in plain words when they are enabled.


use rule notebook_stage as rule_runs with:
    """One rule's runs at one noise level: Table 2's noisy targets and shuffling, the rule's flow."""
    input:
        source=notebook("research"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
    output:
        runs_file=result("research/rules/{flow}_level{level}.csv"),
        html=html("research_rules_{flow}_level{level}"),
    log:
        **notebook_log("research_rules_{flow}_level{level}"),
    benchmark:
        benchmark_file("research_rules_{flow}_level{level}")
    resources:
        runtime=20,
    params:
        **training(seed=config["noise"]["seed"]),
        part="rules",
        flow=lambda wildcards: wildcards.flow,
        level=lambda wildcards: int(wildcards.level),
        run_indices=RULE_RUNS,


use rule notebook_stage as depth_runs with:
    """The depth runs of one c* at one noise level: targets moved by (a*, b*, c*), noise, fit (a, b, c)."""
    input:
        source=notebook("research"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
    output:
        runs_file=result("research/depth/c{c}_level{level}.csv"),
        html=html("research_depth_c{c}_level{level}"),
    log:
        **notebook_log("research_depth_c{c}_level{level}"),
    benchmark:
        benchmark_file("research_depth_c{c}_level{level}")
    resources:
        runtime=30,
    params:
        **training(seed=config["noise"]["seed"]),
        part="depth",
        flow=RESEARCH_DEPTH.get("flow", "paper"),
        depth_lr_scale=RESEARCH_DEPTH.get("lr_scale", 20),
        c=depth_shift,
        level=lambda wildcards: int(wildcards.level),
        run_indices=DEPTH_RUNS,


use rule notebook_stage as table4 with:
    """Table 4: Table 2 per rule beside the paper's rule on the same draws, the paper and the issue's bar."""
    input:
        source=notebook("research"),
        rule_files=each("rule_runs", "runs_file"),
        table2_distances=result("noise/distances.csv"),
        baseline_run_files=each("baseline_runs", "runs_file"),
    output:
        **table_files("table4"),
        table4_summary=result("tables/table4_summary.md"),
        figure=figure("research_rules", "research_rules"),
        html=html("table4"),
    log:
        **notebook_log("table4"),
    benchmark:
        benchmark_file("table4")
    params:
        part="table4",
        names=RULE_NAMES,
        levels=config["noise"]["levels"],
        run_indices=RULE_RUNS,


use rule notebook_stage as table5 with:
    """Table 5: the depth runs' mean errors of a, b, c and distances per c* and noise level."""
    input:
        source=notebook("research"),
        depth_files=each("depth_runs", "runs_file"),
    output:
        **table_files("table5"),
        table5_summary=result("tables/table5_summary.md"),
        figure=figure("research_depth", "research_depth"),
        html=html("table5"),
    log:
        **notebook_log("table5"),
    benchmark:
        benchmark_file("table5")
    params:
        part="table5",
        shifts_c=list(DEPTH_SHIFTS.values()),
        levels=DEPTH_LEVELS,
        run_indices=DEPTH_RUNS,
