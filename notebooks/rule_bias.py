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
# # Beyond the paper, Table 4: where each gradient rule's flow vanishes
#
# SGD stops moving on average where a rule's mean flow vanishes. Near theta* the flow per configuration is
# about `bias + stiffness * (theta - theta*)` per axis, so it vanishes `-bias / stiffness` from theta*
# (`sdm.experiments.rule_bias`): the bias is the flow at theta* on run 0's noisy targets of each level (the
# draw of Table 2's run 0), the stiffness its central difference over theta* +- 1e-3 m on the same draw, both
# at the last level (zoom 0). For a schedule, its last rule (the refinement's) is measured: the one whose fixed
# point the runs end at. The paper's rule is measured beside the rules of Table 4. The stage `table4` sets the
# predicted offset beside each rule's measured mean distance. It needs no run of Tables 2 or 4, so it runs
# beside them.

# %% tags=["parameters"]
sky = "results/sky/sky.bin"  # input: the training set
split = "results/split/split.json"  # input
table4_bias = "results/tables/table4_bias.csv"  # output: one row per (rule, level)
names = ["closed"]  # Table 4's rules or schedules (research.rules.names); the paper's rule is measured too
noise_levels = [0, 1, 2, 3, 4]  # the noise levels
s = 4  # zoom levels (train.s)
seed = 0  # noise seed (noise.seed): run 0's draw of each level
shift = [0.517, 0.303]  # (a*, b*), metres
threads = 1

# %%
import pandas as pd
from IPython.display import display

from sdm.experiments import load_split, rule_bias, single_thread
from sdm.experiments.report.io import read_json, write_csv

single_thread(threads)
train_set, _, camera = load_split(sky, read_json(split))
bias = pd.concat([rule_bias(train_set, rule, noise_levels, seed, s=s, shift=shift, camera=camera).assign(rule=rule)
                  for rule in ["paper", *names]], ignore_index=True)
bias = bias[["rule", *bias.columns.drop("rule")]]
write_csv(table4_bias, bias)
display(bias)
