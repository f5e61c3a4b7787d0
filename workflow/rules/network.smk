# Table 7: SDM inside a network (config section research.network; docs/method/network.md). One job per
# training loss (the network and its learning curve), one per noise level for the test-time comparison, and
# the gathering stage. Opt-in (research.network.enabled): its snapshot is
# docs/results/network/ (`make run-network snapshot-network`).

NETWORK = RESEARCH.get("network", {"enabled": False})
NETWORK_ON = bool(NETWORK.get("enabled", False))
NETWORK_LOSSES = list(NETWORK.get("losses", [])) if NETWORK_ON else []
NETWORK_LEVELS = [int(level) for level in NETWORK.get("levels", [])] if NETWORK_ON else []


def network_data():
    """What every Table 7 stage reads to rebuild its configurations (the split sizes, seed, levels, theta*'s spread)."""
    return {key: NETWORK[key] for key in ("sizes", "seed", "levels", "camera_sd")}


notebook_stage(
    "network_train",
    "Table 7: a ShiftNet trained with one loss (SDM, silhouette, Chamfer or supervised); its dev learning curve.",
    jobs=[{"loss": loss} for loss in NETWORK_LOSSES],
    job="network_train_{loss}",
    input=dict(sky=SKY_FILE),
    output=dict(weights=result("research/network/{loss}.pt"), curve=result("research/network/{loss}_curve.csv")),
    params=dict(**network_data(), loss=wildcard("loss"), train=NETWORK.get("train")),
    runtime=60,
)

notebook_stage(
    "network_test",
    "Table 7: every trained network, alone and with k SDM steps, CMA-ES and SDM from zero, on the test set at one noise level.",
    jobs=[{"level": level} for level in NETWORK_LEVELS],
    job="network_test_level{level}",
    input=dict(sky=SKY_FILE, weights=each("network_train", "weights")),
    output=dict(test_file=result("research/network/test_level{level}.csv")),
    params=dict(
        **network_data(),
        **{key: OBJECTS.get(key) for key in ("warm", "rows", "schedule", "cmaes", "batch_size")},
        level=wildcard("level", int),
        losses=NETWORK_LOSSES,
        refine=NETWORK.get("refine"),
        s=config["train"]["s"],
        lr_decay=config["train"]["lr_decay"],
    ),
    runtime=60,
)

notebook_stage(
    "network_bias",
    "Table 7: where each SDM rule's flow vanishes on the test set, per noise level (the bias a trained network inherits).",
    jobs=[{}] if NETWORK_ON and any(loss.startswith("sdm_") for loss in NETWORK_LOSSES) else [],
    input=dict(sky=SKY_FILE),
    output=dict(bias_file=result("research/network/bias.csv")),
    params=dict(**network_data(), s=NETWORK.get("train", {}).get("s")),
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
        figure=figure("network_curves", "network_curves"),
    ),
    params=dict(refine=NETWORK.get("refine"), train=NETWORK.get("train"), sizes=NETWORK.get("sizes")),
)
