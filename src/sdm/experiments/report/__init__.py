"""Tables, figures and the reproduction report of the workflow, with the paper's numbers beside ours.

- the paper's numbers are :mod:`sdm.experiments.paper` (the one module that holds them);
- :mod:`sdm.experiments.report.tables`: Table 1/2 frames and CSV / Markdown / LaTeX writers;
- :mod:`sdm.experiments.report.figures`: Figures 1-4, theta's path, distance distributions;
- :mod:`sdm.experiments.report.reproduction`: the text of ``results/report/reproduction.md``;
- :mod:`sdm.experiments.report.verdict`: ``results/report/verdict.json``, the facts of the README's verdict;
- :mod:`sdm.experiments.report.io`: atomic file writes (:mod:`sdm.io` re-exported: a killed job never leaves a file
  that looks complete; files get the mode a plain open() gives them).
"""
