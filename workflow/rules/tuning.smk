# Table 1: one training run per (n_epoch, lr) cell, scored by the dev loss; then the best cell.


use rule notebook_stage as tune with:
    """Train on the train set with one cell of the grid; score it on the dev set."""
    input:
        source=notebook("tune"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
    output:
        cell=result("tuning/cell_{n_epoch}_{lr}.json"),
        history=result("tuning/history_{n_epoch}_{lr}.csv"),
        html=html("tune_{n_epoch}_{lr}"),
    log:
        **notebook_log("tune_{n_epoch}_{lr}"),
    benchmark:
        benchmark_file("tune_{n_epoch}_{lr}")
    params:
        **training(seed=config["train"]["seed"]),
        n_epoch=tuning_value("n_epoch"),
        lr=tuning_value("lr"),


use rule notebook_stage as best with:
    """Collect the grid (Table 1) and pick the cell with the lowest dev loss."""
    input:
        source=notebook("best"),
        cells=each("tune", "cell"),
        histories=each("tune", "history"),
    output:
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        best_history=result("tuning/best_history.csv"),
        html=html("best"),
    log:
        **notebook_log("best"),
    benchmark:
        benchmark_file("best")
