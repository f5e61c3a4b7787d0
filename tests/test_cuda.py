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
