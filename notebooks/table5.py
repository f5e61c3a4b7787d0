# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Beyond the paper, Table 5: the shift with depth
#
# The runs of the stage `depth_runs` (one file per c* and noise level): per c* and level, the mean absolute
# errors of a, b and c and the distances to (a*, b*) and (a*, b*, c*). The bar, noise-free: a, b
# within 2e-3 m, c within 2e-2 m. Every expected (c*, level, run) must be there.

# %% tags=["parameters"]
depth_files = []  # input: the depth_runs files
shifts_c = [1.0]  # the c* expected
levels = [0, 1, 2, 3, 4]  # the levels expected
runs = 2  # the runs 0..runs-1 each (c*, level) must hold
table5_csv = "results/tables/table5.csv"  # output
table5_md = "results/tables/table5.md"  # output: written beside table5_csv, same stem
table5_tex = "results/tables/table5.tex"  # output: written beside table5_csv, same stem
table5_html = "results/tables/table5.html"  # output: written beside table5_csv, same stem (for the Snakemake report)
table5_summary = "results/tables/table5_summary.md"  # output: plain words, for the report
figure = "results/figures/research_depth.png"  # output
threads = 1

# %%
from pathlib import Path

from IPython.display import Markdown, display

from sdm.experiments import single_thread
from sdm.report.figures import show_figure
from sdm.report.io import write_text
from sdm.report.research import (
    TABLE5_FORMAT, depth_figure, gathered_runs, table5_display, table5_frame, table5_summary as summary_of_table5,
    write_research_table,
)
from sdm.report.tables import to_markdown

single_thread(threads)
expected = {(float(value), level, run) for value in shifts_c for level in levels for run in range(runs)}
depth_runs = gathered_runs(depth_files, ("c_true", "level", "run"), expected, "Table 5")
table5 = table5_frame(depth_runs)
written = write_research_table(table5, Path(table5_csv).with_suffix(""), 5)
assert {str(path) for path in written} == {table5_csv, table5_md, table5_tex, table5_html}, written
display(Markdown(to_markdown(table5_display(table5), TABLE5_FORMAT)))
show_figure(depth_figure(table5), figure)

# %% [markdown]
# ## In plain words (every number from the table above)

# %%
answer = summary_of_table5(table5)
write_text(table5_summary, answer)
display(Markdown(answer))
