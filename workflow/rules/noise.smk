# Table 2: at each noise level, noise.runs independent runs with the tuned settings,
# split into chunks of noise.chunk_size runs so that jobs fan out over cores or nodes. Each chunk
# also records how long its runs took (SDM's time per run in Table 3; Table 2 does not read it).

notebook_stage(
    "noise",
    "One chunk of noise runs at one level: noisy train targets, train, distance to theta*.",
    jobs=[
        {"noise_level": level, "chunk": chunk} for level in NOISE_LEVELS for chunk in range(-(-N_RUNS // CHUNK_SIZE))
    ],
    job="noise_level{noise_level}_chunk{chunk}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE, best=BEST_FILE),
    output=dict(
        chunk_file=result("noise/level{noise_level}_chunk{chunk}.csv"),
        timing_file=result("noise/level{noise_level}_chunk{chunk}_seconds.json"),
    ),
    params=dict(**training(seed=config["noise"]["seed"]), noise_level=wildcard("noise_level", int), **chunk_runs()),
    runtime=15,
)
