# Data: annotations (generated or read) -> sampled images -> Sky dataset -> train/dev split.


use rule notebook_stage as synthetic with:
    """Generate the synthetic annotation set in ApolloCar3D's layout (data.source: synthetic)."""
    input:
        source=notebook("synthetic"),
    output:
        folder=directory(result("data/synthetic_apollo")),
        html=html("synthetic"),
    log:
        **notebook_log("synthetic"),
    benchmark:
        benchmark_file("synthetic")
    resources:
        runtime=20,
    params:
        n_images=config["data"]["synthetic"]["n_images"],
        seed=config["data"]["synthetic"]["seed"],


use rule notebook_stage as data with:
    """Read the annotations (synthetic, ApolloCar3D folder or PKU csv) and describe them."""
    input:
        **annotation_inputs(),
        source=notebook("data"),
    output:
        images=result("data/images.csv"),
        summary=result("data/summary.json"),
        html=html("data"),
    log:
        **notebook_log("data"),
    benchmark:
        benchmark_file("data")
    resources:
        runtime=20,
    params:
        **annotation_params(),


use rule notebook_stage as sample with:
    """Sample the images of the Sky dataset (4,248 in the paper)."""
    input:
        source=notebook("sample"),
        images=result("data/images.csv"),
    output:
        sample=result("sample/sample.csv"),
        html=html("sample"),
    log:
        **notebook_log("sample"),
    benchmark:
        benchmark_file("sample")
    params:
        n_images=config["sky"]["n_images"],
        seed=config["sky"]["seed"],


use rule notebook_stage as sky with:
    """Build one Sky configuration per sampled image."""
    input:
        **annotation_inputs(),
        source=notebook("sky"),
        sample=result("sample/sample.csv"),
    output:
        sky=SKY_FILE,
        stats=result("sky/stats.json"),
        html=html("sky"),
    log:
        **notebook_log("sky"),
    benchmark:
        benchmark_file("sky")
    resources:
        runtime=30,
    params:
        **annotation_params(),
        shift=config["sky"]["shift"],


use rule notebook_stage as split with:
    """Choose 768 configurations and split them 512 train / 256 dev."""
    input:
        source=notebook("split"),
        sky=SKY_FILE,
    output:
        split=SPLIT_FILE,
        html=html("split"),
    log:
        **notebook_log("split"),
    benchmark:
        benchmark_file("split")
    params:
        n_selected=config["split"]["n_selected"],
        n_train=config["split"]["n_train"],
        n_dev=config["split"]["n_dev"],
        seed=config["split"]["seed"],
