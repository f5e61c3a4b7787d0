"""The one atomic file writer of :mod:`sdm` and the workflow: a file appears under its name only once complete.

Every file the library and the workflow write (the Sky file, tables, figures,
JSON, CSV, the rendered notebooks) goes through :func:`write_atomic`:

1. a temporary file is created in the destination's folder (so the final rename
   is atomic: same file system), named ``.<stem>.<random>.tmp<suffix>`` -- hidden,
   and keeping the suffix so writers that infer the format from it still work;
2. it is created with ``os.open(..., 0o666)``, exactly like a plain ``open(path,
   "w")``, so the kernel applies the user's umask (and any default ACL): with
   umask 022 the final file is ``0644`` (readable by group and others), with
   umask 077 it is ``0600``. (``tempfile.mkstemp`` would give ``0600`` whatever
   the umask, which made every output private to its owner.);
3. the content is written, flushed to disk (``fsync``) and renamed over the
   destination with ``os.replace``;
4. if anything fails on the way (including ``KeyboardInterrupt``), the
   temporary file is removed and the destination is left as it was.

A CSV (:func:`write_csv`) gets a checksum file beside it, ``name.csv.sha256``: the SHA-256 of its bytes and its row
count, which its reader checks (:func:`csv_damage`; :func:`sdm.experiments.report.io.read_csv`), so a result cut or changed
after it was written is named, not read.

It also says where :mod:`sdm` keeps what it can rebuild (:func:`cache_dir`: the
compiled kernel, the workflow's parsed code).

This module uses only the standard library and imports nothing from
:mod:`sdm`, so ``workflow/scripts/run_notebook.py`` and
``workflow/scripts/code_deps.py`` can load it by path without importing torch.
"""
from __future__ import annotations

import hashlib
import json
import os
import secrets
from pathlib import Path
from typing import Any, Callable

#: Mode requested for new files; the process umask is subtracted by the kernel, as for ``open()``.
NEW_FILE_MODE = 0o666


def cache_dir() -> Path:
    """Where :mod:`sdm` keeps what it can rebuild: ``$SDM_CACHE_DIR``, else ``$XDG_CACHE_HOME/sdm``, else
    ``~/.cache/sdm`` (``RuntimeError`` where no home folder can be found). Deleting it is always safe."""
    if os.environ.get("SDM_CACHE_DIR"):
        return Path(os.environ["SDM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "sdm"


def current_umask() -> int:
    """The process umask (e.g. ``0o022``), for modes set by ``chmod`` (a folder made by ``mkdtemp``).

    Read from ``/proc/self/status`` where Linux offers it, so that no other thread
    ever sees a changed umask; elsewhere set and restored with ``os.umask``.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _create_temporary(path: Path) -> Path:
    """Create (exclusively) an empty hidden temporary file beside ``path``, mode ``0o666 & ~umask``."""
    for _ in range(100):
        temporary = path.with_name(f".{path.stem}.{secrets.token_hex(6)}.tmp{path.suffix}")
        try:
            handle = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, NEW_FILE_MODE)
        except FileExistsError:
            continue
        os.close(handle)
        return temporary
    raise FileExistsError(f"{path.parent}: could not create a temporary file for {path.name}")


def write_atomic(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(temporary path)`` then rename the temporary file to ``path``.

    Args:
        path: the destination; its folder is created if missing.
        write: writes the whole content to the path it is given (it may open it
            in any mode; the file already exists, empty, with the final mode).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = _create_temporary(path)
    try:
        write(temporary)
        handle = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(handle)
        finally:
            os.close(handle)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` atomically."""
    return write_atomic(path, lambda temporary: temporary.write_bytes(data))


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) atomically."""
    return write_atomic(path, lambda temporary: temporary.write_text(text, encoding="utf-8"))


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON atomically."""
    return write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def read_json(path: str | Path) -> Any:
    """Read a JSON file (UTF-8)."""
    return json.loads(Path(path).read_text(encoding="utf-8"))


#: The suffix of a CSV's checksum file: ``name.csv.sha256`` beside ``name.csv``.
CHECKSUM_SUFFIX = ".sha256"


def checksum_path(path: str | Path) -> Path:
    """The checksum file of the CSV at ``path`` (:data:`CHECKSUM_SUFFIX`)."""
    path = Path(path)
    return path.with_name(path.name + CHECKSUM_SUFFIX)


def write_csv(path: str | Path, frame) -> Path:
    """Write a pandas DataFrame as CSV (no index) atomically, then its checksum file (:func:`checksum_path`): one
    line ``<sha256>  <rows> rows  <name>``. The old checksum file goes first, so a write stopped midway never
    leaves a checksum of other bytes beside the CSV."""
    path = Path(path)
    checksum = checksum_path(path)
    checksum.unlink(missing_ok=True)
    data = frame.to_csv(index=False).encode("utf-8")
    write_bytes(path, data)
    write_text(checksum, f"{hashlib.sha256(data).hexdigest()}  {len(frame)} rows  {path.name}\n")
    return path


def csv_damage(path: str | Path, data: bytes | None = None) -> str | None:
    """What is wrong with the CSV at ``path`` (its bytes ``data``, read if ``None``) against its checksum file:
    ``None`` where they match or there is no checksum file (a CSV not written by :func:`write_csv`)."""
    path = Path(path)
    checksum = checksum_path(path)
    if not checksum.is_file():
        return None
    data = path.read_bytes() if data is None else data
    try:
        digest, rows = checksum.read_text(encoding="ascii").split()[:2]
        rows = int(rows)
    except (ValueError, UnicodeDecodeError):
        return f"its checksum file {checksum.name} is unreadable"
    if hashlib.sha256(data).hexdigest() != digest:
        lines = data.count(b"\n")
        return (f"its bytes do not match {checksum.name} (written with {rows} rows; it now holds {max(lines - 1, 0)} "
                f"full rows in {len(data)} bytes: cut or changed after it was written)")
    return None
