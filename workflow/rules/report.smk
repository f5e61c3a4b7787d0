# Tables 1-2, the paper's figures and the reproduction report.


use rule notebook_stage as tables with:
    """Merge the noise runs; write Tables 1 and 2 with the paper's values beside ours."""
    input:
        source=notebook("tables"),
        grid=result("tuning/grid.csv"),
        best=BEST_FILE,
        stats=result("sky/stats.json"),
        chunks=each("noise", "chunk_file"),
    output:
        **table_files("table1"),
        **table_files("table2"),
        distances=result("noise/distances.csv"),
        html=html("tables"),
    log:
        **notebook_log("tables"),
    benchmark:
        benchmark_file("tables")
    params:
        levels=config["noise"]["levels"],
        runs=config["noise"]["runs"],


use rule notebook_stage as figures with:
    """Figures 1-4 of the paper, theta's path per zoom level, distances per noise level."""
    input:
        source=notebook("figures"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
        best=BEST_FILE,
        best_history=result("tuning/best_history.csv"),
        distances=result("noise/distances.csv"),
    output:
        fig1=figure("fig1_configuration", "fig1"),
        fig2=figure("fig2_forward", "fig2"),
        fig3=figure("fig3_backward", "fig3"),
        fig4=figure("fig4_noise", "fig4"),
        theta_path=figure("theta_path", "theta_path"),
        distances_plot=figure("distances", "distances"),
        html=html("figures"),
    log:
        **notebook_log("figures"),
    benchmark:
        benchmark_file("figures")
    params:
        example=config["figures"]["example"],
        noise_seed=config["figures"]["seed"],
        levels=config["noise"]["levels"],
        s=config["train"]["s"],
        shift=config["sky"]["shift"],


use rule notebook_stage as report with:
    """Compare every number with the paper and explain each gap."""
    input:
        **extra_tables_read_by_report(),
        source=notebook("report"),
        table1=result("tables/table1.csv"),
        table2=result("tables/table2.csv"),
        distances=result("noise/distances.csv"),
        stats=result("sky/stats.json"),
        summary=result("data/summary.json"),
        sky=SKY_FILE,
        split=SPLIT_FILE,
    output:
        report=report(result("report/reproduction.md"), caption="../report/reproduction.rst", category="Report"),
        html=html("report"),
    log:
        **notebook_log("report"),
    benchmark:
        benchmark_file("report")
    params:
        config=config_values(
            "data.source",
            *annotation_keys(),
            "sky.shift",
            "split.n_selected",
            "split.n_train",
            "split.n_dev",
            "train.s",
            "train.batch_size",
            "noise.levels",
            "noise.runs",
            "noise.seed",
        ),
