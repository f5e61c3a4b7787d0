"""SDM inside a network (sdm.experiments.network): the gradient that reaches the weights, training, determinism, bad input."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sdm.experiments import network as N
from sdm.batch import ConfigurationSet
from sdm.errors import SDMInputError
from sdm.mapping.layer import SpatialDomainMapping
from sdm.sharing import TruthDistribution
from sdm.sky import shift_vector

from scenes import configurations

TINY = N.NetworkSettings(epochs=3, batch_size=8, lr=(("default", 3e-3),), s=2, seed=5)


@pytest.fixture(scope="module")
def sets():
    """48 training and 16 dev configurations of synthetic scenes, each with its own shift and mixed noise."""
    data = ConfigurationSet.from_configurations(configurations(64, seed=43, mean_cars=3))
    train = N.shift_set(data.subset(range(48)), 1, N.mixed_noise_levels(48, [0, 1], 2))
    dev = N.shift_set(data.subset(range(48, 64)), 3, torch.zeros(16, dtype=torch.int64))
    return train, dev


@pytest.mark.parametrize("kind", N.SDM_RULES)
def test_the_weights_gradient_is_the_networks_vjp_of_the_layers_flow(sets, kind):
    """Autograd through the SDM loss gives the weights exactly the network's VJP of each configuration's summed
    point flows (the layer's own output, summed by hand), over its points (the mean pull per point)."""
    train, _ = sets
    torch.manual_seed(0)
    net = N.ShiftNet(train.data.camera.screen_shape).double()
    indices = torch.arange(8)
    noise_level = 1
    loss = N.BatchLoss(kind, train, TINY, torch.Generator().manual_seed(0))
    theta = net(N.network_images(train.data, indices).double())
    net.zero_grad()
    loss(theta, indices, noise_level).backward()
    through_autograd = [p.grad.clone() for p in net.parameters()]

    batch = train.data.batch(indices)
    layer = SpatialDomainMapping(train.data.camera, s=TINY.s, zoom=noise_level, rule=N.SDM_RULES[kind])
    points = batch.points + shift_vector(theta.detach().index_select(0, batch.config), batch.points)
    out = layer(points, batch.pixels, batch.targets, batch.config, batch.rank)
    flow = torch.zeros(len(indices), 2, dtype=torch.float64).index_add(0, batch.config, out.result.flow)
    assert bool(flow.abs().sum() > 0)  # the batch is pulled: the comparison means something
    flow = flow / train.data.counts.index_select(0, indices).double().unsqueeze(1)
    theta = net(N.network_images(train.data, indices).double())
    by_hand = torch.autograd.grad(theta, list(net.parameters()), grad_outputs=flow)
    for mine, reference in zip(through_autograd, by_hand):
        torch.testing.assert_close(mine, reference, rtol=1e-12, atol=1e-15)


#: A prior centred at zero shift, about 0.6 m from every theta* of the sets: a network in its units starts far.
FAR = TruthDistribution(centre=(0.0, 0.0))


def test_training_through_sdm_moves_the_dev_distance_down(sets):
    train, dev = sets
    start = N.distances(N.predict(_fresh(train, FAR), dev.data), dev.truth).mean()
    assert float(start) > 0.4
    trained = N.train_network("sdm_paper", train, dev, TINY, prior=FAR)
    assert float(trained.curve["dev_mean_m"].iloc[-1]) < 0.5 * float(start)
    assert list(trained.curve["zoom"]) == N.epoch_zooms(TINY.epochs, TINY.s) == [2, 1, 0]


def test_a_fresh_network_starts_at_the_priors_mean(sets):
    """Outputs in the prior's units: a fresh network's shifts lie within a few spreads of the prior's centre, and
    another centre moves them by exactly the difference."""
    train, dev = sets
    near, far = N.predict(_fresh(train), dev.data), N.predict(_fresh(train, FAR), dev.data)
    centre = torch.tensor(TruthDistribution().centre, dtype=torch.float64)
    assert float((near - centre).norm(dim=1).max()) < 3 * TruthDistribution().camera_sd
    torch.testing.assert_close(near - far, centre.expand_as(near), rtol=0, atol=1e-12)


def _fresh(train, prior: TruthDistribution = TruthDistribution()) -> N.ShiftNet:
    torch.manual_seed(TINY.seed)
    return N.ShiftNet(train.data.camera.screen_shape, centre=prior.centre, scale=prior.camera_sd)


@pytest.mark.parametrize("kind", ["sdm_closed_centred_r1", "chamfer"])
def test_the_same_settings_train_the_same_network(sets, kind):
    train, dev = sets
    first = N.train_network(kind, train, dev, TINY)
    second = N.train_network(kind, train, dev, TINY)
    assert first.curve.drop(columns="train_cpu_s").equals(second.curve.drop(columns="train_cpu_s"))
    for mine, other in zip(first.net.state_dict().values(), second.net.state_dict().values()):
        assert torch.equal(mine, other)


def test_every_loss_trains(sets):
    train, dev = sets
    short = N.NetworkSettings(epochs=1, batch_size=8, s=1, seed=1)
    for kind in N.LOSSES:
        curve = N.train_network(kind, train, dev, short).curve
        assert curve["dev_mean_m"].notna().all() and (curve["loss"] == kind).all()


def test_weights_round_trip(sets, tmp_path):
    train, dev = sets
    net = _fresh(train)
    path = N.save_weights(net, tmp_path / "net.pt")
    loaded = N.load_weights(path, train.data.camera.screen_shape)
    assert torch.equal(N.predict(net, dev.data), N.predict(loaded, dev.data))
    (tmp_path / "bad.pt").write_bytes(b"not a weights file")
    with pytest.raises(SDMInputError, match="bad.pt"):
        N.load_weights(tmp_path / "bad.pt", train.data.camera.screen_shape)
    with pytest.raises(SDMInputError, match="screen"):
        N.load_weights(path, (64, 128))


def test_a_damaged_or_non_finite_weights_file_is_refused_naming_it(sets, tmp_path):
    """On main a weights file with one flipped byte of a parameter, or a NaN weight, loaded."""
    train, _ = sets
    net = _fresh(train)
    path = N.save_weights(net, tmp_path / "net.pt")
    data = bytearray(path.read_bytes())
    weight = next(iter(net.state_dict().values())).detach().reshape(-1)[:4].numpy().tobytes()
    at = bytes(data).index(weight)  # the first parameter's first bytes, as stored
    data[at] ^= 0x10
    (tmp_path / "flipped.pt").write_bytes(bytes(data))
    with pytest.raises(SDMInputError, match=r"flipped\.pt: its weights do not match their SHA-256"):
        N.load_weights(tmp_path / "flipped.pt", train.data.camera.screen_shape)
    with torch.no_grad():
        next(iter(net.parameters())).view(-1)[0] = float("nan")
    N.save_weights(net, tmp_path / "nan.pt")
    with pytest.raises(SDMInputError, match=r"nan\.pt: weights \[.*\] hold values that are not finite"):
        N.load_weights(tmp_path / "nan.pt", train.data.camera.screen_shape)


def test_bad_input_is_named(sets):
    train, dev = sets
    net = _fresh(train)
    with pytest.raises(SDMInputError, match="images must have shape"):
        net(torch.zeros(2, 2, 64, 256))
    with pytest.raises(SDMInputError, match="images must have shape"):
        net(torch.zeros(2, 3, 128, 256))
    loss = N.BatchLoss("sdm_paper", train, TINY, torch.Generator())
    with pytest.raises(SDMInputError, match="theta must have shape \\(4, 2\\)"):
        loss(torch.zeros(4, 3, dtype=torch.float64), torch.arange(4), 0)
    with pytest.raises(SDMInputError, match="theta must have shape \\(4, 2\\)"):
        loss(torch.zeros(3, 2, dtype=torch.float64), torch.arange(4), 0)
    with pytest.raises(SDMInputError, match="loss must be one of"):
        N.BatchLoss("l1", train, TINY, torch.Generator())
    empty = ConfigurationSet(train.data.points[:0], train.data.pixels[:0], torch.zeros(2, dtype=torch.int64),
                             train.data.targets[:1], train.data.camera)
    with pytest.raises(SDMInputError, match="configuration 0 is empty"):
        N.shift_set(empty, 0, [0])
    with pytest.raises(SDMInputError, match="levels must hold one noise level per configuration"):
        N.shift_set(train.data, 0, [0, 1])
    with pytest.raises(SDMInputError, match="sizes"):
        N.split_three(100, (50, 50, 50), 0)
    with pytest.raises(SDMInputError, match="epochs"):
        N.NetworkSettings(epochs=0)
    with pytest.raises(SDMInputError, match="one batch"):
        N.train_network("supervised", dev, dev, N.NetworkSettings(batch_size=32))


def test_split_is_seeded_and_disjoint():
    split = N.split_three(100, (60, 20, 20), 7)
    assert split == N.split_three(100, (60, 20, 20), 7) != N.split_three(100, (60, 20, 20), 8)
    assert sorted(split["train"] + split["dev"] + split["test"]) == list(range(100))


def test_epoch_levels_go_coarse_to_fine():
    assert N.epoch_zooms(8, 2) == [2, 1, 0, 0, 0, 0, 0, 0]
    assert N.epoch_zooms(2, 4) == [1, 0]
    assert N.epoch_zooms(5, 0) == [0] * 5


def _frame(means: dict, noise_level: int, cpu: dict[str, float]) -> "pd.DataFrame":
    """test_methods' rows at one level: ``means`` maps a method to its mean distance, one per run (a list) for a
    network, one value for the others; each configuration's error lies along a."""
    import pandas as pd

    frames = []
    for method, values in means.items():
        runs = list(enumerate(values)) if isinstance(values, list) else [(N.NO_RUN, values)]
        for run, mean in runs:
            frames.append(pd.DataFrame({"noise_level": noise_level, "method": method, "run": run, "config": range(4),
                                        "distance": [mean] * 4, "error_a": [mean] * 4, "error_b": 0.0,
                                        "cpu_s": cpu.get(method, 1e-4)}))
    return pd.concat(frames, ignore_index=True)


def _curves(losses, runs: int, seconds: float = 10.0) -> list:
    import pandas as pd

    return [pd.DataFrame({"loss": [loss], "run": [run], "epoch": [1], "dev_mean_m": [0.1], "train_cpu_s": [seconds]})
            for loss in losses for run in range(runs)]


def test_table7_gives_each_network_its_runs_mean_spread_and_paired_difference():
    """Per (level, method): the runs' mean and sample sd, and each run's difference to the SDM-trained network of
    the same run: a run that is bad for every loss (run 2) moves the means and not the paired differences."""
    from sdm.experiments.report.network import table7

    means = {"net:sdm_closed_centred_r1": [0.050, 0.060, 0.090], "net:silhouette": [0.052, 0.063, 0.094],
             "net+k:sdm_closed_centred_r1": [0.02, 0.02, 0.02], "net+k:silhouette": [0.03, 0.01, 0.02],
             "cmaes": 0.015, "train_mean": 0.2}
    cpu = {"cmaes": 0.05, "net+k:sdm_closed_centred_r1": 1e-3}
    table = table7([_frame(means, 0, cpu)], _curves(("sdm_closed_centred_r1", "silhouette"), 3, seconds=98.0))
    assert list(table["method"]) == ["train_mean", "net:sdm_closed_centred_r1", "net:silhouette", "net+k:sdm_closed_centred_r1",
                                     "net+k:silhouette", "cmaes"]
    row = table.set_index("method").loc["net:silhouette"]
    assert row["runs"] == 3 and row["mean_m"] == pytest.approx(0.209 / 3)
    assert row["sd_m"] == pytest.approx(float(np.std([0.052, 0.063, 0.094], ddof=1)))
    assert row["diff_m"] == pytest.approx(0.003) and row["diff_min_m"] == pytest.approx(0.002)
    assert row["diff_max_m"] == pytest.approx(0.004) and row["diff_sd_m"] == pytest.approx(0.001)
    assert row["offset_m"] == pytest.approx(row["mean_m"])  # every error along a
    mine = table.set_index("method").loc["net+k:sdm_closed_centred_r1"]
    assert np.isnan(mine["diff_m"]) and mine["train_s"] == 98.0
    # 98 s of training saves 49 ms per configuration: 2000 configurations cost the same, 2001 less
    assert mine["pays_off"] == 2001
    assert np.isnan(table.set_index("method").loc["cmaes", "pays_off"])
    assert table.set_index("method").loc["cmaes", "runs"] == 1


@pytest.mark.parametrize("silhouette, word, moonshot", [
    ([0.052, 0.063, 0.094], "closer at level 0", "met"),  # every run's silhouette network farther
    ([0.052, 0.058, 0.094], "even at level 0", "missed"),  # run 1 the other way: level
    ([0.048, 0.058, 0.080], "farther at level 0", "missed"),
])
def test_table7_words_rank_only_beyond_the_runs_spread(silhouette, word, moonshot):
    from sdm.experiments.report.network import table7, table7_summary, verdict_facts

    means = {"net:sdm_closed_centred_r1": [0.050, 0.060, 0.090], "net:silhouette": silhouette, "train_mean": 0.2}
    table = table7([_frame(means, 0, {})], _curves(("sdm_closed_centred_r1", "silhouette"), 3))
    words = table7_summary(table, 4, {"epochs": 16, "per_epoch": 1024}, 3000)
    assert f"The SDM-trained network is {word}." in words
    assert f"beyond the runs' spread at every noise level**: {moonshot}" in words
    assert "16 epochs of 1024 configurations (drawn anew each epoch from 3000" in words
    facts = verdict_facts(table)["levels"][0]
    assert facts["paired"] == {"silhouette": word.split()[0]}
    assert facts["beats_image_losses"] == (moonshot == "met")


def test_table7_words_follow_the_numbers():
    """The summary's bars read the table: met where the numbers meet them, missed where they do not."""
    from sdm.experiments.report.network import table7, table7_summary, verdict_facts

    nets = {"net:sdm_closed_centred_r1": [0.05, 0.05], "net:silhouette": [0.08, 0.08], "net:chamfer": [0.09, 0.09],
            "net:supervised": [0.03, 0.03], "net+k:sdm_closed_centred_r1": [0.02, 0.02], "cmaes": 0.015, "sdm_zero": 0.04}
    worse = dict(nets, **{"net:sdm_closed_centred_r1": [0.07, 0.07]})  # level 2: 2.33x supervised
    cpu = {"cmaes": 0.05, "net+k:sdm_closed_centred_r1": 1e-4}
    curves = _curves(("sdm_closed_centred_r1", "silhouette", "chamfer", "supervised"), 2)
    table = table7([_frame(nets, 0, cpu), _frame(worse, 2, cpu)], curves)
    assert list(table["method"][:4]) == ["net:sdm_closed_centred_r1", "net:silhouette", "net:chamfer", "net:supervised"]
    words = table7_summary(table, 4, {"epochs": 16, "per_epoch": 0}, 3000)
    assert "level 0: 1.67x supervised's mean; level 2: 2.33x supervised's mean" in words
    assert "within 2x of supervised regression at levels 0 and 2: missed" in words
    assert "level 0: 1.33x CMA-ES's mean at 1/500 of its CPU time per configuration, cheaper than CMA-ES from " \
           "201 configurations on" in words
    assert "100x less CPU time: met" in words
    assert "16 epochs of 3000 configurations" in words
    found = verdict_facts(table)
    assert found["loss"] == "sdm_closed_centred_r1" and found["rule"] == "closed_centred_r1" and found["runs"] == 2
    assert [row["to_supervised"] for row in found["levels"]] == pytest.approx([0.05 / 0.03, 0.07 / 0.03])
    assert [row["to_nothing"] for row in found["levels"]] == [None, None]  # no reference, no ratio to it
    assert [row["paired"] for row in found["levels"]] == [{"silhouette": "closer", "chamfer": "closer"}] * 2
    assert [row["beats_image_losses"] for row in found["levels"]] == [True, True]  # both runs agree
    assert found["levels"][0]["refined_to_search"] == pytest.approx(0.02 / 0.015)
    assert found["levels"][0]["search_cpu_ratio"] == pytest.approx(500)
    assert found["levels"][0]["pays_off_configs"] == pytest.approx(201, abs=1)
    nothing = dict(prior=0.2, train_mean=0.1, start=0.3)
    table = table7([_frame(dict(nets, **nothing), 0, cpu), _frame(dict(worse, **nothing), 2, cpu)], curves)
    assert list(table["method"][:4]) == ["prior", "train_mean", "start", "net:sdm_closed_centred_r1"]
    assert ("level 0: 100.0e-3 m (do nothing: the training set's mean theta*), the networks at 0.30-0.90x of it"
            in table7_summary(table, 4, {"epochs": 16}, 3000))
    assert [row["to_nothing"] for row in verdict_facts(table)["levels"]] == pytest.approx([0.5, 0.7])


def test_a_shift_set_subset_keeps_each_configuration_with_its_shift_and_level():
    whole = N.shift_set(ConfigurationSet.from_configurations(configurations(20, seed=1)), 0,
                        N.mixed_noise_levels(20, (0, 2), seed=1))
    part = whole.subset([3, 1, 7])
    chosen = torch.tensor([3, 1, 7])
    assert torch.equal(part.truth, whole.truth[chosen]) and torch.equal(part.noise_levels, whole.noise_levels[chosen])
    assert torch.equal(part.data.targets, whole.data.targets[chosen])
    with pytest.raises(SDMInputError, match="indices"):
        whole.subset([20])


def test_per_epoch_visits_a_fresh_shuffles_first_configurations(sets):
    """per_epoch = the whole set trains the network of per_epoch 0; fewer make fewer steps and another network."""
    train, dev = sets
    whole = N.train_network("supervised", train, dev, TINY)
    same = N.train_network("supervised", train, dev, N.NetworkSettings(**{**TINY.__dict__, "per_epoch": len(train)}))
    fewer = N.train_network("supervised", train, dev, N.NetworkSettings(**{**TINY.__dict__, "per_epoch": 16}))
    assert whole.curve.drop(columns="train_cpu_s").equals(same.curve.drop(columns="train_cpu_s"))
    assert not torch.equal(N.predict(whole.net, dev.data), N.predict(fewer.net, dev.data))
    with pytest.raises(SDMInputError, match="per_epoch"):
        N.NetworkSettings(batch_size=8, per_epoch=4)


def test_training_runs_share_the_split_and_the_shifts_and_draw_their_own_training_noise():
    """A training run's seed draws the training set's noise; theta*, the levels and the dev set stay the run's
    split's, so that runs pair across losses."""
    data = ConfigurationSet.from_configurations(configurations(24, seed=7, mean_cars=3))
    noise_levels = N.mixed_noise_levels(24, [2, 3], 1)
    seeds = [N.training_seed(0, run) for run in range(3)]
    assert len(set(seeds)) == 3 and seeds == [N.training_seed(0, run) for run in range(3)]
    sets = [N.shift_set(data, 5, noise_levels, noise_seed=seed) for seed in seeds]
    assert all(torch.equal(one.truth, sets[0].truth) and torch.equal(one.noise_levels, sets[0].noise_levels) for one in sets)
    assert not torch.equal(sets[0].data.targets, sets[1].data.targets)
    assert torch.equal(N.shift_set(data, 5, noise_levels).data.targets, N.shift_set(data, 5, noise_levels, noise_seed=5).data.targets)


@pytest.mark.parametrize("kind", N.BIAS_LOSSES)
def test_loss_bias_weighs_every_configuration_alike_whatever_the_batch(sets, kind):
    """The mean gradient over the configurations does not depend on how they are batched: a batch of one gives
    each configuration's own gradient, and SDM's flow per point and the silhouette's mean over a batch are
    both brought back to it."""
    _, dev = sets
    settings = N.NetworkSettings(s=2, sigma=0.5)
    alone = N.loss_bias(dev, 0, kind, settings, batch_size=1)
    batched = N.loss_bias(dev, 0, kind, settings, batch_size=6)
    assert alone["loss"] == kind and alone["bias_a"] != 0
    for key in ("bias_a", "bias_b", "stiffness_a", "stiffness_b", "offset_m"):
        assert batched[key] == pytest.approx(alone[key], rel=1e-5, abs=1e-9), key
    with pytest.raises(SDMInputError, match="loss must be one of"):
        N.loss_bias(dev, 0, "chamfer", settings)


def test_every_method_is_scored_per_run_with_its_error_and_the_training_sets_mean(sets):
    """test_methods: a network's rows carry their run; the error per axis is theta - theta* and its norm the
    distance; the training set's mean theta* is scored for every configuration; the searches have no run."""
    from sdm.experiments.objects import search_settings

    train, dev = sets
    searches = search_settings({"lr": 1e-4, "n_epoch": 2}, {"lr": 5e-3, "n_epoch": 1, "s": 2},
                               "closed_centred_r1+group_crossing:1", {"evaluations_per_unknown": 6}, 2, 8, 0.5)
    refine = N.refine_settings({"s": 1, "n_epoch": 1, "lr": 5e-3, "rule": "closed_centred_r1", "batch_size": 4}, 0)
    nets = {("supervised", 0): _fresh(train), ("supervised", 3): N.ShiftNet(train.data.camera.screen_shape)}
    frame = N.test_methods(dev, 1, nets, refine, searches, 0, train_mean=train.truth.mean(0))
    runs = frame.groupby("method")["run"].unique().map(sorted)
    assert runs["net:supervised"] == runs["net+k:supervised"] == [0, 3]
    assert all(runs[method] == [N.NO_RUN] for method in ("prior", "train_mean", "start", "cmaes", "sdm_zero"))
    assert np.allclose(np.hypot(frame["error_a"], frame["error_b"]), frame["distance"], rtol=1e-12, atol=0)
    mean = frame[frame["method"] == "train_mean"]
    expected = (train.truth.mean(0) - dev.truth).numpy()
    assert np.array_equal(mean["error_a"].to_numpy(), expected[:, 0]) and len(mean) == len(dev)
    assert len(frame) == len(dev) * (2 * 2 + 5)
