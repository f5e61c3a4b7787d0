# Table 1: one training run per (n_epoch, lr) cell, scored by the dev loss; then the best cell.

notebook_stage(
    "tune",
    "Train on the train set with one cell of the grid; score it on the dev set.",
    jobs=[{"n_epoch": n_epoch, "lr": lr} for n_epoch, lr in TUNING_CELLS],
    job="tune_{n_epoch}_{lr}",
    input=dict(sky=SKY_FILE, split=SPLIT_FILE),
    output=dict(cell=result("tuning/cell_{n_epoch}_{lr}.json"), history=result("tuning/history_{n_epoch}_{lr}.csv")),
    params=dict(**training(seed=config["train"]["seed"]), n_epoch=tuning_value("n_epoch"), lr=tuning_value("lr")),
)

notebook_stage(
    "best",
    "Collect the grid (Table 1), pick the cell with the lowest dev loss, draw theta's path in its run.",
    input=dict(cells=each("tune", "cell"), histories=each("tune", "history")),
    output=dict(
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        best_history=result("tuning/best_history.csv"),
        theta_path=figure("theta_path", "theta_path"),
    ),
    params=dict(shift=config["sky"]["shift"]),
)
