"""A compiled CPU kernel for the SDM chain and the paper's flow, with the torch path as fallback.

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
    library.sdm_pixel_mismatch.restype = None  # the CMA-ES baseline's count (pixel_mismatch)
    library.sdm_pixel_mismatch.argtypes = [_I64, _PTR, _I64, _I64, *[_PTR] * 8, _I64, _I64, _PTR, _I64, *[_PTR] * 3]
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


@_eager_under_compile
def pixel_mismatch(thetas: torch.Tensor, layout, table: torch.Tensor, n_target: int) -> torch.Tensor:
    """The CMA-ES baseline's exact zoom-0 pixel mismatch for ``K`` candidates in one pass over the points.

    Args:
        thetas: ``(K, 2)`` float64 candidates ``(a, b)``, metres, on the CPU.
        layout: a usable :class:`sdm.baselines.cmaes.ShiftLayout` on the CPU (its grouping and scratch).
        table: ``(N * Hp * Wp,)`` int8 weight + 1 per padded pixel (:meth:`ShiftLayout.table` with ``compact``).
        n_target: active target pixels of the run.

    Returns:
        ``(K,)`` int64 counts (false positives + false negatives), ``-1`` for a candidate whose group
        shifts cannot be trusted (the caller counts it by the torch reference).
    """
    thetas = thetas.to(torch.float64).contiguous()
    n_candidates = thetas.shape[0]
    n_groups = layout.gain.shape[0]
    offsets = layout.native_offsets(n_candidates)
    counts = torch.empty(n_candidates, dtype=torch.int64)
    _library().sdm_pixel_mismatch(
        n_candidates, thetas.data_ptr(), n_groups, layout.config_group.shape[0] - 1, layout.gain.data_ptr(),
        layout.frac_bounds.data_ptr(), layout.shift_low.data_ptr(), layout.shift_high.data_ptr(),
        layout.group_start.data_ptr(), layout.config_group.data_ptr(), layout.cells.data_ptr(), table.data_ptr(),
        layout.padded_shape[0] * layout.padded_shape[1], layout.padded_shape[1], layout.limits.data_ptr(),
        int(n_target), offsets.data_ptr(), layout.stamp.data_ptr(), counts.data_ptr())
    return counts

