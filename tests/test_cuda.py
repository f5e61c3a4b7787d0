"""CPU and CUDA give the same layer outputs, flow and training history (skipped without a GPU).

Integer results (pixels, masks, counts) and sums of signs (the flow, hence every
theta of a training history) must be bit-identical: each torch op is its own
kernel, so the projection's arithmetic is the same IEEE sequence on both devices.
Only float reductions whose order may differ (the loss value, the softmax of the
explainer) are compared to a relative 1e-12.
"""
import pytest
import torch

from device_probe import probe
from scenes import configuration_set

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

#: Float reductions whose summation order is the device's business.
REDUCED = ("_loss", "explain_kernel")


def test_cpu_and_cuda_agree(saved_set):
    on_cpu = probe(str(saved_set), "cpu")
    on_cuda = probe(str(saved_set), "cuda")
    assert on_cpu.keys() == on_cuda.keys()
    for name, expected in on_cpu.items():
        got = on_cuda[name].cpu()
        if name.endswith(REDUCED):
            torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12, msg=name)
        else:
            assert torch.equal(got, expected), name


def test_outputs_stay_on_cuda(saved_set):
    from sdm.mapping import SpatialDomainMapping

    data = configuration_set(4, seed=5).to("cuda")
    batch = data.batch(range(4))
    out = SpatialDomainMapping(s=4, zoom=1)(batch.points, batch.pixels, batch.targets, batch.config, batch.rank)
    for name in ("out_pixels", "flow", "loss", "entered", "matched", "landed"):
        assert getattr(out.result, name).device.type == "cuda", name
    assert out.loss.device.type == "cuda" and out.depth_map().device.type == "cuda"


def test_training_on_cuda_equals_cpu():
    from sdm.train import TrainSettings, train

    data = configuration_set(64, seed=8)
    settings = TrainSettings(lr=3e-4, n_epoch=2, seed=2)
    on_cpu = train(data, settings, progress=False)
    on_cuda = train(data, settings, progress=False, device="cuda")
    assert on_cuda.theta.device.type == "cpu"
    assert torch.equal(on_cpu.theta, on_cuda.theta)
    torch.testing.assert_close(on_cuda.loss, on_cpu.loss, rtol=1e-12, atol=1e-12)


def test_runs_with_rows_and_refinement_on_cuda_equal_cpu():
    """Packed runs, a shift per car (param_index, per-row rates) and the schedule's refinement passes give the
    CPU's theta history to the bit on the GPU (the CPU's is the compiled kernel's where it is built)."""
    from dataclasses import replace

    from sdm.experiments import noisy_targets
    from sdm.train import Refinement, TrainSettings, rates_per_point, refine_runs, train_runs

    data = configuration_set(64, seed=11)
    settings = [replace(TrainSettings(lr=1e-4, n_epoch=1, s=4, rule="closed_centred_r1"), seed=seed)
                for seed in (4, 9)]
    targets = [noisy_targets(data.targets, 2, 1), noisy_targets(data.targets, 1, 5)]
    refinement = Refinement("group_crossing", 3, pass_steps=4)
    on_cpu = refine_runs(data, targets, settings, train_runs(data, targets, settings), refinement)
    gpu = data.to("cuda")
    gpu_targets = [t.to("cuda") for t in targets]
    on_cuda = refine_runs(gpu, gpu_targets, settings, train_runs(gpu, gpu_targets, settings), refinement)
    assert torch.equal(on_cpu.theta, on_cuda.theta)
    index, _ = data.car_rows()
    rows = dict(param_index=index, row_rate=rates_per_point(index))
    per_car_cpu = train_runs(data, targets, settings, **rows)
    per_car_cuda = train_runs(gpu, gpu_targets, settings, param_index=index.to("cuda"),
                              row_rate=rates_per_point(index).to("cuda"))
    assert torch.equal(per_car_cpu.theta, per_car_cuda.theta)


def test_every_rule_flows_alike_on_cuda_and_cpu():
    """Every registered gradient rule (experiments too) gives the same flow on both devices at every zoom."""
    from sdm.mapping import RULES, SpatialDomainMapping

    data = configuration_set(8, seed=3)
    for name in RULES:
        for zoom in (2, 0):
            flows = []
            for device in ("cpu", "cuda"):
                batch = data.to(device).batch(torch.arange(8, device=device))
                theta = torch.tensor([0.11, 0.07], dtype=torch.float64, device=device, requires_grad=True)
                layer = SpatialDomainMapping(s=2, zoom=zoom, rule=name)
                out = layer(batch.points + torch.nn.functional.pad(theta, (0, 1)), batch.pixels, batch.targets,
                            batch.config, batch.rank)
                out.loss.backward()
                flows.append(theta.grad.cpu())
            torch.testing.assert_close(flows[1], flows[0], rtol=1e-12, atol=1e-12, msg=f"{name} at zoom {zoom}")


@pytest.mark.parametrize("loss", ["sdm_paper", "sdm_closed_centred_r1", "silhouette", "chamfer", "supervised"])
def test_every_network_loss_trains_on_cuda(loss):
    """Table 7's training runs on the GPU under its deterministic mode: twice the same weights, and shifts near
    the CPU's (float32 convolutions round otherwise on the GPU, so not to the bit)."""
    from sdm.experiments.network import NetworkSettings, mixed_noise_levels, predict, shift_set, train_network

    data = configuration_set(48, seed=6)
    settings = NetworkSettings(epochs=2, batch_size=16, s=1, max_points=64)
    predictions = {}
    for device in ("cpu", "cuda", "cuda"):
        whole = shift_set(data.to(device), 0, mixed_noise_levels(48, (0, 2), seed=1))
        trained = train_network(loss, whole, whole, settings)
        predictions.setdefault(device, []).append(predict(trained.net, whole.data).cpu())
    first, second = predictions["cuda"]
    assert torch.equal(first, second)
    assert bool(torch.isfinite(first).all())
    torch.testing.assert_close(first, predictions["cpu"][0], rtol=0, atol=1e-2)
