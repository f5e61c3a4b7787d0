"""The schedule's refinement passes (closed_centred_r1, then group_crossing at zoom 0), counted in SGD steps."""
from dataclasses import replace

import pytest
import torch

from scenes import configuration_set
from sdm.errors import SDMInputError
from sdm.mapping import native
from sdm.experiments import noisy_targets, train_group
from sdm.sky import SKY_SHIFT
from sdm.train import Refinement, TrainSettings, parse_schedule, refine_runs, refine_seed, train_runs

BASE = TrainSettings(lr=1e-4, n_epoch=1, s=4, rule="closed_centred_r1")
#: An epoch of the 64-configuration set: its passes below are one epoch each (pass_steps = PER_EPOCH).
PER_EPOCH = 64 // 16


@pytest.fixture(scope="module")
def small():
    return configuration_set(64, seed=11)


def test_refined_runs_packed_equal_each_run_refined_alone(small):
    """Three runs refined together (R = 3, packed steps) have each run's history refined alone (R = 1) to the bit:
    group_crossing's flow values are exact binary fractions, so the packed sum cannot round otherwise."""
    settings = [replace(BASE, seed=seed) for seed in (4, 9, 4)]
    targets = [noisy_targets(small.targets, 2, 1), noisy_targets(small.targets, 1, 5), small.targets]
    refinement = Refinement("group_crossing", 3, pass_steps=PER_EPOCH)
    together = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    main_steps = 5 * (64 // 16)
    assert together.theta.shape == (main_steps + 3 * (64 // 16) + 1, 3, 2)
    for run, (one, run_targets) in enumerate(zip(settings, targets)):
        alone = refine_runs(small, [run_targets], [one], train_runs(small, [run_targets], [one]), refinement)
        assert torch.equal(together.theta[:, run], alone.theta[:, 0]), run
    assert not torch.equal(together.theta[main_steps:, 0], together.theta[main_steps, 0].expand(4 * 3 + 1, 2))


@pytest.mark.skipif(not native.enabled(), reason="no C compiler: the compiled kernel is not built")
def test_the_compiled_refinement_equals_the_torch_path_bit_for_bit(small, monkeypatch):
    """The passes run in one sdm_train call (zooms 0, 0, ...; group_crossing's mode) and give the torch
    path's theta history to the bit and its loss (the mismatch count) exactly."""
    settings = [replace(BASE, seed=seed) for seed in (3, 8)]
    targets = [noisy_targets(small.targets, 3, 2), noisy_targets(small.targets, 1, 6)]
    refinement = Refinement("group_crossing", 3, pass_steps=PER_EPOCH)
    calls = []
    program = native.train_program
    monkeypatch.setattr(native, "train_program", lambda *args, **kwargs: calls.append(1) or program(*args, **kwargs))
    compiled = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    assert len(calls) == 2
    monkeypatch.setattr(native, "enabled", lambda: False)
    torch_path = refine_runs(small, targets, settings, train_runs(small, targets, settings), refinement)
    assert len(calls) == 2
    assert torch.equal(compiled.theta, torch_path.theta)
    main_steps = 5 * (64 // 16)  # before: closed_centred_r1's loss in metres, summed in another order
    scale = float(torch_path.loss[:main_steps].abs().max())
    assert float((compiled.loss[:main_steps] - torch_path.loss[:main_steps]).abs().max()) <= 1e-12 * scale
    assert torch.equal(compiled.loss[main_steps:], torch_path.loss[main_steps:])
    assert bool((compiled.loss[main_steps:] == compiled.loss[main_steps:].round()).all())  # pixel counts


def test_refinement_passes_continue_the_halving_at_the_finest_zoom(small):
    """Pass i runs at zoom ``zoom``, at four times the last zoom's rate times lr_decay^i (rate_from 2), shuffled by
    its own seed; rate_from 1 starts at twice the last zoom's."""
    history = train_group(small, [small.targets], BASE, [7], refine=Refinement("group_crossing", 3, pass_steps=PER_EPOCH))
    per_pass = 64 // 16
    assert history.zoom[-3 * per_pass:].tolist() == [0] * (3 * per_pass)
    rates = history.lr[-3 * per_pass:].reshape(3, per_pass)
    # widths 8, 4, 2e-3 m, every pass at the halving rate whatever its width
    assert Refinement("group_crossing", 3).widths == [8e-3, 4e-3, 2e-3]
    assert rates[:, 0].tolist() == [1e-4 * 0.5**2, 1e-4 * 0.5**3, 1e-4 * 0.5**4]
    assert Refinement("group_crossing", 2, rate_from=1).rates(BASE) == [1e-4 * 0.5**3, 1e-4 * 0.5**4]
    one_width = Refinement("group_crossing", 3, first_width=2e-3)
    assert one_width.rates(BASE) == Refinement("group_crossing", 3).rates(BASE)
    assert Refinement("paper", 2).rates(BASE) == [1e-4 * 0.5**2, 1e-4 * 0.5**3]  # no kernel: the plain rates
    assert bool((rates == rates[:, :1]).all())
    assert refine_seed(7) != 7 and refine_seed(7) != refine_seed(8)


def test_refinement_keeps_the_true_shift_without_noise(small):
    """Started at theta* on noise-free targets, group_crossing's passes do not move it (exact fixed point)."""
    settings = BASE
    start = train_runs(small, [small.targets], [settings], theta0=[SKY_SHIFT])
    assert torch.equal(start.theta[-1, 0], torch.tensor(SKY_SHIFT, dtype=torch.float64))
    stay = refine_runs(small, [small.targets], [settings], start, Refinement("group_crossing", 2, pass_steps=PER_EPOCH))
    moved = (stay.theta[len(start.theta):, 0] - torch.tensor(SKY_SHIFT, dtype=torch.float64)).abs().max()
    assert float(moved) == 0


def test_the_refinement_moves_c_with_fit_depth_unless_told_not_to(small):
    """With fit_depth the schedule holds c below depth_zoom (1); the refinement's zoom-0 passes move it
    (moves_c, the default) at depth_lr_scale times their rate, or leave it where the schedule put it."""
    settings = [replace(BASE, seed=5, fit_depth=True)]
    targets = [noisy_targets(small.targets, 2, 3)]
    history = train_runs(small, targets, settings)
    per_pass = 64 // 16
    moving = refine_runs(small, targets, settings, history, Refinement("group_crossing", 2, pass_steps=PER_EPOCH))
    held = refine_runs(small, targets, settings, history, Refinement("group_crossing", 2, moves_c=False, pass_steps=PER_EPOCH))
    end = history.theta[-1, 0]
    assert bool((held.theta[-2 * per_pass:, 0, 2] == end[2]).all())
    assert float((moving.theta[-1, 0, 2] - end[2]).abs()) > 0
    # (a, b) move in both; the held run's passes are the moving run's with the c column's rate at zero
    assert not torch.equal(held.theta[-1, 0, :2], end[:2])


@pytest.mark.parametrize("kwargs,match", [({"rule": "no-such"}, "rule"), ({"passes": 0}, "passes"),
                                          ({"passes": 2.0}, "passes"), ({"passes": True}, "passes"),
                                          ({"pass_steps": 0}, "pass_steps"), ({"pass_steps": 32.0}, "pass_steps"),
                                          ({"pass_steps": False}, "pass_steps"), ({"pass_steps": "32"}, "pass_steps"),
                                          ({"rate_from": -1}, "rate_from"), ({"rate_from": 1.5}, "rate_from"),
                                          ({"moves_c": 1}, "moves_c"), ({"first_width": 0.0}, "first_width"),
                                          ({"first_width": -1e-3}, "first_width"),
                                          ({"last_width": float("nan")}, "last_width"),
                                          ({"last_width": float("inf")}, "last_width"),
                                          ({"first_width": "16e-3"}, "first_width"), ({"last_width": True}, "last_width"),
                                          ({"first_width": 1e-3, "last_width": 2e-3}, "first_width")])
def test_bad_refinements_are_refused_naming_the_field(kwargs, match):
    with pytest.raises(SDMInputError, match=match):
        Refinement(**kwargs)


def test_the_kernel_narrows_by_halves_to_the_last_width_on_the_last_pass():
    """Refinement.widths: last_width on the last pass, twice the next pass's before it, at most first_width; one width
    on every pass where the two are equal."""
    assert Refinement("group_crossing", 4).widths == [16e-3, 8e-3, 4e-3, 2e-3]
    assert Refinement("group_crossing", 6).widths == [16e-3, 16e-3, 16e-3, 8e-3, 4e-3, 2e-3]
    assert Refinement("group_crossing", 1).widths == [2e-3]
    assert Refinement("group_crossing", 3, first_width=5e-3, last_width=1e-3).widths == [4e-3, 2e-3, 1e-3]
    assert Refinement("group_crossing", 2, first_width=3e-3, last_width=3e-3).widths == [3e-3, 3e-3]
    assert parse_schedule("closed_centred_r1+group_crossing:4")[1].widths == [16e-3, 8e-3, 4e-3, 2e-3]


@pytest.mark.parametrize("compiled", [True, False])
def test_the_passes_widths_equal_the_reference_loop_bit_for_bit(small, monkeypatch, compiled):
    """Each pass at its own kernel half-width (16, 8, 4, 2e-3 m), on the compiled path (one sdm_train call for every
    pass) and on the torch path: each run's theta history and loss are tests/train_reference.py's, run over the
    zooms 0, 0, 0, 0 with a group_crossing rule of each pass's width at each pass's rate, shuffled by the run's
    refine_seed generator. The widths matter: the same passes at 2e-3 m alone end elsewhere."""
    from train_reference import reference_train

    if compiled and not native.enabled():
        pytest.skip("no C compiler: the compiled kernel is not built")
    if not compiled:
        monkeypatch.setattr(native, "enabled", lambda: False)
    calls = []
    program = native.train_program
    monkeypatch.setattr(native, "train_program", lambda *args, **kwargs: calls.append(1) or program(*args, **kwargs))
    settings = [replace(BASE, seed=seed) for seed in (3, 8)]
    targets = [noisy_targets(small.targets, 3, 2), noisy_targets(small.targets, 1, 6)]
    refinement = Refinement("group_crossing", 4, pass_steps=PER_EPOCH)
    history = train_runs(small, targets, settings)
    refined = refine_runs(small, targets, settings, history, refinement)
    assert len(calls) == (2 if compiled else 0)
    main_steps = history.theta.shape[0] - 1
    for run, (one, run_targets) in enumerate(zip(settings, targets)):
        passes = replace(one, rule="group_crossing", seed=refine_seed(one.seed), n_epoch=1)
        theta, loss = reference_train(small.with_targets(run_targets), passes, theta0=history.theta[-1, run],
                                      zooms=[0] * 4, rates=refinement.rates(one), crossing_widths=refinement.widths)
        assert torch.equal(refined.theta[main_steps:, run], theta), run
        assert torch.equal(refined.loss[main_steps:, run], loss), run
    narrow = refine_runs(small, targets, settings, history, replace(refinement, first_width=2e-3))
    assert not torch.equal(narrow.theta[-1], refined.theta[-1])


@pytest.mark.parametrize("name,expected", [
    ("closed_centred_r1", ("closed_centred_r1", None)),
    ("closed_centred_r1+group_crossing:3", ("closed_centred_r1", Refinement("group_crossing", 3))),
    ("paper+group_crossing", ("paper", Refinement("group_crossing", 4))),
])
def test_schedules_are_parsed_by_name(name, expected):
    assert parse_schedule(name) == expected


@pytest.mark.parametrize("name,match", [("closedd", "rule"), ("paper+nope:2", "rule"), ("paper+group_crossing:0", ":"),
                                        ("paper+group_crossing:x", ":"), (3, "schedule")])
def test_bad_schedules_are_refused_naming_the_part(name, match):
    with pytest.raises(SDMInputError, match=match):
        parse_schedule(name)


def test_a_pass_counts_sgd_steps_whatever_the_size_of_the_training_set(small):
    """A pass is pass_steps SGD steps: on 64 configurations (4 steps an epoch) a pass of 8 steps is two epochs at
    one rate, and the refinement's steps do not change with the set's size (40 configurations: 2 steps an epoch)."""
    refinement = Refinement("group_crossing", 3, pass_steps=8)
    assert refinement.steps == 24
    for configs in (small, small.subset(range(40))):
        history = train_group(configs, [configs.targets], BASE, [7], refine=refinement)
        main_steps = 5 * (len(configs) // 16)
        assert history.theta.shape == (main_steps + 24 + 1, 1, 2)
        assert history.zoom[main_steps:].tolist() == [0] * 24
        assert history.lr[main_steps:].tolist() == [rate for rate in refinement.rates(BASE) for _ in range(8)]


def test_passes_of_whole_epochs_are_the_epochs_of_one_program(small):
    """Where an epoch's steps divide pass_steps, the passes are whole epochs in one program: 2 passes of 8 steps on
    64 configurations are the 4 epochs of the run's refine_seed generator, at the pass's rate (one sdm_train call
    on the compiled path), the same steps as 4 one-epoch passes at those rates."""
    settings = [replace(BASE, seed=seed) for seed in (2, 6)]
    targets = [noisy_targets(small.targets, 2, 4), noisy_targets(small.targets, 1, 8)]
    history = train_runs(small, targets, settings)
    two = refine_runs(small, targets, settings, history, Refinement("group_crossing", 2, pass_steps=8))

    class Halving(Refinement):  # four one-epoch passes, the rate and the kernel width halving every second one
        def rates(self, one):
            return [rate for rate in Refinement("group_crossing", 2).rates(one) for _ in range(2)]

        @property
        def widths(self):
            return [width for width in Refinement("group_crossing", 2).widths for _ in range(2)]

    four = refine_runs(small, targets, settings, history, Halving("group_crossing", 4, pass_steps=PER_EPOCH))
    assert torch.equal(two.theta, four.theta) and torch.equal(two.lr, four.lr)


def test_a_pass_that_ends_inside_an_epoch_is_cut_after_its_steps(small):
    """pass_steps 6 on 64 configurations (4 steps an epoch): each pass trains two epochs and keeps its first 6 steps;
    the next pass starts from the 6th step's theta with the next epochs' shufflings. Held to the passes run one by
    one by hand from the same shufflings."""
    from tqdm.std import tqdm

    from sdm.train.engine import shufflings as _shufflings, train_steps as _train_program

    settings = [replace(BASE, seed=seed) for seed in (3, 5)]
    targets = [noisy_targets(small.targets, 3, 1), noisy_targets(small.targets, 1, 2)]
    history = train_runs(small, targets, settings)
    refinement = Refinement("group_crossing", 2, pass_steps=6)
    cut = refine_runs(small, targets, settings, history, refinement)
    assert cut.theta.shape[0] == history.theta.shape[0] + 12
    orders = _shufflings([refine_seed(one.seed) for one in settings], 64, 4)
    passes = [replace(one, rule="group_crossing", depth_zoom=one.zoom) for one in settings]
    theta = history.theta[-1]
    for index, (rate, width) in enumerate(zip(refinement.rates(passes[0]), refinement.widths)):
        steps, _ = _train_program(small, targets, [False, False], passes, small.camera, "fast", [0, 0], [rate, rate],
                                  orders[2 * index : 2 * index + 2], theta, tqdm(disable=True), widths=[width, width])
        start = history.theta.shape[0] + 6 * index
        assert torch.equal(cut.theta[start : start + 6], steps[1:7]), index
        theta = steps[6]


@pytest.mark.parametrize("width", [0.0, -2e-3, float("nan"), float("inf"), "2e-3", True])
def test_a_bad_kernel_width_is_refused_naming_it(width):
    from sdm.mapping.rules import crossing_width_rule

    with pytest.raises(SDMInputError, match="^width must be a positive finite number of metres"):
        crossing_width_rule("group_crossing", width)


def test_only_group_crossing_reads_a_width():
    """A width builds group_crossing at that width; the rule's own width, no width and every other rule give the
    registered rule itself."""
    from sdm import FLOW_RULES
    from sdm.mapping.crossing import CROSSING_WIDTH
    from sdm.mapping.rules import crossing_width_rule

    assert crossing_width_rule("group_crossing", None) is FLOW_RULES["group_crossing"]
    assert crossing_width_rule("group_crossing", CROSSING_WIDTH) is FLOW_RULES["group_crossing"]
    assert crossing_width_rule("paper", 16e-3) is FLOW_RULES["paper"]
    assert crossing_width_rule("group_crossing", 16e-3) is not FLOW_RULES["group_crossing"]
