"""Run the layer, the trainer and the experiments on a saved set; save what they return.

Used by ``test_devices.py`` (CPU: under ``torch.set_default_device("meta")``) and
``test_cuda.py``. ``python device_probe.py DATA OUT DEVICE [DEFAULT_DEVICE]``:

* ``DATA``: a ``torch.save`` of the set's tensors (``points, pixels, offsets, targets``);
* ``DEVICE``: where the inputs are put (``cpu`` or ``cuda``);
* ``DEFAULT_DEVICE``: if given, ``torch.set_default_device`` is called with it
  *before* ``sdm`` is imported, so that any tensor ``sdm`` creates without naming
  a device (a module-level constant as much as a tensor built inside a call)
  lands there. With ``meta`` such a tensor cannot meet the inputs without an
  error, and cannot reach an output without the output leaving ``DEVICE``.

Every output is checked to live on ``DEVICE`` and saved (on the CPU) to ``OUT``.
"""
from __future__ import annotations

import sys

import torch


def probe(data_path: str, device: str) -> dict:
    from sdm.batch import ConfigurationSet
    from sdm.experiments import flow_at_true_shift, noise_runs
    from sdm.mapping import SpatialDomainMapping, dynamic_flow, explain_point  # noqa: F401 (import is the probe)
    from sdm.metrics import false_positive_pixels
    from sdm.train import TrainSettings, train
    from sdm.zoom import subrep_phases, target_pyramid

    saved = torch.load(data_path, map_location="cpu")
    data = ConfigurationSet(saved["points"], saved["pixels"], saved["offsets"], saved["targets"]).to(device)
    out: dict[str, torch.Tensor] = {}
    batch = data.batch(range(4))
    for method in ("fast", "dense"):
        for zoom in (4, 0):
            theta = torch.tensor([0.21, 0.13], dtype=torch.float64, device=device, requires_grad=True)
            layer = SpatialDomainMapping(s=4, zoom=zoom, method=method)
            points = batch.points + torch.nn.functional.pad(theta, (0, 1))
            result = layer(points, batch.pixels, batch.targets, batch.config, batch.rank)
            result.loss.backward()
            key = f"{method}{zoom}"
            out |= {f"{key}_loss": result.loss.detach(), f"{key}_grad": theta.grad,
                    f"{key}_pixels": result.result.out_pixels, f"{key}_flow": result.result.flow,
                    f"{key}_matched": result.result.matched, f"{key}_landed": result.result.landed,
                    f"{key}_depth": result.depth_map()}
    info = explain_point(batch.points[0] + torch.tensor([0.05, 0.02, 0.0], dtype=torch.float64, device=device),
                         tuple(batch.pixels[0].tolist()), batch.targets[0], zoom=1)
    out |= {"explain_pull": info["pull"], "explain_kernel": info["kernel"]}
    out["phases"] = subrep_phases(2, device=device)
    out["pyramid1"] = target_pyramid(data.targets, 2)[1]
    settings = TrainSettings(lr=3e-4, n_epoch=1, s=3, zoom=0, seed=4)
    history = train(data, settings, progress=False)
    out |= {"train_theta": history.theta, "train_loss": history.loss}
    out["false_positive"] = false_positive_pixels(data, history.final_theta)
    single = noise_runs(data, 1, [0], settings, group_size=1).iloc[0]
    out["noise_run"] = torch.tensor([single["a"], single["b"]], dtype=torch.float64, device="cpu")
    batched = noise_runs(data, 1, [0, 1], settings)
    out["noise_runs"] = torch.tensor(batched[["a", "b"]].to_numpy(), device="cpu")
    frame = flow_at_true_shift(data, [0], seed=0, s=2)
    out["flow_at_true_shift"] = torch.tensor(frame[["flow_a", "flow_b"]].to_numpy(), device="cpu")
    return out


#: Outputs that are CPU tensors whatever the device (histories and tables are records, not working tensors).
ON_CPU_BY_CONTRACT = ("train_theta", "train_loss", "noise_run", "noise_runs", "flow_at_true_shift")


def main() -> None:
    data_path, out_path, device = sys.argv[1:4]
    if len(sys.argv) > 4:
        torch.set_default_device(sys.argv[4])
    results = probe(data_path, device)
    expected = {name: "cpu" if name in ON_CPU_BY_CONTRACT else torch.device(device).type for name in results}
    wrong = {name: str(value.device) for name, value in results.items() if value.device.type != expected[name]}
    if wrong:
        raise SystemExit(f"outputs not on {device}: {wrong}")
    torch.save({name: value.detach().to("cpu") for name, value in results.items()}, out_path)


if __name__ == "__main__":
    main()
