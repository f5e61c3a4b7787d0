"""Single-run references of the paired runs: one run at a time, each trained or fitted alone.

:func:`sdm.experiments.paired_runs` runs every table's runs in groups (Table 2's ``noise_runs``,
Table 4's ``rule_noise_runs``, Table 5's ``depth_noise_runs``, Table 3's ``sdm.experiments.baselines.baseline_noise_runs``);
these loops are what it replaced, kept here so that the tests can hold the driver to them: the run's
seed from :func:`~sdm.experiments.run_seed`, its noisy targets drawn alone, then :func:`sdm.train`
(or the method's ``fit``) on that run only. Rows as the driver's tables have them.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from sdm.experiments.baselines import fit
from sdm.depth import depth_targets
from sdm.experiments import noisy_targets, run_seed
from sdm.metrics import distance
from sdm.sky import SKY_SHIFT
from sdm.train import train


def noise_run(train_set, noise_level, run, settings, shift=SKY_SHIFT, camera=None) -> dict:
    """Table 2's run ``(level, run)`` alone: ``{"level", "run", "seed", "a", "b", "distance"}`` (metres)."""
    seed_run = run_seed(settings.seed, noise_level, run)
    noisy = train_set.with_targets(noisy_targets(train_set.targets, noise_level, seed_run))
    a, b = train(noisy, replace(settings, seed=seed_run), camera=camera, progress=False).final_theta
    return {"noise_level": int(noise_level), "run": int(run), "seed": seed_run, "a": float(a), "b": float(b),
            "distance": float(distance((a, b), tuple(shift)))}


def baseline_noise_run(name, train_set, noise_level, run, settings, seed, shift=SKY_SHIFT, camera=None) -> dict:
    """Table 3's run ``(level, run)`` of method ``name`` alone (``sdm.experiments.baselines.fit`` on Table 2's noisy targets)."""
    seed_run = run_seed(seed, noise_level, run)
    noisy = train_set.with_targets(noisy_targets(train_set.targets, noise_level, seed_run))
    result = fit(name, noisy, settings, seed_run, camera)
    a, b = result.theta
    return {"method": name, "noise_level": int(noise_level), "run": int(run), "seed": seed_run, "a": float(a), "b": float(b),
            "distance": distance((a, b), tuple(shift)), "seconds": result.seconds, "evaluations": result.evaluations}


def depth_noise_run(train_set, c, noise_level, run, settings, shift=SKY_SHIFT, camera=None) -> dict:
    """Table 5's run ``(c, level, run)`` alone: ``train`` with ``fit_depth`` on the noisy targets of ``(a*, b*, c)``."""
    truth = (float(shift[0]), float(shift[1]), float(c))
    seed_run = run_seed(settings.seed, noise_level, run)
    clean = depth_targets(train_set, truth, camera or train_set.camera)
    noisy = train_set.with_targets(noisy_targets(clean, noise_level, seed_run))
    fitted = train(noisy, replace(settings, fit_depth=True, seed=seed_run), camera=camera, progress=False).final_theta
    errors = [abs(value - true) for value, true in zip(fitted, truth)]
    return {"c_true": truth[2], "noise_level": int(noise_level), "run": int(run), "seed": seed_run,
            "a": fitted[0], "b": fitted[1], "c": fitted[2],
            "error_a": errors[0], "error_b": errors[1], "error_c": errors[2],
            "distance_ab": float(np.hypot(errors[0], errors[1])),
            "distance": float(np.sqrt(sum(error ** 2 for error in errors)))}
