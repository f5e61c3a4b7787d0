# Table 7: SDM inside a network (config section research.network; docs/method/network.md). One job per
# training loss and training run (the network and its learning curve; run r of every loss has the same seed),
# one per noise level for the test-time comparison, and the gathering stage. Opt-in (research.network.enabled):
# its snapshot is docs/results/network/ (`make run-network snapshot-network`).

NETWORK = RESEARCH.get("network", {"enabled": False})
NETWORK_ON = bool(NETWORK.get("enabled", False))
NETWORK_LOSSES = list(NETWORK.get("losses", [])) if NETWORK_ON else []
NETWORK_NOISE_LEVELS = [int(level) for level in NETWORK.get("noise_levels", [])] if NETWORK_ON else []
NETWORK_RUNS = list(range(int(NETWORK.get("runs", 1)))) if NETWORK_ON else []
# every trained network, in network_train's job order (each("network_train", ...) lists its files so)
NETWORK_JOBS = [{"loss": loss, "run": str(run)} for loss in NETWORK_LOSSES for run in NETWORK_RUNS]


def network_data():
    """What every Table 7 stage reads to rebuild its configurations (the split sizes, seed, levels, theta*'s spread)."""
    return {key: NETWORK[key] for key in ("sizes", "seed", "noise_levels", "camera_sd")}


notebook_stage(
    "network_train",
    "Table 7: a ShiftNet trained with one loss (SDM, silhouette, Chamfer or supervised), one training run's seed; its dev learning curve.",
    jobs=NETWORK_JOBS,
    job="network_train_{loss}_run{run}",
    input=dict(sky=SKY_FILE),
    output=dict(
        weights=result("research/network/{loss}_run{run}.pt"),
        curve=result("research/network/{loss}_run{run}_curve.csv"),
    ),
    params=dict(**network_data(), loss=wildcard("loss"), run=wildcard("run", int), train=NETWORK.get("train")),
    runtime=60,
)

notebook_stage(
    "network_test",
    "Table 7: every trained network, alone and with k SDM steps, CMA-ES and SDM from zero, on the test set at one noise level.",
    jobs=[{"noise_level": level} for level in NETWORK_NOISE_LEVELS],
    job="network_test_level{noise_level}",
    input=dict(sky=SKY_FILE, weights=each("network_train", "weights")),
    output=dict(test_file=result("research/network/test_level{noise_level}.csv")),
    params=dict(
        **network_data(),
        **{key: OBJECTS.get(key) for key in ("warm", "rows", "schedule", "cmaes", "batch_size")},
        noise_level=wildcard("noise_level", int),
        networks=[[job["loss"], int(job["run"])] for job in NETWORK_JOBS],
        refine=NETWORK.get("refine"),
        s=config["train"]["s"],
        lr_decay=config["train"]["lr_decay"],
    ),
    runtime=60,
)

notebook_stage(
    "network_bias",
    "Table 7: where each label-free loss's mean gradient (SDM's flow, the silhouette's) vanishes on the test set, per noise level.",
    jobs=(
        [{}]
        if NETWORK_ON and any(loss in ("sdm_paper", "sdm_closed_centred_r1", "silhouette") for loss in NETWORK_LOSSES)
        else []
    ),
    input=dict(sky=SKY_FILE),
    output=dict(bias_file=result("research/network/bias.csv")),
    params=dict(**network_data(), losses=NETWORK_LOSSES, train=NETWORK.get("train")),
)

notebook_stage(
    "table7",
    "Table 7: per noise level, each method's distance to theta* on the test set and CPU time; the learning curves.",
    jobs=[{}] if NETWORK_ON else [],
    input=dict(
        test_files=each("network_test", "test_file"),
        curves=each("network_train", "curve"),
        bias_files=each("network_bias", "bias_file"),
    ),
    output=dict(
        **table_files("table7"),
        table7_summary=result("tables/table7_summary.md"),
        table7_verdict=result("tables/table7_verdict.json"),
        table7_curves=result("tables/table7_curves.csv"),
        figure=figure("network_curves", "network_curves"),
    ),
    params=dict(refine=NETWORK.get("refine"), train=NETWORK.get("train"), sizes=NETWORK.get("sizes")),
)
