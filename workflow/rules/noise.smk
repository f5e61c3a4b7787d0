# Table 2: at each noise level, noise.runs independent runs with the tuned settings,
# split into chunks of noise.chunk_size runs so that jobs fan out over cores or nodes. Each chunk
# also records how long its runs took (SDM's time per run in Table 3; Table 2 does not read it).


use rule notebook_stage as noise with:
    """One chunk of noise runs at one level: noisy train targets, train, distance to theta*."""
    input:
        source=notebook("noise"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
    output:
        chunk_file=result("noise/level{level}_chunk{chunk}.csv"),
        timing_file=result("noise/level{level}_chunk{chunk}_seconds.json"),
        html=html("noise_level{level}_chunk{chunk}"),
    log:
        **notebook_log("noise_level{level}_chunk{chunk}"),
    benchmark:
        benchmark_file("noise_level{level}_chunk{chunk}")
    resources:
        runtime=15,
    params:
        **training(seed=config["noise"]["seed"]),
        level=lambda wildcards: int(wildcards.level),
        run_indices=chunk_runs,
