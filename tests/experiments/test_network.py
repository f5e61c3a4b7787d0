"""SDM inside a network (sdm.network): the gradient that reaches the weights, training, determinism, bad input."""
from __future__ import annotations

import pytest
import torch

from sdm import network as N
from sdm.batch import ConfigurationSet
from sdm.errors import SDMInputError
from sdm.mapping.layer import SpatialDomainMapping
from sdm.sky import shift_vector

from scenes import configurations

TINY = N.NetworkSettings(epochs=3, batch_size=8, lr=(("default", 3e-3),), s=2, seed=5)


@pytest.fixture(scope="module")
def sets():
    """48 training and 16 dev configurations of synthetic scenes, each with its own shift and mixed noise."""
    data = ConfigurationSet.from_configurations(configurations(64, seed=43, mean_cars=3))
    train = N.shift_set(data.subset(range(48)), 1, N.mixed_levels(48, [0, 1], 2))
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
    level = 1
    loss = N.BatchLoss(kind, train, TINY, torch.Generator().manual_seed(0))
    theta = net(N.network_images(train.data, indices).double())
    net.zero_grad()
    loss(theta, indices, level).backward()
    through_autograd = [p.grad.clone() for p in net.parameters()]

    batch = train.data.batch(indices)
    layer = SpatialDomainMapping(train.data.camera, s=TINY.s, zoom=level, flow=N.SDM_RULES[kind])
    points = batch.points + shift_vector(theta.detach().index_select(0, batch.config), batch.points)
    out = layer(points, batch.pixels, batch.targets, batch.config, batch.rank)
    flow = torch.zeros(len(indices), 2, dtype=torch.float64).index_add(0, batch.config, out.result.flow)
    assert bool(flow.abs().sum() > 0)  # the batch is pulled: the comparison means something
    flow = flow / train.data.counts.index_select(0, indices).double().unsqueeze(1)
    theta = net(N.network_images(train.data, indices).double())
    by_hand = torch.autograd.grad(theta, list(net.parameters()), grad_outputs=flow)
    for mine, reference in zip(through_autograd, by_hand):
        torch.testing.assert_close(mine, reference, rtol=1e-12, atol=1e-15)


def test_training_through_sdm_moves_the_dev_distance_down(sets):
    train, dev = sets
    start = N.distances(N.predict(_fresh(train), dev.data), dev.truth).mean()
    trained = N.train_network("sdm_paper", train, dev, TINY)
    assert float(trained.curve["dev_mean_m"].iloc[-1]) < 0.5 * float(start)
    assert list(trained.curve["level"]) == N.epoch_levels(TINY.epochs, TINY.s) == [2, 1, 0]


def _fresh(train) -> N.ShiftNet:
    torch.manual_seed(TINY.seed)
    return N.ShiftNet(train.data.camera.screen_shape)


@pytest.mark.parametrize("kind", ["sdm_recommended", "chamfer"])
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
    assert N.epoch_levels(8, 2) == [2, 1, 0, 0, 0, 0, 0, 0]
    assert N.epoch_levels(2, 4) == [1, 0]
    assert N.epoch_levels(5, 0) == [0] * 5


def _frame(means: dict[str, float], level: int, cpu: dict[str, float]) -> "pd.DataFrame":
    import pandas as pd

    return pd.concat([pd.DataFrame({"level": level, "method": method, "config": range(4),
                                    "distance": [mean] * 4, "cpu_s": cpu.get(method, 1e-4)})
                      for method, mean in means.items()], ignore_index=True)


def test_table7_words_follow_the_numbers():
    """The summary's bars read the table: met where the numbers meet them, missed where they do not."""
    import pandas as pd

    from sdm.report.network import table7, table7_summary, verdict_facts

    nets = {"net:sdm_paper": 0.05, "net:silhouette": 0.08, "net:chamfer": 0.09, "net:supervised": 0.03,
            "net+k:sdm_paper": 0.02, "cmaes": 0.015, "sdm_zero": 0.04}
    worse = dict(nets, **{"net:sdm_paper": 0.07})  # level 2: 2.33x supervised, still closer than the image losses
    cpu = {"cmaes": 0.05, "net+k:sdm_paper": 1e-4}
    curves = [pd.DataFrame({"loss": [loss], "epoch": [1], "train_cpu_s": [10.0]})
              for loss in ("sdm_paper", "silhouette", "chamfer", "supervised")]
    table = table7([_frame(nets, 0, cpu), _frame(worse, 2, cpu)], curves)
    assert list(table["method"][:4]) == ["net:sdm_paper", "net:silhouette", "net:chamfer", "net:supervised"]
    words = table7_summary(table, 4, 16, 3000)
    assert "level 0: 1.67x supervised's mean; level 2: 2.33x supervised's mean" in words
    assert "within 2x of supervised regression at levels 0 and 2: missed" in words
    assert "closer than both at every level: met" in words
    assert "level 0: 1.33x CMA-ES's mean at 1/500 of its CPU time" in words
    assert "100x less CPU time: met" in words
    found = verdict_facts(table)
    assert found["loss"] == "sdm_paper" and found["rule"] == "paper"
    assert [row["to_supervised"] for row in found["levels"]] == pytest.approx([0.05 / 0.03, 0.07 / 0.03])
    assert [row["to_nothing"] for row in found["levels"]] == [None, None]  # no reference, no ratio to it
    assert [row["beats_image_losses"] for row in found["levels"]] == [True, True]
    assert found["levels"][0]["refined_to_search"] == pytest.approx(0.02 / 0.015)
    assert found["levels"][0]["search_cpu_ratio"] == pytest.approx(500)
    nothing = dict(prior=0.2, start=0.1)
    table = table7([_frame(dict(nets, **nothing), 0, cpu), _frame(dict(worse, **nothing), 2, cpu)], curves)
    assert list(table["method"][:3]) == ["start", "prior", "net:sdm_paper"]
    assert "level 0: 200.0e-3 m, the networks at 0.15-0.45x of it" in table7_summary(table, 4, 16, 3000)
    assert [row["to_nothing"] for row in verdict_facts(table)["levels"]] == pytest.approx([0.25, 0.35])


def test_a_shift_set_subset_keeps_each_configuration_with_its_shift_and_level():
    whole = N.shift_set(ConfigurationSet.from_configurations(configurations(20, seed=1)), 0,
                        N.mixed_levels(20, (0, 2), seed=1))
    part = whole.subset([3, 1, 7])
    chosen = torch.tensor([3, 1, 7])
    assert torch.equal(part.truth, whole.truth[chosen]) and torch.equal(part.levels, whole.levels[chosen])
    assert torch.equal(part.data.targets, whole.data.targets[chosen])
    with pytest.raises(SDMInputError, match="indices"):
        whole.subset([20])
