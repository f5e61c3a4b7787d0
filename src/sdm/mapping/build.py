"""The compiled CPU kernel's build cache: the C files of ``kernel/`` compiled once per machine into one library, checked
and loaded with ctypes.

The kernel serves three callers, each through a binding module of its own that imports this one: the layer and
the trainer (:mod:`sdm.mapping.native`), the paired runs' noise (:mod:`sdm.sky_native`) and the CMA-ES baseline's
count (:mod:`sdm.experiments.baselines.cmaes_native`). :func:`library` is the loaded library, its functions typed by
:data:`SIGNATURES`; :func:`check_arrays` checks a binding's arrays before a call.

The kernel's sources (:data:`SOURCES`, one file per concern: ``chain.c`` the layer's chain and flow, ``train.c``
and its parts the trainer, ``noise.c`` the paired runs' noise, ``mismatch.c`` the CMA-ES count; the headers
:data:`HEADERS`) are compiled once per machine, in one call of the system C compiler (``$CC``, default ``cc``,
split into words as a shell would: ``CC="ccache gcc"``), into one library in a cache folder (``$SDM_CACHE_DIR``,
default ``$XDG_CACHE_HOME/sdm`` or ``~/.cache/sdm``) and loaded with :mod:`ctypes`; no torch headers are involved,
so it takes a few seconds at most.

The cache (:func:`cache_files`) holds ``sdm_native_<key>.so``, its SHA-256 in
``sdm_native_<key>.sha256`` and, after a failed build, ``sdm_native_<key>.failed``;
the key hashes every source and header, ``$CC``, the flags and the platform. A cached library
is checked against its checksum before it is loaded, never by loading it (a
truncated one kills the process with SIGBUS inside ``dlopen``); a missing,
damaged or foreign one is rebuilt. A build is checked before it is cached: the
compiler must exit 0 within :data:`BUILD_TIMEOUT_S` (it runs in a session of its
own; on timeout its whole process group is killed) and write a non-empty library
that loads and has every function of :data:`SIGNATURES`. A failed build is
written to the ``.failed`` file, and later processes warn with it instead of
running the compiler again (parallel workflow jobs do not each wait for a hanging
compiler): delete that file to build again; a different ``CC`` or a changed
source has a key of its own and builds by itself. A compiler that cannot be
found is not remembered (that costs nothing to find out again). Deleting the
cache folder is always safe.

Whenever the kernel cannot be used its callers run their torch paths (the same
results, slower) after one warning that says why (and, where a cached file or a
build failed, which file and what cause); with ``SDM_NATIVE=0`` they do so
without a warning. It serves CPU tensors only (:func:`serves`).
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import shlex
import signal
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import torch

from ..errors import SDMInputError
from ..io import cache_dir, write_atomic, write_text

#: The kernel's folder beside this module: its C sources, each compiled into the one library, and the headers they
#: include. Every file of the folder is one of them (tests/mapping/test_native_cache.py holds it), so the cache key
#: (:func:`cache_files`) covers each byte the compiler reads.
KERNEL = Path(__file__).with_name("kernel")
SOURCES = tuple(KERNEL / name for name in ("chain.c", "crossing.c", "mismatch.c", "noise.c", "targets.c", "train.c",
                                           "train_setup.c"))
HEADERS = tuple(KERNEL / name for name in ("kernel.h", "targets.h", "train.h", "train_points.h"))
#: ``-ffp-contract=off``: no fused multiply-add, so every float operation rounds as torch's does. ``-O3``
#: vectorises loops, float ones only elementwise (without ``-ffast-math`` nothing is reassociated); the
#: trainer's AVX2 code is chosen at run time inside the library, so no ``-march`` (and no CPU in the key).
FLAGS = ("-O3", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math")

_I64 = ctypes.c_int64
_PTR = ctypes.c_void_p

#: Seconds the C compiler may run before it and every process it started are killed. The build takes
#: 2 s of CPU, 4-5 s wall on a loaded 2-core machine (``cc`` on :data:`SOURCES`, load average 3.5); 30 s leaves
#: six times that for slow disks, a cold ``ccache`` and many jobs building at once, while a hanging
#: compiler costs the first processes half a minute once instead of two minutes each (the failure
#: is then remembered, see :func:`cache_files`).
BUILD_TIMEOUT_S = 30.0

#: The kernel's functions, name -> ``(restype, argtypes)``: every one must be in the built library
#: (checked when it is loaded) and is bound with these types. A new kernel function is one entry here.
SIGNATURES: dict[str, tuple[object, list]] = {
    "sdm_chain": (_I64, [_I64, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _I64, _I64, _PTR, _I64, _I64,
                         _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR]),
    "sdm_paper_flow": (_I64, [_I64, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _I64, _I64,
                              _PTR, _PTR, _PTR, _PTR]),
    "sdm_train": (_I64, [_I64, _I64, _PTR, _PTR, _PTR, _PTR, _I64, _I64, _PTR, _I64, _I64, _I64, _I64,
                         *[_PTR] * 11, _I64, _I64, _I64, _PTR, _PTR, _I64, _PTR, _PTR, _PTR, _PTR]),
    "sdm_noise_fill": (_I64, [_I64, _PTR, _I64, _PTR, _PTR, _I64, _I64, _PTR, _PTR, _I64]),
    # the CMA-ES baseline's count (sdm.experiments.baselines.cmaes_native)
    "sdm_pixel_mismatch": (None, [_I64, _PTR, _I64, _I64, *[_PTR] * 8, _I64, _I64, _PTR, _I64, _I64,
                                  *[_PTR] * 5]),
}


_switched_off = False


def enabled() -> bool:
    """Whether the compiled kernel is in use (built or loaded on first call; ``SDM_NATIVE=0`` turns it off)."""
    return not _switched_off and library() is not None


@contextlib.contextmanager
def disabled():
    """Inside the block every caller runs its torch path (for comparisons and benchmarks; process-wide)."""
    global _switched_off
    before, _switched_off = _switched_off, True
    try:
        yield
    finally:
        _switched_off = before


class _Unavailable(Exception):
    """Why the kernel cannot be used (the warning's text); ``remember``: a build that ran and failed."""

    def __init__(self, message: str, remember: bool = False):
        super().__init__(message)
        self.remember = remember


def cache_files(compiler: str | None = None) -> tuple[Path, Path, Path]:
    """The cache's files for ``compiler`` (default ``$CC`` or ``cc``): ``(library, checksum, failure)``.

    ``sdm_native_<key>.so`` is the library, ``sdm_native_<key>.sha256`` its SHA-256 (``sha256sum``'s
    format, written after a successful build and checked before every load) and ``sdm_native_<key>.failed``
    the error of a build that failed, which stops later processes from running the compiler again;
    ``<key>`` hashes every source and header (:func:`source_digest`), the compiler, the flags and the platform,
    so a changed ``CC`` or kernel file gets files of its own. Deleting any of them is safe: the kernel is built
    again.
    """
    compiler = os.environ.get("CC", "cc") if compiler is None else compiler
    sources = source_digest()  # OSError where an install left a source out
    key = hashlib.sha256(b"\0".join([sources, compiler.encode(), " ".join(FLAGS).encode(),
                                     platform.machine().encode(), sys.platform.encode()])).hexdigest()[:16]
    folder = cache_dir().absolute()  # RuntimeError where no home folder can be found
    # Absolute: ctypes.CDLL would search the library path for a bare file name.
    return tuple(folder / f"sdm_native_{key}{suffix}" for suffix in (".so", ".sha256", ".failed"))


def source_digest() -> bytes:
    """Each kernel file's name and SHA-256, one line per file (:data:`SOURCES`, then :data:`HEADERS`)."""
    return b"".join(f"{path.name} {hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode()
                    for path in (*SOURCES, *HEADERS))


@functools.lru_cache(maxsize=1)
def library():
    """The loaded kernel, every function of :data:`SIGNATURES` typed; ``None`` where it cannot be used (after
    one warning that says why) or ``SDM_NATIVE=0`` turns it off. Built or loaded on the first call."""
    if os.environ.get("SDM_NATIVE", "1").strip().lower() in ("0", "off", "false", "no"):
        return None
    try:
        return _cached_or_built(os.environ.get("CC", "cc"))
    except _Unavailable as why:
        warnings.warn(f"sdm: the compiled CPU kernel is not available: {why} The SDM layer runs its torch path "
                      "(same results, slower); SDM_NATIVE=0 silences this warning.", RuntimeWarning, stacklevel=3)
        return None


def _cached_or_built(compiler: str):
    """The kernel from the cache if its checksum and functions check out, else built (once) and cached."""
    try:
        command = shlex.split(compiler)  # as a shell would: CC="ccache gcc", CC="env gcc"
    except ValueError as error:
        raise _Unavailable(f"CC={compiler!r} cannot be split into words as a shell would ({error}).") from None
    if not command:
        raise _Unavailable("CC is set but empty; set it to a C compiler (e.g. CC=cc), or unset it.")
    try:
        library, checksum, failure = cache_files(compiler)
    except (OSError, RuntimeError) as error:
        raise _Unavailable(f"its source or cache folder cannot be found ({error}); set SDM_CACHE_DIR.") from None
    damage = _damage(library, checksum)
    if damage is None:
        try:
            return _bind(ctypes.CDLL(str(library)), library)
        except (OSError, _Unavailable) as error:  # a foreign library planted with its checksum
            damage = f"not the kernel ({error})"
    if failure.is_file():
        try:
            cause = failure.read_text(encoding="utf-8", errors="replace").strip()
        except OSError as error:
            cause = f"({error})"
        raise _Unavailable(f"an earlier build failed: {cause} That failure is remembered in {failure}: delete "
                           "that file to build again (a different CC or a changed kernel source builds afresh).")
    try:
        return _build(command, library, checksum, failure)
    except _Unavailable as why:
        cause = f"{why}" if not damage else f"the cached kernel {library} is {damage}, and rebuilding it failed: {why}"
        if not why.remember:
            raise _Unavailable(cause) from None
        with contextlib.suppress(OSError):  # a read-only cache: nothing to remember it in
            write_text(failure, cause + "\n")
            cause += (f" This failure is remembered in {failure}: delete that file to build again (a different "
                      "CC or a changed kernel source builds afresh).")
        raise _Unavailable(cause) from None


def _damage(library: Path, checksum: Path) -> str | None:
    """``None`` where ``library`` matches its checksum file, else what is wrong ("" where there is no library).

    Checked on the bytes, never by loading them: a truncated library kills the process with SIGBUS inside
    ``dlopen``, and a foreign or garbage one fails with a misleading error.
    """
    try:
        data = library.read_bytes()
    except FileNotFoundError:
        return ""
    except OSError as error:
        return f"unreadable ({error})"
    try:
        expected = checksum.read_text(encoding="ascii").split()[0]
    except (OSError, UnicodeDecodeError, IndexError):
        return f"without a valid checksum file {checksum.name} (one is written after each successful build)"
    if hashlib.sha256(data).hexdigest() != expected:
        return (f"damaged: its SHA-256 does not match {checksum.name} ({len(data)} bytes; truncated, "
                "overwritten or copied from elsewhere)")
    return None


def _bind(library: ctypes.CDLL, path: Path) -> ctypes.CDLL:
    """``library`` with every function of :data:`SIGNATURES` typed; :class:`_Unavailable` if one is missing."""
    missing = [name for name in SIGNATURES if not hasattr(library, name)]
    if missing:
        raise _Unavailable(f"{path} lacks the function(s) {', '.join(missing)}.", remember=True)
    for name, (restype, argtypes) in SIGNATURES.items():
        function = getattr(library, name)
        function.restype, function.argtypes = restype, argtypes
    return library


def _build(command: list[str], library: Path, checksum: Path, failure: Path) -> ctypes.CDLL:
    """Compile the kernel into ``library``, check and load it, then write its checksum; the loaded library.

    Built beside the target and renamed into place (:func:`sdm.io.write_atomic`): concurrent processes
    (parallel workflow jobs) each build their own file, and no half-written one is ever loaded. The
    build is checked (non-empty, loadable, every function present) and loaded from its temporary
    name before it is renamed: what failed is never cached, and ``dlopen`` never returns a stale
    handle for the final name (it reuses one per path).
    """
    built = {}

    def compile_and_check(partial: Path):
        _compile(command, [*FLAGS, "-o", str(partial), *map(str, SOURCES)])
        data = partial.read_bytes()
        if not data:
            raise _Unavailable(f"CC={shlex.join(command)!r} exited 0 but wrote nothing to its output file.",
                               remember=True)
        try:
            loaded = ctypes.CDLL(str(partial))
        except OSError as error:
            raise _Unavailable(f"what CC={shlex.join(command)!r} built cannot be loaded ({error}).",
                               remember=True) from None
        built["library"] = _bind(loaded, partial)
        built["digest"] = hashlib.sha256(data).hexdigest()

    try:
        write_atomic(library, compile_and_check)
        # After the library: a reader between the two renames sees a mismatch and builds again.
        write_text(checksum, f"{built['digest']}  {library.name}\n")
    except OSError as error:
        raise _Unavailable(f"the cache folder {library.parent} cannot be written ({error}); "
                           "set SDM_CACHE_DIR to a writable folder.") from None
    failure.unlink(missing_ok=True)
    return built["library"]


def _compile(command: list[str], arguments: list[str]) -> None:
    """Run the compiler (``command``: ``$CC``'s words) in a session of its own; on timeout kill its process group.

    Its output goes to a temporary file, not a pipe: a grandchild holding a pipe open would keep
    ``communicate`` waiting after the compiler itself was killed.
    """
    with tempfile.TemporaryFile() as log:
        try:
            process = subprocess.Popen([*command, *arguments], stdin=subprocess.DEVNULL, stdout=log,
                                       stderr=subprocess.STDOUT, start_new_session=True)
        except OSError as error:  # not remembered: finding no compiler is instant, and one may be installed
            raise _Unavailable(f"the C compiler {command[0]!r} cannot be run ({error.strerror or error}); "
                               "set CC to a C compiler.") from None
        try:
            status = process.wait(timeout=BUILD_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise _Unavailable(f"CC={shlex.join(command)!r} did not finish within {BUILD_TIMEOUT_S:g} s; it and "
                               "its process group were killed.", remember=True) from None
        finally:
            if process.returncode is None:  # timed out or interrupted: the group id is still ours
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)
                process.wait()
        if status != 0:
            log.seek(0)
            output = log.read().decode(errors="replace").strip()
            raise _Unavailable(f"CC={shlex.join(command)!r} failed (exit status {status})"
                               + (f"; it printed {output[-300:]!r}." if output else "."), remember=True)


def eager_under_compile(function):
    """``function``, run eagerly by Dynamo when a graph is being traced (a ``ctypes`` call cannot be traced).

    The same as decorating it with ``torch.compiler.disable`` (one graph break per call, the kernel runs
    inside the compiled program), but applied only while tracing: the decorator imports Dynamo, about
    1.2 s, and ``sdm`` is imported by every workflow job and test process, few of which compile.
    """

    @functools.wraps(function)
    def call(*args, **kwargs):
        if torch.compiler.is_compiling():
            return torch.compiler.disable(function)(*args, **kwargs)
        return function(*args, **kwargs)

    return call


@eager_under_compile
def serves(*tensors: torch.Tensor) -> bool:
    """Whether the kernel can take these tensors: all on the CPU, and the kernel available."""
    return all(t.device.type == "cpu" for t in tensors) and enabled()


def check_arrays(function: str, **arrays: tuple[torch.Tensor, torch.dtype, tuple | None]) -> dict[str, int]:
    """Check a binding's arrays before its ctypes call: :class:`SDMInputError` naming the first wrong argument.

    Each keyword is ``name=(tensor, dtype, shape)``: the tensor must be a :class:`torch.Tensor` of ``dtype``, on the
    CPU, C-contiguous, and of ``shape`` (``None``: any). A shape's entries are whole numbers, or sizes by name:
    ``"G"`` (or ``"G+1"``) binds size ``G`` where it is first met (in the order of the keywords) and must match
    wherever it is met again; ``"L*G"`` and the like are sums and products of bound sizes and whole numbers.

    Returns:
        The bound sizes by name.

    >>> import torch
    >>> check_arrays("demo", gain=(torch.zeros(3, 2, dtype=torch.float64), torch.float64, ("G", 2)),
    ...              start=(torch.zeros(4, dtype=torch.int64), torch.int64, ("G+1",)))
    {'G': 3}
    >>> check_arrays("demo", gain=(torch.zeros(3, 2, dtype=torch.float64), torch.float64, ("G", 2)),
    ...              start=(torch.zeros(3, dtype=torch.int64), torch.int64, ("G+1",)))
    Traceback (most recent call last):
    ...
    sdm.errors.SDMInputError: demo: start must have shape (4,), got (3,)
    """
    sizes: dict[str, int] = {}
    for name, (tensor, dtype, shape) in arrays.items():
        if not isinstance(tensor, torch.Tensor):
            raise SDMInputError(f"{function}: {name} must be a torch.Tensor, got {type(tensor).__name__}")
        if tensor.dtype != dtype:
            raise SDMInputError(f"{function}: {name} must be {dtype}, got {tensor.dtype}")
        if tensor.device.type != "cpu":
            raise SDMInputError(f"{function}: {name} must be on the CPU (the compiled kernel's), got {tensor.device}")
        if not tensor.is_contiguous():
            raise SDMInputError(f"{function}: {name} must be C-contiguous (call .contiguous())")
        if shape is None:
            continue
        if tensor.dim() == len(shape):
            for size, wanted in zip(tensor.shape, shape):
                dim, _, extra = wanted.partition("+") if isinstance(wanted, str) else ("", "", "")
                if dim.isidentifier() and dim not in sizes and (extra == "" or extra.isdigit()):
                    sizes[dim] = size - int(extra or 0)  # "G" or "G+1" met first: binds G
        expected = tuple(_size(wanted, sizes) for wanted in shape)
        if tuple(tensor.shape) != expected:
            shown = "(" + ", ".join(map(str, expected)) + ("," if len(expected) == 1 else "") + ")"
            raise SDMInputError(f"{function}: {name} must have shape {shown}, got {tuple(tensor.shape)}")
    return sizes


def _size(wanted: int | str, sizes: dict[str, int]) -> int | str:
    """A shape entry of :func:`check_arrays`: a whole number, or a sum of products of bound sizes and numbers
    (the entry itself, for the message, where a size is not bound: the array's rank was wrong)."""
    if isinstance(wanted, int):
        return wanted
    total = 0
    for term in wanted.split("+"):
        product = 1
        for factor in term.split("*"):
            factor = factor.strip()
            if not factor.isdigit() and factor not in sizes:
                return wanted
            product *= int(factor) if factor.isdigit() else sizes[factor]
        total += product
    return total
