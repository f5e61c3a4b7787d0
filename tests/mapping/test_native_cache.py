"""The compiled kernel's cache (sdm.mapping.build): a damaged cache or a bad compiler is never fatal, never silent.

Each test points ``SDM_CACHE_DIR`` at a folder of its own and clears ``build.library``'s cache before and
after, so every ``load()`` behaves as a fresh process would; the truncated library runs in a real
subprocess, because loading it (as the code before these checks did) kills the process with SIGBUS.
Damaged files are planted by atomic replacement, never rewritten in place: this process may have the
library they replace mapped, and truncating a mapped file would crash it.
"""
from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import stat
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import pytest
import torch

from sdm.camera import APOLLO_CAMERA_5 as CAM
from sdm.io import write_bytes, write_text
from sdm.mapping import build
from sdm.mapping.fast import fast_mapping
from sdm.sky import shift_vector

from scenes import configuration_set

COMPILER = os.environ.get("CC", "cc")
#: Each test builds the kernel in a fresh cache folder (seconds): out of `make test-fast`.
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which((shlex.split(COMPILER) or [""])[0]) is None,
                                 reason=f"no C compiler ({COMPILER!r}): these tests build the kernel")]
FIELDS = ("out_pixels", "flow", "loss", "entered", "matched", "landed")


@pytest.fixture
def load(monkeypatch, tmp_path):
    """``load(CC=...)``: ``(library or None, [warning messages])`` as a fresh process would get them."""
    monkeypatch.setenv("SDM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", COMPILER)
    monkeypatch.delenv("SDM_NATIVE", raising=False)

    def load(**env):
        for name, value in env.items():
            monkeypatch.setenv(name, value)
        build.library.cache_clear()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            library = build.library()
        return library, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]

    build.library.cache_clear()
    yield load
    build.library.cache_clear()  # later tests get the usual cache again


def layer_call():
    """One layer call on 4 configurations: ``(result, torch path's result)``."""
    data = configuration_set(4, seed=9)
    batch = data.batch(torch.arange(4))
    points = batch.points + shift_vector(torch.tensor([0.3, 0.2], dtype=torch.float64), batch.points)
    args = (points, batch.pixels, batch.config, batch.rank, data.targets, 4, 0, CAM)
    return fast_mapping(*args), fast_mapping(*args, native=False)


def assert_same(mine, theirs):
    for field in FIELDS:
        assert torch.equal(getattr(mine, field), getattr(theirs, field)), f"{field} differs"


def cached(tmp_path: Path, suffix: str) -> list[Path]:
    """The cache's files ending in ``suffix`` (found by name, as a user would: ``sdm_native_<key><suffix>``)."""
    return sorted((tmp_path / "cache").glob(f"sdm_native_*{suffix}"))


def good_build(load, tmp_path: Path, monkeypatch) -> tuple[str, bytes]:
    """The kernel's cache file name and bytes, built in a folder of its own.

    Of its own because ``dlopen`` hands back the library already loaded under the same path without
    reading the file again: a file planted where this process once loaded one would not be looked at.
    """
    assert load(SDM_CACHE_DIR=str(tmp_path / "elsewhere"))[0] is not None
    [built] = (tmp_path / "elsewhere").glob("sdm_native_*.so")
    monkeypatch.setenv("SDM_CACHE_DIR", str(tmp_path / "cache"))  # back to the test's cache
    return built.name, built.read_bytes()


def assert_cached_and_checked(library: Path):
    checksum = library.with_suffix(".sha256")
    assert checksum.read_text().split()[0] == hashlib.sha256(library.read_bytes()).hexdigest()


def script(path: Path, body: str) -> str:
    """An executable shell script at ``path`` (a stand-in compiler); its path."""
    path.write_text("#!/bin/sh\n" + textwrap.dedent(body))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


