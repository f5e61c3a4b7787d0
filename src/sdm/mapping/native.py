"""A compiled CPU kernel for the SDM chain, the paper's flow and whole training runs, with the torch path as fallback.

On the CPU the fast path's cost is not the arithmetic but the passes over memory:
every level runs some twenty torch operations over all points, each a full pass
plus dispatch (``benchmarks/bench_sdm.py`` measures it). ``_native.c`` does each
level in one loop over the points and the paper's flow in one more, with the same
integer arithmetic and the same floating-point operations in the same order as
:func:`~sdm.mapping.fast.fast_mapping`'s level loop and
:func:`~sdm.mapping.flow.dynamic_flow`, so results are equal to the bit
(``tests/test_native.py``).

The C file is compiled once per machine with the system C compiler (``$CC``,
default ``cc``) into a cache folder (``$SDM_CACHE_DIR``, default
``$XDG_CACHE_HOME/sdm`` or ``~/.cache/sdm``) and loaded with :mod:`ctypes`; no
torch headers are involved, so it takes well under a second. Where no compiler
is found, or ``SDM_NATIVE=0`` is set, the layer runs its torch path (the same
results, slower) after one warning. It serves CPU tensors (non-contiguous ones
are copied); CUDA tensors take the torch path. The chain runs in the kernel for
any gradient rule and point dtype; the flow only for the paper's rule on float64
points (other rules and float32 points get torch's flow).

It serves two callers. The layer (:func:`~sdm.mapping.fast.fast_mapping`) calls
:func:`chain` and :func:`paper_flow` once per forward pass. The trainer
(:func:`sdm.train.train_runs`) calls :func:`train_program` once per program of
``R`` runs: every level, epoch, mini-batch, projection, chain, flow (the paper's,
or ``closed_centred_r1``'s, :data:`TRAINED_RULES`), loss and SGD step in C, the
per-step Python work gone; theta histories equal the torch path's to the bit
(the loss to 1e-12 relative: its sum is compensated, not in torch's order). The
paper's flow and the centred closed rule share one window function in C.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import subprocess
import sys
import warnings
from pathlib import Path

import torch

from ..io import write_atomic
from ..representation import NO_RANK

SOURCE = Path(__file__).with_name("_native.c")
#: ``-ffp-contract=off``: no fused multiply-add, so every float operation rounds as torch's does.
FLAGS = ("-O2", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math")

_I64 = ctypes.c_int64
_PTR = ctypes.c_void_p


_switched_off = False


def enabled() -> bool:
    """Whether the compiled kernel is in use (built or loaded on first call; ``SDM_NATIVE=0`` turns it off)."""
    return not _switched_off and _library() is not None


@contextlib.contextmanager
def disabled():
    """Inside the block the layer runs its torch path (for comparisons and benchmarks; process-wide)."""
    global _switched_off
    before, _switched_off = _switched_off, True
    try:
        yield
    finally:
        _switched_off = before


def cache_dir() -> Path:
    """Where the compiled kernel is kept: ``$SDM_CACHE_DIR``, else ``$XDG_CACHE_HOME/sdm``, else ``~/.cache/sdm``."""
    if os.environ.get("SDM_CACHE_DIR"):
        return Path(os.environ["SDM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "sdm"


@functools.lru_cache(maxsize=1)
def _library():
    if os.environ.get("SDM_NATIVE", "1").strip().lower() in ("0", "off", "false", "no"):
        return None
    compiler = os.environ.get("CC", "cc")
    try:
        source = SOURCE.read_bytes()  # OSError where an install left the source out
        key = hashlib.sha256(b"\0".join([source, compiler.encode(), " ".join(FLAGS).encode(),
                                         platform.machine().encode(), sys.platform.encode()])).hexdigest()[:16]
        folder = cache_dir()  # RuntimeError where no home folder can be found
        target = folder / f"sdm_native_{key}.so"
        if not target.is_file():
            # Built beside the target and renamed into place (sdm.io.write_atomic): concurrent processes
            # (parallel workflow jobs) each build their own file, and no half-written one is ever loaded.
            write_atomic(target, lambda partial: subprocess.run(
                [compiler, *FLAGS, "-o", str(partial), str(SOURCE)], check=True, capture_output=True, text=True,
                timeout=120))
        library = ctypes.CDLL(str(target))
    except (OSError, RuntimeError, subprocess.SubprocessError) as error:
        detail = getattr(error, "stderr", "") or error
        warnings.warn(f"sdm: the compiled CPU kernel is not available ({compiler}: {str(detail).strip()[:300]}); "
                      "the SDM layer runs its torch path (same results, slower). Set CC to a C compiler, "
                      "or SDM_NATIVE=0 to silence this.", RuntimeWarning, stacklevel=3)
        return None
    library.sdm_chain.restype = None
    library.sdm_chain.argtypes = [_I64, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _I64, _I64, _PTR, _I64,
                                  _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR]
    library.sdm_paper_flow.restype = _I64
    library.sdm_paper_flow.argtypes = [_I64, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _I64,
                                       _PTR, _PTR, _PTR, _PTR]
    library.sdm_train.restype = _I64
    library.sdm_train.argtypes = [_I64, _I64, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _PTR, _I64, _I64, _I64, _I64,
                                  _PTR, _PTR, _PTR, _PTR, _I64, _PTR, _PTR, _PTR, _PTR]
    return library


def _eager_under_compile(function):
    """``function``, run eagerly by Dynamo when a graph is being traced (a ``ctypes`` call cannot be traced).

    The same as decorating it with ``torch.compiler.disable`` (one graph break per call, the kernel runs
    inside the compiled program), but applied only while tracing: the decorator imports Dynamo, about
    1.2 s, and ``sdm`` is imported by every workflow job and test process, few of which compile.
    """

    @functools.wraps(function)
    def call(*args):
        if torch.compiler.is_compiling():
            return torch.compiler.disable(function)(*args)
        return function(*args)

    return call


@_eager_under_compile
def serves(*tensors: torch.Tensor) -> bool:
    """Whether the kernel can take these tensors: all on the CPU, and the kernel available."""
    return all(t.device.type == "cpu" for t in tensors) and enabled()


@_eager_under_compile
def chain(projected: torch.Tensor, pixels: torch.Tensor, config: torch.Tensor, rank: torch.Tensor,
          scratch: torch.Tensor, height: int, width: int, steps: int, zoom: int):
    """Levels ``steps..zoom`` of the zoom chain (the level loop of :func:`~sdm.mapping.fast.fast_mapping`).

    Args:
        projected: ``(P, 2)`` int64 ``floor(P(p))``, screen pixels ``(row, col)``.
        pixels: ``(P, 2)`` int64 pixel of each point in ``I~``.
        config: ``(P,)`` int64 configuration of each point; ``rank``: ``(P,)`` int64 ``rmin`` priority.
        scratch: ``(>= n * H * W + 1,)`` int64, every entry :data:`~sdm.representation.NO_RANK`
            (and so again on return).
        height, width: the screen; steps, zoom: the levels.

    All tensors on the CPU (see :func:`serves`; non-contiguous ones are copied); the results too.

    Returns:
        ``(out_pixels, entered, landed, block, landing)``: ``(P, 2)`` int64 output pixel (``-1``
        where dropped), ``(P,)`` bool entered and landed at level ``zoom``, ``(P, 2)`` int64 input
        and landing block at level ``zoom``.
    """
    projected, pixels, config, rank = (t.contiguous() for t in (projected, pixels, config, rank))
    n_points = pixels.shape[0]
    out_pixels = torch.empty_like(pixels)
    entered = torch.empty(n_points, dtype=torch.bool, device=pixels.device)
    landed = torch.empty_like(entered)
    block, landing = torch.empty_like(pixels), torch.empty_like(pixels)
    current, cell, alive = _workspace(n_points, pixels.device)
    _library().sdm_chain(n_points, projected.data_ptr(), pixels.data_ptr(), config.data_ptr(), rank.data_ptr(),
                         height, width, steps, zoom, scratch.data_ptr(), NO_RANK, out_pixels.data_ptr(),
                         entered.data_ptr(), landed.data_ptr(), block.data_ptr(), landing.data_ptr(),
                         current.data_ptr(), cell.data_ptr(), alive.data_ptr())
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


@_eager_under_compile
def paper_flow(screen: torch.Tensor, config: torch.Tensor, landed: torch.Tensor, block: torch.Tensor,
               landing: torch.Tensor, target: torch.Tensor, zoom: int):
    """The paper's flow (:func:`~sdm.mapping.flow.dynamic_flow`) but the loss's metres.

    Args: as :func:`~sdm.mapping.flow.dynamic_flow` (``screen`` float64), all on the CPU
        (non-contiguous ones are copied).

    Returns:
        ``(flow, matched, pulled, window_l1)``: ``(P, 2)`` float64 flow, ``(P,)`` bool matched,
        ``(p,)`` int64 indices of the pulled points (ascending) and ``(p, 2)`` float64 per axis
        ``(row, col)`` the summed distance in screen pixels to the blocks pulling each of them.
    """
    screen, config, landed, block, landing, target = (
        t.contiguous() for t in (screen, config, landed, block, landing, target))
    n_points = screen.shape[0]
    grid_h, grid_w = target.shape[1:]
    flow = torch.zeros_like(screen)
    matched = torch.empty(n_points, dtype=torch.bool, device=screen.device)
    pulled = torch.empty(n_points, dtype=torch.int64, device=screen.device)
    window_l1 = torch.empty_like(screen)
    n_pulled = _library().sdm_paper_flow(n_points, screen.data_ptr(), config.data_ptr(), landed.data_ptr(),
                                         block.data_ptr(), landing.data_ptr(), target.data_ptr(), grid_h, grid_w,
                                         zoom, matched.data_ptr(), flow.data_ptr(), pulled.data_ptr(),
                                         window_l1.data_ptr())
    return flow, matched, pulled[:n_pulled], window_l1[:n_pulled]


#: The gradient rules whose whole training run the kernel does (:func:`train_program`).
TRAINED_RULES = ("paper", "closed_centred_r1")


def train_program(points: torch.Tensor, pixels: torch.Tensor, rank: torch.Tensor, offsets: torch.Tensor,
                  camera, steps: int, levels: list[int], n_epoch: int, batch_size: int, rates: list[float],
                  centred: list[bool], orders: torch.Tensor, targets: list[list[torch.Tensor]],
                  theta0: torch.Tensor):
    """``R`` whole SGD runs in one call (``sdm_train``): the compiled path of :func:`sdm.train.train_runs`.

    Args:
        points: ``(P, 3)`` float64 points ``Q`` (metres), ``pixels`` ``(P, 2)`` int64, ``rank`` ``(P,)`` int64,
            ``offsets`` ``(N + 1,)`` int64: the packed set (:class:`~sdm.batch.ConfigurationSet`).
        camera: :class:`~sdm.camera.Camera` (intrinsics and screen ``(H, W)``).
        steps: the chain's coarsest level ``s``; ``levels``: the loss levels ``s, s - 1, ...``, one after another.
        n_epoch, batch_size: epochs per level, configurations per mini-batch (the last incomplete one dropped).
        rates: the learning rate at each of ``levels``.
        centred: per level, whether it takes ``closed_centred_r1``'s window (centred on the landing block,
            on a target the caller closed) instead of the paper's flow.
        orders: ``(len(levels) * n_epoch, R, N)`` int64, each epoch's shuffling of each run.
        targets: ``R`` lists, one ``(N, H >> level, W >> level)`` bool target per level of ``levels``.
        theta0: ``(R, 2)`` float64 starts ``(a, b)``, metres.

    All tensors on the CPU (non-contiguous ones are copied); the results too.

    Returns:
        ``(thetas, losses, failed)``: ``(steps_total + 1, R, 2)`` float64 theta before the first step and after
        each, ``(steps_total, R)`` float64 loss of each step (metres), ``(R,)`` int64 the 0-based step at which
        the run's theta became non-finite (its later entries are not written), ``-1`` where it did not.
    """
    points, pixels, rank, offsets, orders, theta0 = (
        t.contiguous() for t in (points, pixels, rank, offsets, orders, theta0))
    targets = [[level.contiguous() for level in run] for run in targets]
    n_runs, n_configs = orders.shape[1], orders.shape[2]
    device = points.device
    total = len(levels) * n_epoch * (n_configs // batch_size)
    constants = torch.tensor([camera.fx, camera.fy, camera.cx, camera.cy, camera.rows_per_image_pixel,
                              camera.cols_per_image_pixel, camera.fy * camera.rows_per_image_pixel,
                              camera.fx * camera.cols_per_image_pixel], dtype=torch.float64, device=device)
    rates_t = torch.tensor(rates, dtype=torch.float64, device=device)
    centred_t = torch.tensor(centred, dtype=torch.uint8, device=device)
    addresses = torch.tensor([[level.data_ptr() for level in run] for run in targets], dtype=torch.int64,
                             device=device)
    thetas = torch.empty(total + 1, n_runs, 2, dtype=torch.float64, device=device)
    losses = torch.zeros(total, n_runs, dtype=torch.float64, device=device)
    failed = torch.empty(n_runs, dtype=torch.int64, device=device)
    height, width = camera.screen_shape
    code = _library().sdm_train(
        n_runs, n_configs, offsets.data_ptr(), points.data_ptr(), pixels.data_ptr(), rank.data_ptr(), height, width,
        constants.data_ptr(), steps, len(levels), n_epoch, batch_size, rates_t.data_ptr(), centred_t.data_ptr(),
        orders.data_ptr(), addresses.data_ptr(), NO_RANK, theta0.data_ptr(), thetas.data_ptr(), losses.data_ptr(),
        failed.data_ptr())
    if code != 0:
        raise MemoryError("sdm_train: no memory for one configuration's working rows")
    return thetas, losses, failed
