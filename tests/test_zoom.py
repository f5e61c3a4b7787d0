import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from sdm.errors import SDMInputError
from sdm.zoom import depth_to_space, space_to_depth, subrep_phases, target_pyramid, zoom_out


@settings(max_examples=30, deadline=None)
@given(steps=st.integers(0, 4), batch=st.integers(1, 3), seed=st.integers(0, 2**31))
def test_space_to_depth_round_trips_exactly(steps, batch, seed):
    x = torch.randn(batch, 32, 64, generator=torch.Generator().manual_seed(seed))
    y = space_to_depth(x, steps)
    assert y.shape == (batch, 4**steps, 32 >> steps, 64 >> steps)
    assert torch.equal(depth_to_space(y, steps), x)


@pytest.mark.parametrize("steps", [1, 2, 3, 4])
def test_subrepresentations_are_phase_classes(steps):
    block = 1 << steps
    rows = torch.arange(128)[:, None].expand(128, 256)
    cols = torch.arange(256)[None, :].expand(128, 256)
    sub_rows, sub_cols = space_to_depth(rows, steps), space_to_depth(cols, steps)
    phases = subrep_phases(steps)
    assert torch.equal(sub_rows % block, phases[:, 0, None, None].expand_as(sub_rows))
    assert torch.equal(sub_cols % block, phases[:, 1, None, None].expand_as(sub_cols))
    assert torch.equal(sub_rows // block, torch.arange(128 // block)[None, :, None].expand_as(sub_rows))
    assert sorted(map(tuple, phases.tolist())) == [(r, c) for r in range(block) for c in range(block)]


def test_first_step_follows_the_papers_reshape():
    x = torch.arange(4 * 6).reshape(4, 6)
    expected = x.reshape(2, 2, 3, 2).permute(1, 3, 0, 2).reshape(4, 2, 3)
    assert torch.equal(space_to_depth(x, 1), expected)


def test_zoomed_out_target_is_the_union_of_subrepresentations_and_a_max_pool():
    target = torch.rand(3, 128, 256, generator=torch.Generator().manual_seed(1)) > 0.97
    for steps, zoomed in enumerate(target_pyramid(target, 4)):
        assert torch.equal(zoomed, space_to_depth(target, steps).any(-3))
        pooled = F.max_pool2d(target.float()[:, None], 1 << steps)[:, 0] > 0
        assert torch.equal(zoom_out(target, steps), pooled)


def test_screen_not_divisible_by_two_to_the_s():
    with pytest.raises(SDMInputError, match="not divisible by 2\\^s = 32"):
        space_to_depth(torch.zeros(128, 240), 5)
