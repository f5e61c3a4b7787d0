"""Training: SGD on the shift theta = (a, b) through the SDM layer (paper, section 6; docs/method/paper.md,
"Training and evaluation"), and the documented passes after it.

- :mod:`sdm.train.settings`: what a run is given and what it returns (:class:`TrainSettings`, :class:`Refinement`,
  :func:`parse_schedule`, :class:`History`, :class:`RunsHistory`).
- :mod:`sdm.train.engine`: the one training engine, :func:`train_runs` (``R`` runs as one program, compiled where
  the rule has a compiled form), and :func:`train`, the engine with ``R = 1``.
- :mod:`sdm.train.torch_path`: the engine's torch path (every device, every rule).
- :mod:`sdm.train.refine`: :func:`refine_runs`, a history continued by a :class:`Refinement`'s passes.
- :mod:`sdm.train.checks`: the one check of the engine's arguments and results.
"""
from .engine import train, train_runs
from .refine import refine_runs
from .settings import (THETA_BOUND, History, Refinement, RunsHistory, TrainSettings, parse_schedule, rates_per_point,
                       refine_seed)

__all__ = ["THETA_BOUND", "History", "Refinement", "RunsHistory", "TrainSettings", "parse_schedule", "rates_per_point",
           "refine_runs", "refine_seed", "train", "train_runs"]
