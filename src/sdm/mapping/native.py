"""The compiled CPU kernel's bindings for the layer (the SDM chain and the paper's flow) and the trainer.

On the CPU the fast path's cost is not the arithmetic but the passes over memory:
every zoom runs some twenty torch operations over all points, each a full pass
plus dispatch (``benchmarks/speed/bench_sdm.py`` measures it). ``kernel/chain.c`` does each
zoom in one loop over the points and the paper's flow in one more, with the same
integer arithmetic and the same floating-point operations in the same order as
:func:`~sdm.mapping.fast.fast_mapping`'s zoom loop and
:func:`~sdm.mapping.flow.dynamic_flow`, so results are equal to the bit
(``tests/mapping/test_native.py``). The library is built, cached and loaded by :mod:`sdm.mapping.build`; whenever it
cannot be used the layer runs its torch path (the same results, slower). It serves CPU tensors (non-contiguous
ones are copied); CUDA tensors take the torch path. The chain runs in the kernel for
any gradient rule and point dtype; the flow only for the paper's rule on float64
points (other rules and float32 points get torch's flow).

It serves two callers. The layer (:func:`~sdm.mapping.fast.fast_mapping`) calls
:func:`chain` and :func:`paper_flow` once per forward pass. The trainer
(:func:`sdm.train.train_runs`) calls :func:`train_program` once per program of
``R`` runs: every zoom, epoch, mini-batch, projection, chain, flow (the paper's,
``closed_centred_r1``'s or ``group_crossing``'s: :meth:`sdm.mapping.rules.Rule.kernel_flows`), loss and SGD step
in C, the per-step Python work gone; theta histories equal the torch path's to the bit
(the loss to 1e-12 relative: its sum is compensated, not in torch's order). The
paper's flow and the centred closed rule share one window function in C. Its
chain runs in int32 with the per-coordinate arithmetic vectorised, its
projection two points per AVX2 register where the CPU has it (picked at run
time), and it zooms the runs' targets out itself (``kernel/train.c`` and its parts say why each
keeps the bits). The kernel's other callers have bindings of their own: :mod:`sdm.sky_native` (the paired runs'
noise) and :mod:`sdm.experiments.baselines.cmaes_native` (the CMA-ES baseline's count).
"""
from __future__ import annotations

import threading
import weakref

import torch

from ..errors import SDMInputError
from ..representation import NO_RANK
# enabled, disabled and serves: what the layer's and the trainer's callers ask of the kernel (sdm.mapping.build's).
# The calls below read the library as _library.
from .build import disabled, enabled, eager_under_compile, serves  # noqa: F401
from .build import check_arrays
from .build import library as _library
from .crossing import CROSSING_SCALE, CROSSING_STEPS, CROSSING_WIDTH, rigid_groups
from .rules import KernelFlow


#: The largest start pixel (either sign) :func:`chain` takes: moved by less than ``2^61`` pixels over at most 60
#: zooms, it stays within int64.
PIXEL_BOUND = 2**61


def _check_range(call: str, name: str, values: torch.Tensor, low: int, high: int) -> None:
    """:class:`SDMInputError` naming ``call`` and ``name`` unless every entry of ``values`` lies in ``[low, high)``."""
    if values.numel() and (int(values.min()) < low or int(values.max()) >= high):
        raise SDMInputError(f"{call}: {name} must lie in [{low}, {high}), got entries in "
                            f"[{int(values.min())}, {int(values.max())}]")


def _check_screen(call: str, height, width, s, zoom) -> None:
    """:class:`SDMInputError` naming ``call`` unless the screen is positive and ``0 <= zoom <= s <= 60``."""
    for name, value in (("height", height), ("width", width), ("s", s), ("zoom", zoom)):
        if isinstance(value, bool) or not isinstance(value, int):
            raise SDMInputError(f"{call}: {name} must be an integer, got {value!r}")
    if height < 1 or width < 1 or not 0 <= zoom <= s <= 60:
        raise SDMInputError(f"{call}: needs a positive screen and 0 <= zoom <= s <= 60, got a {height} x {width} "
                            f"screen, s {s}, zoom {zoom}")