def test_a_truncated_cached_kernel_is_rebuilt_not_loaded(load, tmp_path):
    library, messages = load()
    assert library is not None and not messages
    [target] = cached(tmp_path, ".so")
    good = target.read_bytes()
    write_bytes(target, good[:7000])  # what `head -c 7000 good.so > target` leaves
    code = textwrap.dedent(
        """
        import warnings
        warnings.simplefilter("error")  # any warning fails the run
        from sdm.mapping import build
        import test_native_cache as t
        assert build.enabled()
        t.assert_same(*t.layer_call())
        print("ok")
        """
    )
    tests = Path(__file__).parents[1]
    env = os.environ | {"SDM_CACHE_DIR": str(target.parent), "CC": COMPILER,
                        "PYTHONPATH": os.pathsep.join([str(tests), str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"exit status {done.returncode}: {done.stderr[-2000:]}"
    assert done.stdout.strip() == "ok"
    assert target.read_bytes() == good  # rebuilt (the compiler is deterministic), with its checksum
    assert_cached_and_checked(target)


@pytest.mark.parametrize("planted", [b"not a shared library\n" * 50, b""], ids=["garbage", "empty"])
def test_a_garbage_or_empty_cached_kernel_is_rebuilt_without_a_warning(load, tmp_path, monkeypatch, planted):
    name, _ = good_build(load, tmp_path, monkeypatch)
    target = write_bytes(tmp_path / "cache" / name, planted)
    library, messages = load()
    assert library is not None and messages == []
    assert_cached_and_checked(target)
    assert_same(*layer_call())


def test_a_failed_rebuild_of_a_damaged_cache_names_the_file_and_the_cause(load, tmp_path, monkeypatch):
    broken = tmp_path / "broken"
    compiler = script(tmp_path / "flaky-cc", f"""\
        [ -e {shlex.quote(str(broken))} ] && {{ echo "cc1: out of memory" >&2; exit 1; }}
        exec {COMPILER} "$@"
        """)
    monkeypatch.setenv("CC", compiler)
    name, good = good_build(load, tmp_path, monkeypatch)
    target = write_bytes(tmp_path / "cache" / name, b"garbage")
    write_text(target.with_suffix(".sha256"), f"{hashlib.sha256(good).hexdigest()}  {name}\n")
    broken.touch()
    library, messages = load()
    assert library is None and len(messages) == 1
    assert f"the cached kernel {target} is damaged" in messages[0] and "cc1: out of memory" in messages[0], messages
    assert "cc1: out of memory" in cached(tmp_path, ".failed")[0].read_text()


def test_a_foreign_library_with_a_valid_checksum_is_replaced(load, tmp_path, monkeypatch):
    empty = tmp_path / "empty.c"
    empty.write_text("int sdm_unrelated(void) { return 0; }\n")
    foreign = tmp_path / "foreign.so"
    subprocess.run([*shlex.split(COMPILER), "-shared", "-fPIC", "-o", str(foreign), str(empty)], check=True)
    name, _ = good_build(load, tmp_path, monkeypatch)
    target = write_bytes(tmp_path / "cache" / name, foreign.read_bytes())
    checksum = target.with_suffix(".sha256")
    write_text(checksum, f"{hashlib.sha256(foreign.read_bytes()).hexdigest()}  {target.name}\n")
    library, messages = load()
    assert library is not None and messages == []
    assert target.read_bytes() != foreign.read_bytes()
    assert_cached_and_checked(target)
    assert_same(*layer_call())


def test_a_compiler_writing_nothing_is_reported_and_remembered(load, tmp_path):
    log = tmp_path / "calls.log"
    compiler = script(tmp_path / "quiet-cc", f'echo "$@" >> {shlex.quote(str(log))}\nexit 0\n')
    library, messages = load(CC=compiler)
    assert library is None and len(messages) == 1
    assert cached(tmp_path, ".so") == [] and cached(tmp_path, ".sha256") == []  # nothing cached as good
    [failure] = cached(tmp_path, ".failed")
    assert "wrote nothing" in messages[0] and str(failure) in messages[0], messages
    assert "wrote nothing" in failure.read_text()
    # A second process reads the failure instead of running the compiler again, and says how to retry.
    library, messages = load()
    assert library is None and len(messages) == 1
    assert "earlier build failed" in messages[0] and "wrote nothing" in messages[0], messages
    assert f"{failure}: delete that file" in messages[0]
    assert len(log.read_text().splitlines()) == 1
    failure.unlink()  # the documented way to retry
    load()
    assert len(log.read_text().splitlines()) == 2


def test_a_library_without_the_kernels_functions_is_reported_not_raised(load, tmp_path):
    empty = tmp_path / "empty.c"
    empty.write_text("int sdm_unrelated(void) { return 0; }\n")
    # A "compiler" that builds a valid shared library from the wrong source.
    compiler = script(tmp_path / "wrong-cc", f"""\
        while [ $# -gt 0 ]; do [ "$1" = -o ] && out=$2; shift; done
        exec {COMPILER} -shared -fPIC -o "$out" {shlex.quote(str(empty))}
        """)
    library, messages = load(CC=compiler)
    assert library is None and len(messages) == 1
    assert "lacks the function(s) sdm_chain, sdm_paper_flow" in messages[0], messages
    assert cached(tmp_path, ".so") == [] and cached(tmp_path, ".sha256") == []
    assert len(cached(tmp_path, ".failed")) == 1
    assert not build.enabled()  # and the layer runs its torch path
    kernel, reference = layer_call()
    assert_same(kernel, reference)


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] == "Z"  # killed, not yet reaped
    except FileNotFoundError:
        return True


def test_a_hanging_compiler_is_killed_with_its_children(load, tmp_path, monkeypatch):
    monkeypatch.setattr(build, "BUILD_TIMEOUT_S", 2.0)
    pid_file = tmp_path / "child.pid"
    compiler = script(tmp_path / "hanging-cc", f"sleep 900 &\necho $! > {shlex.quote(str(pid_file))}\nsleep 300\n")
    try:
        library, messages = load(CC=compiler)
        child = int(pid_file.read_text())
        deadline = time.monotonic() + 10.0
        while not _gone(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _gone(child), "the compiler's child outlived the timeout"
        assert library is None and len(messages) == 1
        assert "did not finish within 2 s" in messages[0] and "killed" in messages[0], messages
        [failure] = cached(tmp_path, ".failed")
        assert cached(tmp_path, ".so") == [] and "did not finish" in failure.read_text()
    finally:  # never leave the stand-in compiler's child behind, even when the code under test did
        if pid_file.is_file() and not _gone(int(pid_file.read_text())):
            os.kill(int(pid_file.read_text()), 9)


@pytest.mark.parametrize("wrapper", ["env", "ccache"])
def test_cc_is_split_into_words_as_a_shell_would(load, tmp_path, wrapper):
    if shutil.which(wrapper) is None:
        pytest.skip(f"{wrapper} not installed")
    library, messages = load(CC=f"{wrapper} {COMPILER}")
    assert library is not None and messages == []
    [target] = cached(tmp_path, ".so")
    assert_cached_and_checked(target)


def test_an_empty_cc_is_reported(load):
    library, messages = load(CC="  ")
    assert library is None and len(messages) == 1 and "CC is set but empty" in messages[0], messages


def test_the_key_covers_every_kernel_file(tmp_path, monkeypatch):
    """Every file of the kernel's folder is a source (compiled into the library) or a header, and an edit of any
    one of them gives the cache another key: a cached library is never one built from other bytes."""
    assert sorted(build.KERNEL.iterdir()) == sorted((*build.SOURCES, *build.HEADERS))
    assert {path.suffix for path in build.SOURCES} == {".c"} and {path.suffix for path in build.HEADERS} == {".h"}
    copy = tmp_path / "kernel"
    shutil.copytree(build.KERNEL, copy)
    monkeypatch.setenv("SDM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(build, "SOURCES", tuple(copy / path.name for path in build.SOURCES))
    monkeypatch.setattr(build, "HEADERS", tuple(copy / path.name for path in build.HEADERS))
    keys = [build.cache_files("cc")[0].name]
    for path in (*build.SOURCES, *build.HEADERS):
        path.write_bytes(path.read_bytes() + b"\n")
        keys.append(build.cache_files("cc")[0].name)
    assert len(set(keys)) == len(keys) == 1 + len(build.SOURCES) + len(build.HEADERS)


def test_without_a_compiler_the_layer_gives_the_kernels_numbers(load, tmp_path, monkeypatch):
    kernel, _ = layer_call()
    assert build.enabled()
    path = os.environ["PATH"]
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))
    monkeypatch.delenv("CC")
    library, messages = load(SDM_CACHE_DIR=str(tmp_path / "machine-without-cc"))
    assert library is None and len(messages) == 1
    assert "the C compiler 'cc' cannot be run" in messages[0], messages
    fallback, _ = layer_call()
    assert_same(fallback, kernel)
    # Not remembered (finding no compiler costs nothing): one installed later is used at once.
    assert not any((tmp_path / "machine-without-cc").glob("*"))
    assert load(PATH=path, CC=COMPILER)[0] is not None
