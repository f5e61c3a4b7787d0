"""The SDM layer: forward against brute-force oracles, dense against fast, and the dynamic gradient flow."""
import contextlib
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from scenes import configurations
from sdm.batch import ConfigurationSet
from sdm.camera import APOLLO_CAMERA_5, Camera
from sdm.errors import SDMInputError
from sdm.mapping import SpatialDomainMapping, dynamic_flow, explain_point, native
from sdm.mapping.dense import dense_mapping
from sdm.mapping.fast import fast_mapping
from sdm.representation import inside
from sdm.sky import SKY_SHIFT, pixel_centre_points, shift_vector
from sdm.zoom import zoom_out

ROOT = Path(__file__).resolve().parents[2]

CAM = APOLLO_CAMERA_5
H, W = CAM.screen_shape
SLOW = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def shifted(batch, theta):
    return batch.points + shift_vector(theta, batch.points)


def brute_force_zoom(points, pixels, config, zoom):
    """Dictionary oracle for one zoom: every point lands at floor(P(p) / B) * B + phase; rmin by (depth, index)."""
    block_size = 1 << zoom
    screen = CAM.project(points).tolist()
    best = {}
    for i, ((row, col), (r, c), n, z) in enumerate(zip(screen, pixels.tolist(), config.tolist(), points[:, 2].tolist())):
        land = (math.floor(row / block_size), math.floor(col / block_size))
        if not (0 <= land[0] < H // block_size and 0 <= land[1] < W // block_size):
            continue
        key = (n, land[0] * block_size + r % block_size, land[1] * block_size + c % block_size)
        if key not in best or (z, i) < best[key][0]:
            best[key] = ((z, i), i)
    out = torch.full((len(screen), 2), -1, dtype=torch.int64)
    for (_, row, col), (_, i) in best.items():
        out[i] = torch.tensor([row, col])
    return out


def in_reach(points, pixels, zoom):
    landing = torch.floor(CAM.project(points) / (1 << zoom)).long()
    return bool(((landing - (pixels >> zoom)).abs() <= 1).all())


def max_shift_for(zoom, depth_min):
    """Largest |a| (and |b|) moving the nearest point less than B - 0.5 pixels: inside the 3x3 reach."""
    dy, dx = CAM.metres_per_screen_pixel(depth_min)
    return ((1 << zoom) - 0.5) * min(dx, dy)


@SLOW
@given(zoom=st.integers(0, 4), seed=st.integers(0, 10_000), u=st.floats(-1, 1), v=st.floats(-1, 1))
def test_one_zoom_is_a_reprojection_within_reach(zoom, seed, u, v):
    batch = ConfigurationSet.from_configurations(configurations(3, seed)).batch(range(3))
    limit = max_shift_for(zoom, float(batch.points[:, 2].min()))
    points = shifted(batch, (u * limit, v * limit))
    assert in_reach(points, batch.pixels, zoom)
    target = zoom_out(batch.targets, zoom)
    result = fast_mapping(points, batch.pixels, batch.config, batch.rank, target, zoom, zoom, CAM)
    assert torch.equal(result.out_pixels, brute_force_zoom(points, batch.pixels, batch.config, zoom))


def coarse_collision(points, pixels, config, steps):
    """Whether two points of one phase share a landing block at some zoom >= 1 (the chain's only loss)."""
    screen = CAM.project(points)
    for zoom in range(steps, 0, -1):
        block_size = 1 << zoom
        land = torch.floor(screen / block_size).long()
        ok = (land >= 0).all(1) & (land[:, 0] < H // block_size) & (land[:, 1] < W // block_size)
        key = torch.stack((config, land[:, 0], land[:, 1], pixels[:, 0] % block_size, pixels[:, 1] % block_size), 1)[ok]
        if torch.unique(key, dim=0).shape[0] < key.shape[0]:
            return True
    return False


@SLOW
@given(seed=st.integers(0, 10_000), n_cars=st.integers(1, 4), u=st.floats(-1, 1), v=st.floats(-1, 1))
def test_chain_output_is_contained_in_the_direct_reprojection(seed, n_cars, u, v):
    configs = configurations(2, seed, mean_cars=n_cars)
    batch = ConfigurationSet.from_configurations(configs).batch(range(2))
    limit = max_shift_for(4, float(batch.points[:, 2].min()))
    points = shifted(batch, (u * limit, v * limit))
    result = fast_mapping(points, batch.pixels, batch.config, batch.rank, batch.targets, 4, 0, CAM)
    direct = brute_force_zoom(points, batch.pixels, batch.config, 0)
    alive = result.alive
    # Every surviving point sits where the direct re-projection puts it ...
    assert torch.equal(result.out_pixels[alive], torch.floor(CAM.project(points[alive])).long())
    # ... so the output mask is inside the re-projection's mask,
    chain_mask = torch.zeros(2, H, W, dtype=torch.bool)
    chain_mask[batch.config[alive], result.out_pixels[alive, 0], result.out_pixels[alive, 1]] = True
    direct_alive = direct[:, 0] >= 0
    direct_mask = torch.zeros(2, H, W, dtype=torch.bool)
    direct_mask[batch.config[direct_alive], direct[direct_alive, 0], direct[direct_alive, 1]] = True
    assert bool((chain_mask <= direct_mask).all())
    # ... and equal to it, point for point, when no coarse collision happened.
    if not coarse_collision(points, batch.pixels, batch.config, 4):
        assert torch.equal(result.out_pixels, direct)


def test_single_car_chain_equals_reprojection():
    """A rigidly shifted disc has no coarse collisions: the chain is exactly the re-projection."""
    batch = ConfigurationSet.from_configurations(configurations(1, 7, mean_cars=1)[:1]).batch([0])
    points = shifted(batch, SKY_SHIFT)
    assert not coarse_collision(points, batch.pixels, batch.config, 4)
    result = fast_mapping(points, batch.pixels, batch.config, batch.rank, batch.targets, 4, 0, CAM)
    assert torch.equal(result.out_pixels, brute_force_zoom(points, batch.pixels, batch.config, 0))


def test_true_shift_is_a_fixed_point_and_loses_few_pixels():
    data = ConfigurationSet.from_configurations(configurations(16, 11))
    batch = data.batch(range(16))
    points = shifted(batch, SKY_SHIFT)
    for zoom in (4, 3, 2, 1, 0):
        result = fast_mapping(points, batch.pixels, batch.config, batch.rank, zoom_out(batch.targets, zoom), 4, zoom, CAM)
        assert float(result.loss) == 0 and not bool(result.flow.any())
        assert bool((result.matched == (result.entered & _on_screen(points))).all())
    lost = 1 - int(result.alive.sum()) / int(batch.targets.sum())  # zoom 0: coarse collisions only
    assert 0 <= lost < 0.05


def _on_screen(points):
    screen = CAM.project(points)
    return (screen[:, 0] >= 0) & (screen[:, 0] < H) & (screen[:, 1] >= 0) & (screen[:, 1] < W)


# theta = 0 exactly puts every point on the centre of its own adjustment at zoom 0: a tie
# (sign(0) against a rounding error), which the paper sets aside as a measure-zero boundary case.
generic_shift = st.floats(-1.0, 1.5).filter(lambda x: abs(x) > 1e-6)


@pytest.mark.slow
@SLOW
@given(seed=st.integers(0, 10_000), zoom=st.integers(0, 4), a=generic_shift, b=generic_shift)
def test_dense_reference_in_the_large_c_limit_equals_the_fast_path(seed, zoom, a, b):
    batch = ConfigurationSet.from_configurations(configurations(2, seed)).batch(range(2))
    points = shifted(batch, (a, b))
    target = zoom_out(batch.targets, zoom)
    fast = fast_mapping(points, batch.pixels, batch.config, batch.rank, target, 4, zoom, CAM)
    dense = dense_mapping(points, batch.pixels, batch.config, batch.rank, target, 4, zoom, CAM, sharpness=1e9)
    assert torch.equal(fast.out_pixels, dense.out_pixels)
    assert torch.equal(fast.entered, dense.entered) and torch.equal(fast.matched, dense.matched)
    assert torch.equal(fast.landed, dense.landed)
    assert not bool(fast.flow[~fast.missed].any())  # only points that missed are pulled
    assert torch.equal(fast.flow, dense.flow)
    assert float(fast.loss) == pytest.approx(float(dense.loss), rel=1e-9, abs=1e-9)


def test_dense_output_converges_to_the_fast_path_as_its_sharpness_grows():
    batch = ConfigurationSet.from_configurations(configurations(2, 5)).batch(range(2))
    points = shifted(batch, (0.31, 0.17))
    fast = fast_mapping(points, batch.pixels, batch.config, batch.rank, batch.targets, 4, 0, CAM)
    differing = []
    for sharpness in (3.0, 30.0, 300.0, 3e3, 1e9):
        dense = dense_mapping(points, batch.pixels, batch.config, batch.rank, batch.targets, 4, 0, CAM,
                              sharpness=sharpness)
        differing.append(int((dense.out_pixels != fast.out_pixels).any(1).sum()))
    assert differing[0] > 0 and differing[-1] == 0
    assert differing == sorted(differing, reverse=True)


# -- the single point of Figure 3 ------------------------------------------------------------

def single_point(pixel=(60, 100), depth=20.0):
    pixels = torch.tensor([pixel])
    return pixel_centre_points(pixels, torch.tensor([depth], dtype=torch.float64)), pixels


@pytest.mark.parametrize("target_pixel, pull_sign", [((60, 101), (-1, 0)), ((61, 101), (-1, -1)), ((59, 99), (1, 1))])
def test_single_point_gradient_pulls_towards_the_target(target_pixel, pull_sign):
    q, pixels = single_point()
    target = torch.zeros(H, W, dtype=torch.bool)
    target[target_pixel] = True
    theta = torch.zeros(2, dtype=torch.float64, requires_grad=True)
    layer = SpatialDomainMapping(s=0, zoom=0)
    out = layer(q + torch.nn.functional.pad(theta, (0, 1)), pixels, target)
    out.loss.backward()
    # dJ/dtheta = sign(p - T): gradient descent moves the point towards the target pixel's adjustment.
    assert tuple(torch.sign(theta.grad).tolist()) == pull_sign
    assert not bool(out.result.matched.any())


@pytest.mark.slow
def test_single_point_descends_to_its_target_then_stops():
    q, pixels = single_point()
    target = torch.zeros(H, W, dtype=torch.bool)
    target[62, 102] = True  # two pixels down and right: needs the zoom chain (s = 1) to reach it
    theta = torch.zeros(2, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.SGD([theta], lr=0.02)
    for zoom in (1, 0):
        layer = SpatialDomainMapping(s=1, zoom=zoom)
        for _ in range(30):
            out = layer(q + torch.nn.functional.pad(theta, (0, 1)), pixels, target)
            optimiser.zero_grad()
            out.loss.backward()
            optimiser.step()
    out = SpatialDomainMapping(s=1, zoom=0)(q + torch.nn.functional.pad(theta.detach(), (0, 1)), pixels, target)
    assert tuple(out.result.out_pixels[0].tolist()) == (62, 102)
    assert bool(out.result.matched[0]) and float(out.loss) == 0
    layer = SpatialDomainMapping(s=1, zoom=0)
    theta.grad = None
    layer(q + torch.nn.functional.pad(theta, (0, 1)), pixels, target).loss.backward()
    assert not bool(theta.grad.any())  # matched: zero gradient


def test_explain_point_agrees_with_the_layer():
    q, pixels = single_point()
    target = torch.zeros(H, W, dtype=torch.bool)
    target[61, 101] = True
    info = explain_point(q[0], tuple(pixels[0].tolist()), target, zoom=0, sharpness=20.0)
    assert info["kernel"].sum().item() == pytest.approx(1.0)
    assert tuple(info["landing"].tolist()) == (60, 100) and info["kernel"][1, 1] == info["kernel"].max()
    assert info["matched"] is False
    theta = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    SpatialDomainMapping(s=0, zoom=0)(q + theta, pixels, target).loss.backward()
    assert torch.equal(info["pull"], theta.grad[:2])


def test_autograd_carries_the_flow_to_the_shift():
    batch = ConfigurationSet.from_configurations(configurations(4, 2)).batch(range(4))
    theta = torch.tensor([0.2, 0.1], dtype=torch.float64, requires_grad=True)
    out = SpatialDomainMapping(s=4, zoom=2)(
        batch.points + torch.nn.functional.pad(theta, (0, 1)), batch.pixels, batch.targets, batch.config, batch.rank
    )
    out.loss.backward()
    assert torch.equal(theta.grad, out.result.flow.sum(0))
    assert bool(theta.grad.abs().sum() > 0)
    depth = out.depth_map()
    assert int((depth > 0).sum()) == int(out.result.alive.sum())
    assert out.occupancy().shape == (4, H // 4, W // 4)


# -- bad input -------------------------------------------------------------------------------

def test_points_behind_the_camera():
    q, pixels = single_point()
    with pytest.raises(SDMInputError, match="behind the camera"):
        SpatialDomainMapping()(q * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64), pixels, torch.zeros(H, W, dtype=torch.bool))


def test_non_finite_shift():
    q, pixels = single_point()
    theta = torch.tensor([math.nan, 0.0, 0.0], dtype=torch.float64)
    with pytest.raises(SDMInputError, match="non-finite"):
        SpatialDomainMapping()(q + theta, pixels, torch.zeros(H, W, dtype=torch.bool))


def test_empty_configuration():
    with pytest.raises(SDMInputError, match="no points"):
        SpatialDomainMapping()(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 2, dtype=torch.int64),
                               torch.zeros(H, W, dtype=torch.bool))
    with pytest.raises(SDMInputError, match="empty list"):
        ConfigurationSet.from_configurations([])


def test_screen_not_divisible_by_two_to_the_s():
    camera = Camera(fx=1000.0, fy=1000.0, cx=500.0, cy=400.0, image_width=1000, image_height=800,
                    screen_height=120, screen_width=200)
    with pytest.raises(SDMInputError, match="not divisible by 2\\^s = 16"):
        SpatialDomainMapping(camera, s=4)
    SpatialDomainMapping(camera, s=3)  # 120 and 200 are divisible by 8


@pytest.mark.parametrize(
    "kwargs, message",
    [({"zoom": 5}, "zoom must be"), ({"method": "sparse"}, "method must be"), ({"sharpness": 0.0}, "sharpness")],
)
def test_bad_layer_settings(kwargs, message):
    with pytest.raises(SDMInputError, match=message):
        SpatialDomainMapping(**kwargs)


def test_bad_layer_inputs():
    q, pixels = single_point()
    layer = SpatialDomainMapping()
    with pytest.raises(SDMInputError, match="target must have shape"):
        layer(q, pixels, torch.zeros(64, 64, dtype=torch.bool))
    with pytest.raises(SDMInputError, match="bool mask"):
        layer(q, pixels, torch.zeros(H, W))
    with pytest.raises(SDMInputError, match="pixels must lie on"):
        layer(q, torch.tensor([[200, 5]]), torch.zeros(H, W, dtype=torch.bool))
    with pytest.raises(SDMInputError, match="one point per pixel"):
        SpatialDomainMapping(method="dense")(torch.cat((q, q)), torch.cat((pixels, pixels)), torch.zeros(H, W, dtype=torch.bool))


# -- the autograd boundary -------------------------------------------------------------------

def small_batch(n=4, seed=2):
    return ConfigurationSet.from_configurations(configurations(n, seed)).batch(range(n))


def test_only_the_loss_carries_a_gradient():
    batch = small_batch()
    theta = torch.tensor([0.2, 0.1], dtype=torch.float64, requires_grad=True)
    out = SpatialDomainMapping(s=4, zoom=1)(batch.points + shift_vector(theta, batch.points), batch.pixels,
                                             batch.targets, batch.config, batch.rank)
    assert out.loss.requires_grad
    result = out.result
    for name in ("flow", "out_pixels", "entered", "matched", "landed", "loss"):
        assert not getattr(result, name).requires_grad, name
    assert bool(result.flow.any())  # something is pulled, so the check above is not vacuous


def zoom1_loss_of_theta():
    """The layer's loss at zoom 1 on a small batch, as a function of the shift theta (2,)."""
    batch = small_batch()
    layer = SpatialDomainMapping(s=4, zoom=1)

    def loss_of(theta):
        return layer(batch.points + shift_vector(theta, batch.points), batch.pixels, batch.targets,
                     batch.config, batch.rank).loss

    return loss_of


def test_torch_func_grad_sees_the_layer():
    """forward + setup_context: a functional transform gives the same gradient as backward()."""
    loss_of = zoom1_loss_of_theta()

    theta = torch.tensor([0.2, 0.1], dtype=torch.float64)
    functional = torch.func.grad(loss_of)(theta)
    leaf = theta.clone().requires_grad_(True)
    loss_of(leaf).backward()
    assert bool(functional.any()) and torch.equal(functional, leaf.grad)


def test_dynamic_flow_is_the_gradient_of_the_layer():
    """The public rule, called on the fast path's landing, is what backward() delivers."""
    batch = small_batch()
    theta = torch.tensor([0.25, -0.05], dtype=torch.float64, requires_grad=True)
    points = batch.points + shift_vector(theta, batch.points)
    out = SpatialDomainMapping(s=0, zoom=0)(points, batch.pixels, batch.targets, batch.config, batch.rank)
    out.loss.backward()
    result = out.result
    screen = CAM.project(points.detach())
    # One zoom at B = 1: every point enters; it lands on its projected pixel, clamped to its 3x3 window.
    landing = torch.minimum(torch.maximum(torch.floor(screen).long(), batch.pixels - 1), batch.pixels + 1)
    landed = inside(landing, H, W)
    flow, loss, matched = dynamic_flow(screen, points[:, 2].detach(), batch.config, landed, batch.pixels, landing,
                                       batch.targets, 0, CAM)
    assert torch.equal(landed, result.landed) and torch.equal(matched, result.matched)
    assert torch.equal(flow, result.flow) and torch.equal(flow.sum(0), theta.grad)
    assert float(loss.detach()) == float(out.loss.detach())


@pytest.mark.slow
@pytest.mark.parametrize("kernel", [True, False], ids=["kernel", "torch path"])
def test_torch_compile_runs_the_layer(kernel):
    """docs/method/fast-path.md: Dynamo breaks the graph at the input checks and at the kernel's calls (or, on the torch
    path, at the pulled points' nonzero), and runs, bit for bit as eager, without warnings about sdm's code."""
    loss_of = zoom1_loss_of_theta()
    torch._dynamo.reset()
    compiled = torch.compile(loss_of, backend="eager")
    eager, traced = (torch.tensor([0.2, 0.1], dtype=torch.float64, requires_grad=True) for _ in range(2))
    with contextlib.nullcontext() if kernel else native.disabled():
        loss_of(eager).backward()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            compiled(traced).backward()
    assert torch.equal(eager.grad, traced.grad)
    # e.g. Dynamo's "call to a functools.lru_cache-wrapped function at 'flow.py:..'" for a cached constant
    assert not [str(w.message) for w in caught if "/sdm/" in w.filename or "lru_cache" in str(w.message)]


def test_importing_and_running_the_layer_leaves_dynamo_unimported():
    """Dynamo costs about 1.2 s to import; the layer wraps its kernel calls for torch.compile only while tracing."""
    probe = ("import sys, torch, sdm\n"
             "sys.path[:0] = ['tests', 'tests/mapping']\n"
             "from test_mapping import zoom1_loss_of_theta\n"
             "theta = torch.tensor([0.2, 0.1], dtype=torch.float64, requires_grad=True)\n"
             "zoom1_loss_of_theta()(theta).backward()\n"
             "assert bool(theta.grad.any())\n"
             "print(sorted(name for name in sys.modules if name.startswith('torch._dynamo')))\n")
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def layer_inputs(n=2):
    batch = small_batch(n)
    return {"points": batch.points, "pixels": batch.pixels, "target": batch.targets, "config": batch.config,
            "rank": batch.rank}


def test_half_precision_points_are_refused():
    inputs = layer_inputs()
    for dtype in (torch.float16, torch.bfloat16):
        with pytest.raises(SDMInputError, match=f"points must be float32 or float64.*{str(dtype)}"):
            SpatialDomainMapping()(**inputs | {"points": inputs["points"].to(dtype)})
    out32 = SpatialDomainMapping()(**inputs | {"points": inputs["points"].float()})  # float32 is accepted
    assert out32.loss.dtype == torch.float32


@pytest.mark.parametrize("name", ["config", "rank"])
def test_float_config_or_rank_is_refused(name):
    inputs = layer_inputs()
    with pytest.raises(SDMInputError, match=f"{name} must be int64.*torch.float64"):
        SpatialDomainMapping()(**inputs | {name: inputs[name].double()})


def test_config_is_required_for_several_targets():
    inputs = layer_inputs(2)
    del inputs["config"]
    with pytest.raises(SDMInputError, match="config is required: target holds 2 targets"):
        SpatialDomainMapping()(**inputs)
    one = layer_inputs(1)
    del one["config"]
    SpatialDomainMapping()(**one)  # a single target needs no config


@pytest.mark.parametrize("name", ["pixels", "target", "config", "rank"])
def test_inputs_on_another_device_are_refused(name):
    """``meta`` stands in for a second device: the check reads devices, never values."""
    inputs = layer_inputs()
    with pytest.raises(SDMInputError, match=f"{name} is on meta but points are on cpu"):
        SpatialDomainMapping()(**inputs | {name: inputs[name].to("meta")})