@eager_under_compile
def chain(projected: torch.Tensor, pixels: torch.Tensor, config: torch.Tensor, rank: torch.Tensor,
          scratch: torch.Tensor, height: int, width: int, s: int, zoom: int):
    """Zooms ``s..zoom`` of the zoom chain (the zoom loop of :func:`~sdm.mapping.fast.fast_mapping`).

    Args:
        projected: ``(P, 2)`` int64 ``floor(P(p))``, screen pixels ``(row, col)``.
        pixels: ``(P, 2)`` int64 pixel of each point in ``I~``.
        config: ``(P,)`` int64 configuration of each point; ``rank``: ``(P,)`` int64 ``rmin`` priority.
        scratch: ``(>= 2 * (n * H * W + 1),)`` int64 (the kernel's two alternating rmin tables), every entry
            :data:`~sdm.representation.NO_RANK` (and so again on return).
        height, width: the screen; s, zoom: the coarsest and the finest zoom.

    All tensors on the CPU (see :func:`serves`; non-contiguous ones are copied); the results too.
    :func:`check_arrays` checks their shapes against each other first; the kernel checks ``config`` against the
    tables ``scratch`` holds and the start pixels against :data:`PIXEL_BOUND` in its first pass, before any write.

    Returns:
        ``(out_pixels, entered, landed, block, landing)``: ``(P, 2)`` int64 output pixel (``-1``
        where dropped), ``(P,)`` bool entered and landed at zoom ``zoom``, ``(P, 2)`` int64 input
        and landing block at zoom ``zoom``.
    """
    projected, pixels, config, rank = (t.contiguous() for t in (projected, pixels, config, rank))
    int64 = torch.int64
    check_arrays("chain", projected=(projected, int64, ("P", 2)), pixels=(pixels, int64, ("P", 2)),
                 config=(config, int64, ("P",)), rank=(rank, int64, ("P",)), scratch=(scratch, int64, ("M",)))
    _check_screen("chain", height, width, s, zoom)
    n_points = pixels.shape[0]
    out_pixels = torch.empty_like(pixels)
    entered = torch.empty(n_points, dtype=torch.bool, device=pixels.device)
    landed = torch.empty_like(entered)
    block, landing = torch.empty_like(pixels), torch.empty_like(pixels)
    current, cell, alive = _workspace(n_points, pixels.device)
    code = _library().sdm_chain(n_points, projected.data_ptr(), pixels.data_ptr(), config.data_ptr(),
                                rank.data_ptr(), height, width, s, zoom, scratch.data_ptr(), scratch.numel(),
                                NO_RANK, out_pixels.data_ptr(), entered.data_ptr(), landed.data_ptr(),
                                block.data_ptr(), landing.data_ptr(), current.data_ptr(), cell.data_ptr(),
                                alive.data_ptr())
    if code == -1:  # the kernel checks the values in its first pass over the points, before any write
        raise SDMInputError(f"chain: config must lie in [0, {(scratch.numel() // 2 - 1) // (height * width)}) (the "
                            f"configurations the scratch tables hold), got entries in [{int(config.min())}, "
                            f"{int(config.max())}]")
    if code == -2:
        raise SDMInputError(f"chain: pixels must lie within +-{PIXEL_BOUND} (PIXEL_BOUND)")
    return out_pixels, entered, landed, block, landing


#: Per device, the chain's working rows (reused: fresh pages for every call would cost more than the
#: chain on large batches).
_WORKSPACE: dict[torch.device, tuple[torch.Tensor, torch.Tensor]] = {}


