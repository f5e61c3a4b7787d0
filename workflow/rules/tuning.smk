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
        n_epoch=tuning_value("n_epoch"),
        lr=tuning_value("lr"),
        s=config["train"]["s"],
        batch_size=config["train"]["batch_size"],
        lr_decay=config["train"]["lr_decay"],
        seed=config["train"]["seed"],
        shift=config["sky"]["shift"],


use rule notebook_stage as best with:
    """Collect the grid (Table 1) and pick the cell with the lowest dev loss."""
    input:
        source=notebook("best"),
        cells=tuning_files("cell"),
        histories=tuning_files("history"),
    output:
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        best_history=result("tuning/best_history.csv"),
        html=html("best"),
    log:
        **notebook_log("best"),
    benchmark:
        benchmark_file("best")
