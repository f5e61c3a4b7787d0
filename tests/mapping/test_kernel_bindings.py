"""The compiled kernel's bindings, one module per caller: the build cache (sdm.mapping.build) below them all, the
CMA-ES count beside the baseline (sdm.experiments.baselines.cmaes_native), the noise fill beside sdm.sky (sdm.sky_native).
Each binding takes its arrays by keyword and checks them before the ctypes call, naming the argument."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
import torch

from scenes import configuration_set
from sdm.experiments.baselines.mismatch import MismatchMemo, PixelMismatch
from sdm.experiments.baselines.cmaes_native import pixel_mismatch
from sdm.errors import SDMInputError
from sdm.mapping import build
from sdm.sky import NoiseBuffer
from sdm.sky_native import noise_fill

needs_kernel = pytest.mark.skipif(not build.enabled(), reason="no C compiler: the compiled kernel is not built")


def test_the_mapping_package_imports_without_the_baselines():
    """sdm.mapping (the layer, its rules and the kernel's bindings) imports with sdm.experiments.baselines made unimportable."""
    script = textwrap.dedent(
        """
        import importlib.abc, sys

        class NoBaselines(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "sdm.experiments.baselines" or name.startswith("sdm.experiments.baselines."):
                    raise ImportError(f"{name} is blocked")
                return None

        sys.meta_path.insert(0, NoBaselines())
        import sdm.mapping, sdm.mapping.native, sdm.mapping.build, sdm.mapping.research_rules
        try:
            import sdm.experiments.baselines
        except ImportError:
            print("blocked")
        print(sorted(name for name in sys.modules if name.startswith("sdm.experiments.baselines")))
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == ["blocked", "[]"]


@pytest.fixture(scope="module")
def count_inputs():
    """The keyword arguments of one compiled count, as PixelMismatch.many passes them."""
    if not build.enabled():
        pytest.skip("no C compiler: the compiled count is not built")
    data = configuration_set(16, seed=7)
    objective = PixelMismatch(data)
    layout = objective.layout
    memo = MismatchMemo(layout)
    return dict(thetas=torch.tensor([[0.5, 0.3], [0.1, -0.2]], dtype=torch.float64), gain=layout.gain,
                frac_bounds=layout.frac_bounds, shift_low=layout.shift_low, shift_high=layout.shift_high,
                group_start=layout.group_start, config_group=layout.config_group, cells=layout.cells,
                table=objective.table, padded_shape=layout.padded_shape, limits=layout.limits,
                n_target=objective.n_target, memo_offsets=memo.offsets, memo_sums=memo.sums, memo_state=memo.state,
                stamp=layout.stamp), objective


@needs_kernel
def test_the_cmaes_count_binding_counts_what_the_objective_counts(count_inputs):
    arguments, objective = count_inputs
    counts = pixel_mismatch(**arguments)
    assert counts.tolist() == [objective.reference(theta) for theta in arguments["thetas"].tolist()]


@needs_kernel
@pytest.mark.parametrize("swap, named", [
    (("group_start", "cells"), "group_start must be torch.int64, got torch.int32"),
    (("gain", "frac_bounds"), r"gain must have shape \(G, 2\), got \(2, \d+, 2\)"),
    (("shift_low", "limits"), r"shift_low must have shape \(\d+, 2\), got \(3,\)"),
    (("thetas", "limits"), r"thetas must have shape \(K, 2\), got \(3,\)"),
    (("memo_sums", "memo_offsets"), r"memo_offsets must have shape \(\d+,\)"),
])
def test_a_swapped_argument_is_refused_naming_it(count_inputs, swap, named):
    arguments, _ = count_inputs
    first, second = swap
    swapped = dict(arguments, **{first: arguments[second], second: arguments[first]})
    with pytest.raises(SDMInputError, match=f"^pixel_mismatch: .*{named}"):
        pixel_mismatch(**swapped)


@needs_kernel
def test_the_cmaes_count_refuses_a_strided_a_cuda_less_or_a_short_memo_naming_it(count_inputs):
    arguments, _ = count_inputs
    with pytest.raises(SDMInputError, match="pixel_mismatch: thetas must be C-contiguous"):
        pixel_mismatch(**dict(arguments, thetas=torch.zeros(2, 4, dtype=torch.float64)[:, ::2]))
    with pytest.raises(SDMInputError, match="pixel_mismatch: limits must be on the CPU"):
        pixel_mismatch(**dict(arguments, limits=arguments["limits"].to("meta")))
    many = torch.zeros(arguments["memo_state"].shape[0], 2, dtype=torch.float64)  # K = L + 1 candidates
    with pytest.raises(SDMInputError, match="pixel_mismatch: memo_state holds .* fewer than"):
        pixel_mismatch(**dict(arguments, thetas=many))


@needs_kernel
def test_the_noise_fill_binding_fills_as_the_torch_path_and_names_a_swapped_argument():
    target = configuration_set(4, seed=3).targets
    generator = torch.Generator().manual_seed(2)
    active = target.nonzero()
    with pytest.raises(SDMInputError, match="^noise_fill: active must be C-contiguous"):  # nonzero's is strided
        noise_fill(active=active, moves=torch.zeros(active.shape[0], 2, dtype=torch.int64),
                   out=torch.zeros_like(target), written=torch.empty(active.shape[0], dtype=torch.int64), n_written=0)
    active = active.contiguous()
    moves = torch.randint(-1, 2, (active.shape[0], 2), generator=generator, dtype=torch.int64)
    out = torch.zeros_like(target)
    written = torch.empty(active.shape[0], dtype=torch.int64)
    count = noise_fill(active=active, moves=moves, out=out, written=written, n_written=0)
    with build.disabled():
        expected = NoiseBuffer(target).fill(active, moves)
    assert torch.equal(out, expected) and not torch.equal(out, target)
    assert torch.equal(torch.unique(written[:count]), out.view(-1).nonzero().squeeze(1))  # the pixels it set
    with pytest.raises(SDMInputError, match=r"^noise_fill: moves must have shape \(\d+, 2\), got \(\d+, 3\)"):
        noise_fill(active=moves, moves=active, out=out, written=written, n_written=count)
    with pytest.raises(SDMInputError, match="^noise_fill: out must be torch.bool, got torch.int64"):
        noise_fill(active=active, moves=moves, out=written, written=out, n_written=count)
    with pytest.raises(SDMInputError, match="^noise_fill: written must hold at least"):
        noise_fill(active=active, moves=moves, out=out, written=written[:3], n_written=0)


@needs_kernel
def test_the_bindings_make_nothing_on_the_default_device(count_inputs):
    """Under torch.set_default_device (meta: no memory) the bindings still write CPU memory: every tensor they make
    is on their inputs' device (a device-less one would hand the kernel a null pointer)."""
    arguments, _ = count_inputs
    expected = pixel_mismatch(**arguments)
    target = configuration_set(2, seed=4).targets
    active = target.nonzero().contiguous()
    moves = torch.ones(active.shape[0], 2, dtype=torch.int64)
    out, written = torch.zeros_like(target), torch.empty(active.shape[0], dtype=torch.int64)
    torch.set_default_device("meta")
    try:
        counts = pixel_mismatch(**arguments)
        count = noise_fill(active=active, moves=moves, out=out, written=written, n_written=0)
    finally:
        torch.set_default_device(None)
    assert counts.device.type == "cpu" and torch.equal(counts, expected)
    assert count > 0 and bool(out.any())
