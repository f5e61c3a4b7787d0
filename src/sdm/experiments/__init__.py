"""The paper's experiments, apart from the layer: every table's drivers, the baselines, the network study, the
report. They need the ``experiments`` extra (pandas, matplotlib); the layer (``import sdm``) does not.

- :mod:`sdm.experiments.runs`: the split, the tuning cells and the seeded noise runs (Tables 1, 2, 4 and 5).
- :mod:`sdm.experiments.bias`: where a rule's flow vanishes, per noise level and zoom.
- :mod:`sdm.experiments.data`: the Sky set from ApolloCar3D frames or synthetic scenes.
- :mod:`sdm.experiments.baselines`: Table 3's methods and the floor.
- :mod:`sdm.experiments.objects`, :mod:`sdm.experiments.gate`, :mod:`sdm.experiments.identifiability`: Table 6.
- :mod:`sdm.experiments.network`: Table 7, SDM inside a network.
- :mod:`sdm.experiments.report`: the tables, figures and words of the report; :mod:`sdm.experiments.paper`: the
  paper's published numbers.

The workflow's notebooks narrate and call these; nothing here is specific to
Snakemake. Every random choice takes an explicit seed, so a stage gives the
same numbers whenever and wherever it runs:

- the image sample is :func:`sdm.experiments.data.sample_indices` (the data layer's, which
  :func:`sdm.experiments.data.build_sky_dataset` uses too); the split uses a ``torch.Generator``
  seeded with the config's seed;
- the seed flows one way: the experiment's seed is ``settings.seed``; noise run
  ``run`` at ``noise_level`` trains with :func:`run_seed` ``(settings.seed, noise_level, run)``,
  which fixes both the noise drawn on its training targets and the shuffling of
  its mini-batches (and is reported in its row).
"""
from .bias import DEPTH_BIAS_COLUMNS, depth_bias, flow_at_true_shift, rule_bias
from .runs import (DEPTH_RUN_COLUMNS, NOISE_GROUP_SIZE, RUN_COLUMNS, depth_noise_runs, load_split, noise_runs,
                   noisy_targets, paired_runs, rule_noise_runs, run_seed, settings_for, shift_record, single_thread,
                   split_indices, train_group, tune_cell, tuned_training)

__all__ = ["DEPTH_BIAS_COLUMNS", "DEPTH_RUN_COLUMNS", "NOISE_GROUP_SIZE", "RUN_COLUMNS", "depth_bias", "depth_noise_runs",
           "flow_at_true_shift", "load_split", "noise_runs", "noisy_targets", "paired_runs", "rule_bias",
           "rule_noise_runs", "run_seed", "settings_for", "shift_record", "single_thread", "split_indices",
           "train_group", "tune_cell", "tuned_training"]
