# Table 6: parameters attached to points (config section research.objects; docs/method/objects.md). One job
# per (sharing, noise level) for the paired runs of every method, one per K for the scaling with the number
# of cars, and the gathering stage. Opt-in (research.objects.enabled): its snapshot is docs/results/objects/.

OBJECTS = RESEARCH.get("objects", {"enabled": False})
OBJECTS_ON = bool(OBJECTS.get("enabled", False))
OBJECT_SHARINGS = {name.replace("+", "_and_"): name for name in OBJECTS.get("sharings", [])} if OBJECTS_ON else {}
OBJECT_LEVELS = [int(level) for level in OBJECTS.get("levels", [])] if OBJECTS_ON else []
OBJECT_CARS = [int(k) for k in OBJECTS.get("scaling", {}).get("cars", [])] if OBJECTS_ON else []


def objects_settings():
    """The settings every Table 6 stage reads (its section of the config, in name order)."""
    keys = ("truth", "warm", "rows", "schedule", "cmaes", "floor", "silhouette", "screen")
    return {key: OBJECTS[key] for key in keys}


notebook_stage(
    "objects_runs",
    "Table 6's paired runs of one sharing level at one noise level: SDM (two rules), CMA-ES, silhouette, floor.",
    jobs=[{"sharing": label, "level": level} for label in OBJECT_SHARINGS for level in OBJECT_LEVELS],
    job="objects_{sharing}_level{level}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(runs_file=result("research/objects/{sharing}_level{level}.csv")),
    params=dict(
        **objects_settings(),
        sharing=lambda wildcards: OBJECT_SHARINGS[wildcards.sharing],
        level=wildcard("level", int),
        runs=OBJECTS.get("runs"),
        configurations=OBJECTS.get("configurations"),
        seed=config["noise"]["seed"],
        batch_size=OBJECTS.get("batch_size"),
        lr_decay=config["train"]["lr_decay"],
        s=config["train"]["s"],
    ),
    runtime=60,
)

notebook_stage(
    "objects_scaling",
    "Error against CPU time per configuration with K cars per image, one row per car: SDM and CMA-ES.",
    jobs=[{"cars": k} for k in OBJECT_CARS],
    job="objects_scaling_{cars}",
    output=dict(scaling_file=result("research/objects/scaling_{cars}.csv")),
    params=dict(
        **objects_settings(),
        cars=wildcard("cars", int),
        scaling=OBJECTS.get("scaling"),
        seed=config["noise"]["seed"],
        batch_size=config["train"]["batch_size"],
        lr_decay=config["train"]["lr_decay"],
        s=config["train"]["s"],
    ),
    runtime=60,
)

notebook_stage(
    "table6",
    "Table 6: per sharing level and noise level, each method's distance per unit and CPU time; the scaling figure.",
    jobs=[{}] if OBJECTS_ON else [],
    input=dict(
        runs_files=each("objects_runs", "runs_file"),
        scaling_files=each("objects_scaling", "scaling_file"),
        table2_distances=result("noise/distances.csv"),
    ),
    output=dict(
        **table_files("table6"),
        table6_summary=result("tables/table6_summary.md"),
        figure=figure("objects", "objects"),
        scaling_figure=figure("objects_scaling", "objects_scaling"),
    ),
    params=dict(levels=OBJECT_LEVELS, runs=OBJECTS.get("runs")),
)


def table6_read_by_report():
    """Table 6 for the verdict: this run's when the stage runs, else the committed snapshot where it exists."""
    if OBJECTS_ON:
        return dict(table6_csv=result("tables/table6.csv"))
    snapshot = Path("docs/results/objects/table6.csv")
    return dict(table6_csv=str(snapshot)) if snapshot.exists() else {}
