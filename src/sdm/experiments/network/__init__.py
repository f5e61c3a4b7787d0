"""SDM inside a network: a CNN that reads a configuration's images and outputs its shift, trained without labels.

Each configuration ``i`` has its own shift ``theta*_i = (a, b)`` (metres), drawn as Table 6's "a shift per
configuration" (:class:`sdm.sharing.TruthDistribution`); its target ``L_i`` is rendered from it and gets
Table 2's noise. A small CNN (:class:`ShiftNet`) reads two ``H x W`` images of the configuration and
outputs ``theta_i``:

* channel 0: the target ``L_i`` (1 where active);
* channel 1: ``Q_i`` rendered at zero shift, as inverse depth ``DEPTH_SCALE / z`` of the nearest point in each
  pixel (0 where empty). A point at depth ``z`` moves ``f' a / z`` pixels for a shift ``a``: the inverse
  depth tells the network how far each pixel's point moves.

The losses it is trained with (:data:`LOSSES`), the same architecture, data, initialisation seed and epochs:

* ``sdm_paper``, ``sdm_closed_centred_r1``: the SDM layer's loss on ``Q_i + theta_i`` against ``L_i``; its backward
  is the dynamic gradient flow, carried by autograd through ``theta_i`` into the weights. No labels. The zoom
  level goes from ``s`` to 0 over the epochs (:func:`epoch_zooms`). The paper's rule, or ``closed_centred_r1``
  (the rule of the recommended schedule's first pass).
* ``silhouette``: the soft-silhouette image loss (:mod:`sdm.experiments.baselines.silhouette`), coarse to fine on the same
  levels. No labels.
* ``chamfer``: the two-way 2D Chamfer distance (:mod:`sdm.experiments.baselines.chamfer`). No labels.
* ``supervised``: the mean squared distance to ``theta*_i``: what labels buy.

Every optimiser is Adam at one learning rate with a cosine decay over the steps. Training mixes the noise
levels: each training (and dev) configuration carries one level, drawn with the split's seed, because a
network in use does not know the noise of the image it reads.

Tensors: points float64 metres on the set's device; images float32; ``theta`` float64 metres, ``(N, 2)``.

The package: :mod:`.data` (the split, the shifts, the images), :mod:`.model` (the network, its weights file),
:mod:`.losses`, :mod:`.training`, :mod:`.evaluation` (test time, the flow's bias).
"""
from __future__ import annotations

from .data import (DEPTH_SCALE, PARTS, ShiftSet, mixed_noise_levels, network_images, read_sets, shift_set, split_three,
                   training_seed)
from .evaluation import (BIAS_LOSSES, NO_RUN, NOTHING, SEARCHES, loss_bias, refine, refine_settings, refine_steps,
                         test_methods)
from .losses import LOSSES, SDM_RULES, BatchLoss, NetworkSettings, epoch_zooms
from .model import ShiftNet, load_weights, parameter_count, save_weights, weights_digest
from .training import TrainedNetwork, deterministic, distances, network_settings, predict, train_network

__all__ = ["BIAS_LOSSES", "BatchLoss", "DEPTH_SCALE", "LOSSES", "NO_RUN", "NOTHING", "NetworkSettings", "PARTS",
           "SDM_RULES", "SEARCHES", "ShiftNet", "ShiftSet", "TrainedNetwork", "deterministic", "distances",
           "epoch_zooms", "load_weights", "loss_bias", "mixed_noise_levels", "network_images", "network_settings",
           "parameter_count", "predict", "read_sets", "refine", "refine_settings", "refine_steps", "save_weights",
           "shift_set", "split_three", "test_methods", "train_network", "training_seed", "weights_digest"]
