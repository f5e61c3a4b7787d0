"""No tensor on a fixed device: the library run with every device-less tensor sent to ``meta``.

``torch.set_default_device("meta")`` before ``sdm`` is imported sends every tensor
that ``sdm`` creates without naming a device, at import (module constants) or
during a call, to the ``meta`` device. The probe then runs the layer (both
paths, two zoom levels), the explainer, the trainer, the metrics and the
experiments on CPU inputs: a single device-less tensor either meets a CPU
tensor (torch refuses to mix ``meta`` and ``cpu``) or reaches an output (the
probe checks every output's device). Results must equal a plain CPU run's.
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from scenes import configuration_set

PROBE = Path(__file__).with_name("device_probe.py")


def run_probe(data_path, out_path, device, default_device=None):
    command = [sys.executable, str(PROBE), str(data_path), str(out_path), device] + ([default_device] if default_device else [])
    done = subprocess.run(command, capture_output=True, text=True, env=os.environ | {"OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    return torch.load(out_path)


@pytest.mark.slow
def test_nothing_is_created_on_a_fixed_device(saved_set, tmp_path):
    plain = run_probe(saved_set, tmp_path / "plain.pt", "cpu")
    trapped = run_probe(saved_set, tmp_path / "meta.pt", "cpu", default_device="meta")
    assert plain.keys() == trapped.keys()
    for name in plain:
        assert torch.equal(plain[name], trapped[name]), name


@pytest.mark.slow
def test_the_trap_catches_a_fixed_device_tensor(saved_set, tmp_path):
    """The probe can fail: a module constant created without a device is caught."""
    sabotage = tmp_path / "sitecustomize.py"
    sabotage.write_text(
        "import torch, sdm.mapping.flow as flow\n"
        "flow._axis_shifts = lambda device, dtype: torch.tensor([-1, 0, 1], dtype=dtype)\n"
    )
    command = [sys.executable, "-c",
               f"import sys, runpy, torch; torch.set_default_device('meta'); sys.path.insert(0, {str(tmp_path)!r});"
               f"import sitecustomize; sys.argv = ['probe', {str(saved_set)!r}, {str(tmp_path / 'x.pt')!r}, 'cpu'];"
               f"runpy.run_path({str(PROBE)!r}, run_name='__main__')"]
    done = subprocess.run(command, capture_output=True, text=True, env=os.environ | {"OMP_NUM_THREADS": "1"})
    assert done.returncode != 0 and "meta" in done.stderr


def test_configuration_set_moves_whole():
    """ConfigurationSet.to moves every tensor (meta stands in for a second device) and keeps float64."""
    data = configuration_set(3, seed=2)
    assert data.to("cpu") is data
    moved = data.to("meta")
    assert moved.device.type == "meta" and moved.points.dtype == torch.float64
    for name in ("points", "pixels", "offsets", "targets", "rank"):
        assert getattr(moved, name).device.type == "meta", name
    assert moved.image_ids == data.image_ids and len(moved) == len(data)