def _workspace(n_points: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(P, 2)`` int64 current pixels, ``(P,)`` int64 cells and ``(P,)`` bool alive: scratch on ``device``."""
    rows, flags = _WORKSPACE.get(device, (None, None))
    if rows is None or rows.shape[0] < n_points:
        rows = torch.empty(n_points, 3, dtype=torch.int64, device=device)
        flags = torch.empty(n_points, dtype=torch.bool, device=device)
        _WORKSPACE[device] = rows, flags
    flat = rows.view(-1)
    return flat[: 2 * n_points].view(n_points, 2), flat[2 * n_points : 3 * n_points], flags[:n_points]


@eager_under_compile
def paper_flow(screen: torch.Tensor, config: torch.Tensor, landed: torch.Tensor, block: torch.Tensor,
               landing: torch.Tensor, target: torch.Tensor, zoom: int):
    """The paper's flow (:func:`~sdm.mapping.flow.dynamic_flow`) but the loss's metres.

    Args: as :func:`~sdm.mapping.flow.dynamic_flow` (``screen`` float64), all on the CPU
        (non-contiguous ones are copied); :func:`check_arrays` checks their shapes against each other first, and the
        kernel each landed point (its ``config`` one of the targets, its ``landing`` on the grid and beside its
        ``block``) before it reads the target.

    Returns:
        ``(flow, matched, pulled, window_l1)``: ``(P, 2)`` float64 flow, ``(P,)`` bool matched,
        ``(p,)`` int64 indices of the pulled points (ascending) and ``(p, 2)`` float64 per axis
        ``(row, col)`` the summed distance in screen pixels to the blocks pulling each of them.
    """
    screen, config, landed, block, landing, target = (
        t.contiguous() for t in (screen, config, landed, block, landing, target))
    int64 = torch.int64
    sizes = check_arrays("paper_flow", screen=(screen, torch.float64, ("P", 2)), config=(config, int64, ("P",)),
                         landed=(landed, torch.bool, ("P",)), block=(block, int64, ("P", 2)),
                         landing=(landing, int64, ("P", 2)), target=(target, torch.bool, ("n", "h", "w")))
    _check_screen("paper_flow", sizes["h"], sizes["w"], zoom, zoom)
    n_points = screen.shape[0]
    grid_h, grid_w = target.shape[1:]
    flow = torch.zeros_like(screen)
    matched = torch.empty(n_points, dtype=torch.bool, device=screen.device)
    pulled = torch.empty(n_points, dtype=torch.int64, device=screen.device)
    window_l1 = torch.empty_like(screen)
    n_pulled = _library().sdm_paper_flow(n_points, screen.data_ptr(), config.data_ptr(), landed.data_ptr(),
                                         block.data_ptr(), landing.data_ptr(), target.data_ptr(), sizes["n"], grid_h,
                                         grid_w, zoom, matched.data_ptr(), flow.data_ptr(), pulled.data_ptr(),
                                         window_l1.data_ptr())
    if n_pulled < 0:  # the kernel checks each landed point before it reads the target
        raise SDMInputError(f"paper_flow: every landed point's config must lie in [0, {sizes['n']}) (the targets), "
                            f"its landing on the {grid_h} x {grid_w} grid and beside its block")
    return flow, matched, pulled[:n_pulled], window_l1[:n_pulled]


#: The largest screen side and pixel count :func:`train_program` takes: its chain runs on int32
#: (``TRAIN_MAX_SIDE`` and ``TRAIN_MAX_CELLS`` in ``kernel/train.h``); larger screens train on the torch path.
TRAIN_MAX_SIDE, TRAIN_MAX_CELLS = 2**24, 2**30


def trains_screen(screen_shape) -> bool:
    """Whether :func:`train_program` takes a screen of ``screen_shape`` ``(H, W)`` pixels (see ``TRAIN_MAX_SIDE``)."""
    height, width = screen_shape
    return max(height, width) <= TRAIN_MAX_SIDE and height * width < TRAIN_MAX_CELLS


def train_program(points: torch.Tensor, pixels: torch.Tensor, rank: torch.Tensor, offsets: torch.Tensor,
                  camera, s: int, zooms: list[int], n_epoch: int, batch_size: int, rates: list[float],
                  windows: list[KernelFlow], orders: torch.Tensor, targets: list[list[torch.Tensor | None]],
                  theta0: torch.Tensor, bases: list[torch.Tensor] | None = None,
                  param_index: torch.Tensor | None = None, record_every: int = 1,
                  row_rate: torch.Tensor | None = None, crossing_widths: list[float] | None = None):
    """``R`` whole SGD runs in one call (``sdm_train``): the compiled path of :func:`sdm.train.train_runs`.

    Args:
        points: ``(P, 3)`` float64 points ``Q`` (metres), ``pixels`` ``(P, 2)`` int64, ``rank`` ``(P,)`` int64,
            ``offsets`` ``(N + 1,)`` int64: the packed set (:class:`~sdm.batch.ConfigurationSet`).
        camera: :class:`~sdm.camera.Camera` (intrinsics and screen ``(H, W)``).
        s: the chain's coarsest zoom; ``zooms``: the loss zooms (each in ``0..s``), one after
            another (the paper's ``s, s - 1, ...``; a refinement's ``0, 0, ...``).
        n_epoch, batch_size: epochs per zoom, configurations per mini-batch (the last incomplete one dropped).
        rates: the learning rate at each of ``zooms``.
        windows: per zoom, the flow (:meth:`sdm.mapping.rules.Rule.kernel_flows`), a
            :class:`~sdm.mapping.rules.KernelFlow`: ``PAPER``; ``CENTRED``, ``closed_centred_r1``'s window
            (centred on the landing block, on the zoom's target closed 3 x 3 by the kernel, as
            :func:`sdm.mapping.rules.closing` ``(3)``); ``CROSSING``, ``group_crossing``'s flow (zoom 0 only;
            the loss is then the mismatch count).
        crossing_widths: ``None`` (:data:`sdm.mapping.crossing.CROSSING_WIDTH` at every zoom) or, per entry of
            ``zooms``, ``group_crossing``'s kernel half-width in metres at that zoom (read at its
            ``CROSSING`` zooms only; a refinement's passes, :attr:`sdm.train.Refinement.widths`).
        orders: ``(len(zooms) * n_epoch, R, N)`` int64, each epoch's shuffling of each run.
        targets: ``R`` lists, one ``(N, H >> zoom, W >> zoom)`` bool target per entry of ``zooms``, or
            ``None``: the kernel zooms ``bases[r]`` out to that zoom itself (as
            :func:`sdm.zoom.target_pyramid`; into one buffer the runs reuse, which spares each noise run the
            allocation and passes of a fresh pyramid).
        theta0: ``(R, 2)`` float64 starts ``(a, b)``, metres; ``(R, K, 2)`` with ``param_index``.
        bases: ``R`` ``(N, H, W)`` bool zoom-0 targets, one per run (needed where ``targets`` holds ``None``).
        param_index: ``None`` (every point moved by the one shared shift) or ``(P, G)`` int64, checked by the
            caller (:func:`sdm.train.train_runs`): point ``i`` is moved by the sum of rows
            ``param_index[i, 0..G-1]`` of its run's ``(K, 2)`` theta, and each of those rows takes its flow.
            With ``group_crossing``, every rigid group's points must share their rows.
        row_rate: ``None`` or ``(L, K)`` float64, each row's factor on the rate of each of ``zooms`` (with
            ``param_index``; 0 leaves the row where it is at that zoom).
        record_every: theta is recorded before the first step and after every ``record_every``-th step (the
            total number of steps must be a multiple of it).

    All tensors on the CPU (non-contiguous ones are copied); the results too. :func:`check_program` checks every
    argument against the others first: nothing the kernel reads or writes lies outside its tensor.

    Returns:
        ``(thetas, losses, failed)``: ``(steps_total / record_every + 1, R, 2)`` float64 theta before the first
        step and after every ``record_every``-th (``(..., R, K, 2)`` with ``param_index``), ``(steps_total, R)``
        float64 loss of each step (metres), ``(R,)`` int64 the 0-based step at which the run's theta became
        non-finite (the record after it holds the non-finite theta, later ones are not written), ``-1`` where it
        did not.
    """
    points, pixels, rank, offsets, orders, theta0 = (
        _contiguous(t) for t in (points, pixels, rank, offsets, orders, theta0))
    targets = [[_contiguous(target) for target in run] for run in targets]
    bases = [_contiguous(base) for base in bases] if bases is not None else None
    if isinstance(param_index, torch.Tensor) and param_index.dim() == 1:
        param_index = param_index[:, None]
    param_index, row_rate = _contiguous(param_index), _contiguous(row_rate)
    check_program(points, pixels, rank, offsets, camera, s, zooms, n_epoch, batch_size, rates, windows, orders,
                  targets, theta0, bases, param_index, record_every, row_rate, crossing_widths)
    n_runs, n_configs = orders.shape[1], orders.shape[2]
    device = points.device
    total = len(zooms) * n_epoch * (n_configs // batch_size)
    row_shape = tuple(theta0.shape[1:])  # (2,), or (K, 2) with param_index
    n_rows = theta0.shape[1] if param_index is not None else 1
    constants = torch.tensor([camera.fx, camera.fy, camera.cx, camera.cy, camera.rows_per_image_pixel,
                              camera.cols_per_image_pixel, camera.fy * camera.rows_per_image_pixel,
                              camera.fx * camera.cols_per_image_pixel], dtype=torch.float64, device=device)
    rates_t = torch.tensor(rates, dtype=torch.float64, device=device)
    zooms_t = torch.tensor(zooms, dtype=torch.int64, device=device)
    modes_t = torch.tensor([int(window) for window in windows], dtype=torch.uint8, device=device)
    groups = (_crossing_groups(points, offsets, param_index) if KernelFlow.CROSSING in windows
              else (torch.zeros(1, dtype=torch.int64),) * 3)
    crossing = _crossing_constants(device, crossing_widths, len(zooms))
    addresses = torch.tensor([[target.data_ptr() if target is not None else 0 for target in run] for run in targets],
                             dtype=torch.int64, device=device)
    height, width = camera.screen_shape
    # as sdm_train lays it out: the zoomed-out targets where it zooms any out, then the closed targets
    zooms_out = any(target is None and zoom > 0 for run in targets for target, zoom in zip(run, zooms))
    pyramid = _pyramid_scratch(n_configs * sum((height >> k) * (width >> k) for k in range(1, s + 1)) * zooms_out
                               + n_configs * height * width * (KernelFlow.CENTRED in windows), device)
    base_addresses = torch.tensor([base.data_ptr() for base in bases] if bases is not None else [0] * n_runs,
                                  dtype=torch.int64, device=device)
    thetas = torch.empty(total // record_every + 1, n_runs, *row_shape, dtype=torch.float64, device=device)
    losses = torch.zeros(total, n_runs, dtype=torch.float64, device=device)
    failed = torch.empty(n_runs, dtype=torch.int64, device=device)
    code = _library().sdm_train(
        n_runs, n_configs, offsets.data_ptr(), points.data_ptr(), pixels.data_ptr(), rank.data_ptr(), height, width,
        constants.data_ptr(), s, len(zooms), n_epoch, batch_size, zooms_t.data_ptr(), rates_t.data_ptr(),
        modes_t.data_ptr(), *(group.data_ptr() for group in groups), crossing.data_ptr(), orders.data_ptr(),
        addresses.data_ptr(), base_addresses.data_ptr(), pyramid.data_ptr(), NO_RANK, n_rows,
        param_index.shape[1] if param_index is not None else 1,
        param_index.data_ptr() if param_index is not None else None,
        row_rate.data_ptr() if row_rate is not None else None, record_every, theta0.data_ptr(),
        thetas.data_ptr(), losses.data_ptr(), failed.data_ptr())
    if code == -2:
        raise ValueError(f"sdm_train: a {height} x {width} screen is beyond its int32 chain (trains_screen)")
    if code == -3:
        raise ValueError(f"sdm_train: zooms {zooms} outside 0..{s}, or CROSSING above zoom 0: "
                         f"{[(window.name, zoom) for window, zoom in zip(windows, zooms)]}")
    if code != 0:
        raise MemoryError("sdm_train: no memory for one configuration's working rows")
    return thetas, losses, failed


def check_program(points, pixels, rank, offsets, camera, s, zooms, n_epoch, batch_size, rates, windows, orders,
                  targets, theta0, bases=None, param_index=None, record_every=1, row_rate=None,
                  crossing_widths=None) -> None:
    """:func:`train_program`'s arguments checked against each other, as ``sdm_train`` reads them.

    The sizes: ``P`` points, ``N`` configurations (``offsets``: ``0``, non-decreasing, ``P`` last), ``R`` runs
    (``orders``, ``targets``, ``bases``, ``theta0``), ``L`` loss zooms (``zooms`` in ``0..s``, ``rates``,
    ``windows``, ``crossing_widths``, each run's ``targets`` and ``row_rate``'s rows), ``K`` rows of theta
    (``theta0``, ``row_rate``'s columns, the entries of ``param_index``). Every shuffled configuration lies in
    ``0..N-1``; every target at zoom ``k`` is ``(N, H >> k, W >> k)`` bool; the screen divides into blocks of
    ``2^s``; the steps are a multiple of ``record_every``.

    Raises:
        SDMInputError: naming ``train_program`` and the argument.
    """
    call, int64 = "train_program", torch.int64
    height, width = camera.screen_shape
    _check_screen(call, height, width, s, 0)
    if height % (1 << s) or width % (1 << s):
        raise SDMInputError(f"{call}: a {height} x {width} screen does not divide into blocks of 2^{s} pixels")
    for name, value in (("n_epoch", n_epoch), ("batch_size", batch_size), ("record_every", record_every)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise SDMInputError(f"{call}: {name} must be a positive integer, got {value!r}")
    n_zooms = len(zooms)
    if n_zooms == 0 or any(isinstance(zoom, bool) or not isinstance(zoom, int) or not 0 <= zoom <= s
                           for zoom in zooms):
        raise SDMInputError(f"{call}: zooms must be integers in 0..{s}, at least one, got {zooms}")
    for name, per_zoom in (("rates", rates), ("windows", windows), ("crossing_widths", crossing_widths)):
        if per_zoom is not None and len(per_zoom) != n_zooms:
            raise SDMInputError(f"{call}: {name} must hold one entry per zoom ({n_zooms}), got {len(per_zoom)}")
    if not all(isinstance(window, KernelFlow) for window in windows):  # sdm_train refuses an unknown mode (-3)
        raise SDMInputError(f"{call}: windows must be sdm.mapping.rules.KernelFlow, got {windows}")
    if any(window is KernelFlow.CROSSING and zoom != 0 for window, zoom in zip(windows, zooms)):
        raise SDMInputError(f"{call}: CROSSING runs at zoom 0 only, got zooms {zooms} for windows "
                            f"{[window.name for window in windows]}")
    if not isinstance(orders, torch.Tensor) or orders.dim() != 3 or len(targets) != orders.shape[1]:
        raise SDMInputError(f"{call}: orders must be (zooms * n_epoch, R, N) and targets hold its R runs, got orders "
                            f"{tuple(getattr(orders, 'shape', ()))} and {len(targets)} runs of targets")
    if any(len(run) != n_zooms for run in targets):
        raise SDMInputError(f"{call}: targets must hold {n_zooms} zooms a run, got {[len(run) for run in targets]}")
    if bases is None and any(target is None for run in targets for target in run):
        raise SDMInputError(f"{call}: a zoom left to the kernel (None) needs the run's zoom-0 target in bases")
    if bases is not None and len(bases) != len(targets):
        raise SDMInputError(f"{call}: bases must hold one target per run ({len(targets)}), got {len(bases)}")
    if (not isinstance(theta0, torch.Tensor) or (param_index is None) != (theta0.dim() == 2)
            or (row_rate is not None and param_index is None)):
        raise SDMInputError(f"{call}: theta0 must be (R, 2) without param_index and row_rate, (R, K, 2) with "
                            f"param_index, got {tuple(getattr(theta0, 'shape', ()))} and param_index "
                            f"{None if param_index is None else tuple(param_index.shape)}")
    arrays = dict(offsets=(offsets, int64, ("N+1",)), points=(points, torch.float64, ("P", 3)),
                  pixels=(pixels, int64, ("P", 2)), rank=(rank, int64, ("P",)),
                  orders=(orders, int64, (n_zooms * n_epoch, "R", "N")))
    for run, run_targets in enumerate(targets):
        arrays.update({f"targets[{run}] at zoom {zoom}": (target, torch.bool, ("N", height >> zoom, width >> zoom))
                       for zoom, target in zip(zooms, run_targets) if target is not None})
    arrays.update({f"bases[{run}]": (base, torch.bool, ("N", height, width)) for run, base in enumerate(bases or [])})
    if param_index is None:
        arrays["theta0"] = (theta0, torch.float64, ("R", 2))
    else:
        arrays.update(theta0=(theta0, torch.float64, ("R", "K", 2)), param_index=(param_index, int64, ("P", "G")))
        if row_rate is not None:
            arrays["row_rate"] = (row_rate, torch.float64, (n_zooms, "K"))
    sizes = check_arrays(call, **arrays)
    n_configs = sizes["N"]
    if n_configs < 1 or int(offsets[0]) != 0 or int(offsets[-1]) != sizes["P"] or bool((offsets.diff() < 0).any()):
        raise SDMInputError(f"{call}: offsets must run from 0 to the {sizes['P']} points, non-decreasing, with at "
                            "least one configuration")
    _check_range(call, "orders", orders, 0, n_configs)
    if batch_size > n_configs:
        raise SDMInputError(f"{call}: batch_size {batch_size} is more than the {n_configs} configurations")
    total = n_zooms * n_epoch * (n_configs // batch_size)
    if total % record_every:
        raise SDMInputError(f"{call}: {total} steps are not a multiple of record_every {record_every}")
    if param_index is not None:
        if sizes["G"] < 1:
            raise SDMInputError(f"{call}: param_index must name at least one row per point")
        _check_range(call, "param_index", param_index, 0, sizes["K"])


def _contiguous(tensor):
    """``tensor`` C-contiguous (anything else as it is, for :func:`check_program` to name)."""
    return tensor.contiguous() if isinstance(tensor, torch.Tensor) else tensor

#: _crossing_groups' last layout: (weak references to points and offsets, their versions, the layout). A set's
#: groups depend on its points only, and the paired runs train the same set again and again (a call per group).
_GROUPS_CACHE: list = []


def _crossing_groups(points: torch.Tensor, offsets: torch.Tensor,
                     rows: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``group_crossing``'s rigid groups of a packed set for ``sdm_train``, on the device of ``points``.

    Returns ``(config_group (N + 1,) int64, group_start (G + 1,) int64, members (P,) int32)``: configuration
    ``c``'s groups are ``config_group[c] .. config_group[c + 1]``, group ``g``'s points (indices within their
    configuration, ascending) ``members[group_start[g] .. group_start[g + 1]]``; groups as
    :func:`sdm.mapping.crossing.rigid_groups` numbers them (configuration, then depth). With ``rows`` ``(P, G)``
    (parameters attached to points) a group is further split by its points' rows, so that each group moves as
    one shift (two cars of one configuration may lie at one depth), numbered by configuration, depth, rows.
    """
    if rows is not None:
        return _crossing_layout(points, offsets, rows)
    key = (points._version, offsets._version)
    if _GROUPS_CACHE and _GROUPS_CACHE[0]() is points and _GROUPS_CACHE[1]() is offsets and _GROUPS_CACHE[2] == key:
        return _GROUPS_CACHE[3]
    layout = _crossing_layout(points, offsets)
    _GROUPS_CACHE[:] = [weakref.ref(points), weakref.ref(offsets), key, layout]  # weak: the set may go
    return layout


def _crossing_layout(points: torch.Tensor, offsets: torch.Tensor,
                     rows: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_crossing_groups`, computed."""
    counts = offsets[1:] - offsets[:-1]
    config = torch.repeat_interleave(torch.arange(counts.numel(), device=points.device), counts)
    if points.shape[0] == 0:
        return (torch.zeros(counts.numel() + 1, dtype=torch.int64, device=points.device),
                torch.zeros(1, dtype=torch.int64, device=points.device),
                torch.zeros(1, dtype=torch.int32, device=points.device))
    group, first = rigid_groups(points[:, :2], points[:, 2], config)
    if rows is not None:  # split each group by its points' rows (sorted: configuration, depth, rows)
        group = torch.unique(torch.cat((group[:, None], rows), 1), dim=0, return_inverse=True)[1]
        first = torch.full((int(group.max()) + 1,), points.shape[0], dtype=torch.int64, device=points.device)
        first.scatter_reduce_(0, group, torch.arange(points.shape[0], device=points.device), "amin")
    order = torch.argsort(group, stable=True)
    members = (order - offsets.index_select(0, config.index_select(0, order))).to(torch.int32)
    sizes = torch.bincount(group, minlength=first.numel())
    group_start = torch.cat((sizes.new_zeros(1), torch.cumsum(sizes, 0)))
    per_config = torch.bincount(config.index_select(0, first), minlength=counts.numel())
    config_group = torch.cat((per_config.new_zeros(1), torch.cumsum(per_config, 0)))
    return config_group, group_start, members.contiguous()


def _crossing_constants(device: torch.device, widths: list[float] | None, n_zooms: int) -> torch.Tensor:
    """``(n_zooms, 3)`` float64, per zoom: ``group_crossing``'s kernel half-width (metres; ``widths[i]``,
    :data:`~sdm.mapping.crossing.CROSSING_WIDTH` for ``None``), flow scale and kernel steps."""
    widths = [CROSSING_WIDTH] * n_zooms if widths is None else [float(width) for width in widths]
    return torch.tensor([[width, CROSSING_SCALE, float(CROSSING_STEPS)] for width in widths], dtype=torch.float64,
                        device=device).reshape(n_zooms, 3)

#: Per thread, the compiled trainer's pyramid scratch (:func:`train_program`): kept, because on the machines
#: measured the first touch of fresh pages (a noise run's pyramid is 5.6 MB) cost more than zooming out.
_SCRATCH = threading.local()


def _pyramid_scratch(n_bytes: int, device: torch.device) -> torch.Tensor:
    """A uint8 buffer of at least ``n_bytes`` on ``device`` (the trainer's inputs': the CPU; this thread's,
    reused by later calls). Never device-less: under ``torch.set_default_device`` that would not be memory
    the kernel can write (tests/test_devices.py)."""
    buffer = getattr(_SCRATCH, "pyramid", None)
    if buffer is None or buffer.numel() < n_bytes or buffer.device != device:
        buffer = _SCRATCH.pyramid = torch.empty(max(n_bytes, 1), dtype=torch.uint8, device=device)
    return buffer
