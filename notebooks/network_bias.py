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
# # Table 7: where the SDM flow vanishes on the test set
#
# A network trained through SDM settles, on average, where the flow's mean over its training configurations
# vanishes. Per noise level and rule, the flow per point at each test configuration's own theta* (its bias) and
# its change per metre near theta* (its stiffness) give that place's offset from theta*, as `rule_bias` measures
# it for the shared shift (`sdm.network.flow_bias`; docs/method/network.md).

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input
bias_file = "results/research/network/bias.csv"  # output
sizes = [3000, 500, 748]
seed = 0
levels = [0, 1, 2, 3, 4]
camera_sd = 0.15
s = 2  # research.network.train.s: the chain's coarsest level
threads = 1

# %%
import pandas as pd
from IPython.display import display

from sdm.experiments import single_thread
from sdm.io import write_csv
from sdm.network import SDM_RULES, flow_bias, read_sets

single_thread(threads)
rows = []
for level in levels:
    test = read_sets(sky, sizes, seed, levels, camera_sd, parts=["test"], test_level=level)["test"]
    rows += [flow_bias(test, level, rule, s) for rule in SDM_RULES.values()]
bias = pd.DataFrame(rows)
write_csv(bias_file, bias)
display(bias.round(4))
