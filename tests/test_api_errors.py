"""Gaps in the library's API that once surfaced as torch errors naming no argument, or passed silently.

Each call below gave a bare ``RuntimeError``/``IndexError``/``TypeError`` (or nothing at all) once;
now it raises :class:`sdm.errors.SDMInputError` naming the argument.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.sky import SKY_SHIFT, build_configuration
from sdm.train import TrainSettings


@pytest.fixture(scope="module")
def data():
    return configuration_set(5, seed=3)


# -- ConfigurationSet.batch / subset ------------------------------------------------------------------


@pytest.mark.parametrize("indices", [[-1], [0, -2], [5], [100], [0, 5]])
def test_batch_refuses_indices_outside_the_set_naming_them(data, indices):
    """[-1] gave 'repeats can not be negative' (a negative CSR count), [100] an IndexError about 'size 6'."""
    with pytest.raises(SDMInputError, match=r"indices must lie in \[0, 5\)"):
        data.batch(indices)
    with pytest.raises(SDMInputError, match=r"indices must lie in \[0, 5\)"):
        data.subset(indices)


@pytest.mark.parametrize("indices", [[0.5], [True, False], [[0, 1]], ["a"], 3, torch.tensor([1.0])])
def test_batch_refuses_what_is_not_a_list_of_integers(data, indices):
    """[0.5] was truncated to configuration 0 and [True] read as 1 without a word."""
    with pytest.raises(SDMInputError, match="indices must be a 1-D sequence of integers"):
        data.batch(indices)


def test_batch_takes_integers_of_any_kind_and_repeats(data):
    """Lists, tuples, numpy and torch integers; a configuration may appear twice; an empty batch is empty."""
    reference = data.batch([4, 0, 4])
    for same in ((4, 0, 4), np.array([4, 0, 4]), torch.tensor([4, 0, 4], dtype=torch.int32)):
        batch = data.batch(same)
        assert torch.equal(batch.points, reference.points) and torch.equal(batch.config, reference.config)
    assert reference.num_configs == 3 and torch.equal(reference.targets[0], reference.targets[2])
    assert data.batch([]).num_configs == 0 and len(data.subset([])) == 0


# -- TrainSettings --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("lr", "3e-4", "lr must be a number"),  # was TypeError: must be real number, not str
        ("lr", True, "lr must be a number"),
        ("lr_decay", "0.5", "lr_decay must be a number"),
        ("depth_lr_scale", None, "depth_lr_scale must be a number"),
        ("batch_size", True, "batch_size must be an integer"),  # was accepted as batch_size 1
        ("n_epoch", 2.0, "n_epoch must be an integer"),
        ("n_epoch", "2", "n_epoch must be an integer"),
        ("s", True, "s must be an integer"),
        ("zoom", False, "zoom must be an integer"),
        ("seed", "0", "seed must be an integer"),  # was accepted
        ("seed", 1.5, "seed must be an integer"),  # was accepted
        ("depth_zoom", 1.0, "depth_zoom must be an integer"),
        ("fit_depth", 1, "fit_depth must be True or False"),  # was accepted
        ("rule", ["paper"], "rule must be a rule"),
    ],
)
def test_train_settings_check_every_fields_type_naming_it(field, value, message):
    with pytest.raises(SDMInputError, match=message):
        TrainSettings(**{field: value})


def test_train_settings_take_numpy_numbers_and_ints_for_floats():
    settings = TrainSettings(lr=1, lr_decay=np.float64(0.5), n_epoch=np.int64(2), seed=np.int32(3))
    assert settings.lr == 1 and settings.n_epoch == 2 and settings.seed == 3
    with pytest.raises(SDMInputError, match="lr must be a positive finite number"):
        TrainSettings(lr=np.float64(math.nan))


# -- build_configuration's shift ------------------------------------------------------------------------


CENTRES = torch.tensor([[1.0, 3.0, 30.0]], dtype=torch.float64)


@pytest.mark.parametrize("shift", [(0.517, 0.303, 1.0), [0.5, 0.3, 0.0], torch.tensor([0.517, 0.303, 1.0])])
def test_build_configuration_refuses_a_depth_shift_naming_it(shift):
    """(a, b, c) was accepted and gave targets moved in depth, which a Sky configuration cannot record."""
    with pytest.raises(SDMInputError, match=r"shift must be \(a, b\).*depth_targets"):
        build_configuration(CENTRES, shift)


@pytest.mark.parametrize("shift", [torch.tensor([math.nan, 0.3]), (0.5, 0.3, 1.0, 2.0), "ab", 0.5])
def test_build_configuration_refuses_other_bad_shifts_naming_it(shift):
    with pytest.raises(SDMInputError, match="shift must be"):
        build_configuration(CENTRES, shift)


def test_build_configuration_takes_a_tensor_shift_as_the_same_numbers():
    reference = build_configuration(CENTRES, SKY_SHIFT)
    assert torch.equal(build_configuration(CENTRES, torch.tensor(SKY_SHIFT)).target, reference.target)
