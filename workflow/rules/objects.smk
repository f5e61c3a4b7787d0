# Table 6: parameters attached to points (config section research.objects; docs/method/objects.md). One job
# per (sharing, noise level) for the paired runs of every method, one per K for the scaling with the number
# of cars, and the gathering stage. Opt-in (research.objects.enabled): its snapshot is
# docs/results/objects/ (`make run-objects snapshot-objects`).

OBJECTS = RESEARCH.get("objects", {"enabled": False})
OBJECTS_ON = bool(OBJECTS.get("enabled", False))
OBJECT_CARS = [int(k) for k in OBJECTS.get("scaling", {}).get("cars", [])] if OBJECTS_ON else []
#: The sharings by file label ("camera+car" is "camera_and_car" in a file name).
SHARING_LABELS = {"configuration": "configuration", "car": "car", "camera_and_car": "camera+car"}
#: Table 6's keys a screen may give for its own rows (each replaces the section's whole key).
SCREEN_KEYS = ("disc", "configurations", "sharings", "noise_levels", "methods", "rows", "cmaes")


def objects_screen(scale):
    """The section's settings on the screen of `scale` (research.objects.screens): the screen's own keys where it
    gives them, the section's otherwise."""
    for screen in OBJECTS.get("screens", []):
        if int(screen["scale"]) == int(scale):
            return {key: screen.get(key, OBJECTS.get(key, "pixels" if key == "disc" else None)) for key in SCREEN_KEYS}
    if OBJECTS_ON:  # the config's checks name the key before this (config_check._check_screens)
        raise WorkflowError(f"research.objects.screens has no screen of scale {scale}")
    return {key: OBJECTS.get(key) for key in SCREEN_KEYS}


OBJECT_JOBS = [
    {"scale": int(screen["scale"]), "sharing": label, "noise_level": int(level)}
    for screen in (OBJECTS.get("screens", []) if OBJECTS_ON else [])
    for label, name in SHARING_LABELS.items()
    if name in objects_screen(screen["scale"])["sharings"]
    for level in objects_screen(screen["scale"])["noise_levels"]
]


def objects_settings(scale):
    """The settings every Table 6 stage reads (its section of the config, in name order), those of the screen of
    `scale` (a number, or a params function of the job's wildcard `scale`)."""

    def of(key):
        if callable(scale):
            return lambda wildcards: objects_screen(scale(wildcards))[key]
        return objects_screen(scale)[key]

    common = {key: OBJECTS.get(key) for key in ("truth", "warm", "schedule", "floor", "identifiability", "gate")}
    screen = {
        "screen": (
            (lambda wildcards: {"scale": int(scale(wildcards)), "disc": of("disc")(wildcards)})
            if callable(scale)
            else {"scale": int(scale), "disc": of("disc")}
        )
    }
    return dict(**common, rows=of("rows"), cmaes=of("cmaes"), **screen)


def objects_batches(scale):
    """The run's configurations on the screen of `scale` (a params function of the job's wildcards), and SDM's and
    the silhouette's batch sizes: the section's, at most those configurations."""

    def configurations(wildcards):
        return int(objects_screen(scale(wildcards))["configurations"])

    def silhouette(wildcards):
        own = dict(OBJECTS.get("silhouette") or {})
        return own | {"batch_size": min(int(own["batch_size"]), configurations(wildcards))} if own else own

    return dict(
        configurations=configurations,
        silhouette=silhouette,
        batch_size=lambda wildcards: min(int(OBJECTS.get("batch_size")), configurations(wildcards)),
    )


notebook_stage(
    "objects_runs",
    "Table 6's paired runs of one sharing level at one noise level on one screen: SDM (two rules), the searches, "
    "silhouette, floor, the exact-match sets.",
    jobs=OBJECT_JOBS,
    job="objects_scale{scale}_{sharing}_level{noise_level}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(runs_file=result("research/objects/scale{scale}/{sharing}_level{noise_level}.csv")),
    params=dict(
        **objects_settings(wildcard("scale", int)),
        **objects_batches(wildcard("scale", int)),
        methods=lambda wildcards: objects_screen(int(wildcards.scale))["methods"],
        sharing=lambda wildcards: SHARING_LABELS[wildcards.sharing],
        noise_level=wildcard("noise_level", int),
        runs=OBJECTS.get("runs"),
        seed=config["noise"]["seed"],
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
        **objects_settings(int(OBJECTS.get("scaling", {}).get("scale", 1)) if OBJECTS_ON else 1),
        silhouette=OBJECTS.get("silhouette"),
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
        table6_units=result("tables/table6_units.csv.gz"),
        table6_verdict=result("tables/table6_verdict.json"),
        figure=figure("objects", "objects"),
        scaling_figure=figure("objects_scaling", "objects_scaling"),
    ),
    params=dict(runs=OBJECTS.get("runs")),
)
