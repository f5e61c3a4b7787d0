# Data: annotations (generated or read) -> sampled images -> Sky dataset -> train/dev split.

notebook_stage(
    "synthetic",
    "Generate the synthetic annotation set in ApolloCar3D's layout (data.source: synthetic).",
    jobs=[{}] if config["data"]["source"] == "synthetic" else [],
    output=dict(folder=directory(result("data/synthetic_apollo"))),
    params=dict(n_images=config["data"]["synthetic"]["n_images"], seed=config["data"]["synthetic"]["seed"]),
    runtime=20,
)

notebook_stage(
    "data",
    "Read the annotations (synthetic, ApolloCar3D folder or PKU csv) and describe them.",
    input=annotation_inputs(),
    output=dict(images=result("data/images.csv"), summary=result("data/summary.json")),
    params=annotation_params(),
    tracked=annotation_tracked(),
    runtime=20,
)

notebook_stage(
    "sample",
    "Sample the images of the Sky dataset (4,248 in the paper).",
    input=dict(images=result("data/images.csv")),
    output=dict(sample=result("sample/sample.csv")),
    params=dict(n_images=config["sky"]["n_images"], seed=config["sky"]["seed"]),
)

notebook_stage(
    "sky",
    "Build one Sky configuration per sampled image.",
    input=dict(**annotation_inputs(), sample=result("sample/sample.csv")),
    output=dict(sky=SKY_FILE, stats=result("sky/stats.json")),
    params=dict(**annotation_params(), shift=config["sky"]["shift"]),
    tracked=annotation_tracked(),
    runtime=30,
)

notebook_stage(
    "split",
    "Choose 768 configurations and split them 512 train / 256 dev.",
    input=dict(sky=SKY_FILE),
    output=dict(split=SPLIT_FILE),
    params={key: config["split"][key] for key in ("n_selected", "n_train", "n_dev", "seed")},
)
