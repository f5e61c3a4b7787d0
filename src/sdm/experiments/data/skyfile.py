"""The Sky dataset file: all configurations in one versioned, sparse, lazily readable file.

Layout (format version 3; all integers little-endian; ``docs/data.md`` has the
full description)::

    offset  size  field
    0       8     magic b"\\x89SDMSKY\\n"
    8       4     uint32 format version (3)
    12      4     uint32 header length L in bytes
    16      8     uint64 data offset D (multiple of 64)
    24      8     uint64 total file size in bytes
    32      L     header: UTF-8 JSON object (keys sorted), padded with spaces to D
    D       ...   arrays, each starting at D + its "offset" (multiples of 64),
                  raw little-endian C order, zero padding in between

The header holds ``format`` ("sdm-sky"), ``version``, ``n_configurations``,
``image_ids``, ``shift`` ``[a, b]`` (m), ``camera`` (intrinsics and screen),
``metadata`` (free JSON object) and ``arrays``: for each array its ``dtype``
(numpy string), ``shape``, ``offset`` (bytes from D), ``nbytes`` and
``crc32``; and ``header_crc32``, the CRC-32 of the header itself without that key (as written: compact
JSON, keys sorted), so that no byte of the header (a camera field, the shift) changes unnoticed. The arrays (``N`` configurations; ``P``, ``T``, ``C`` pooled counts)::

    point_offsets   int64 (N+1,)   configuration i's points are rows
                                   point_offsets[i]:point_offsets[i+1]
    point_pixels    int16 (P, 2)   active pixels (row, col) of E', row-major per configuration
    point_depth     float64 (P,)   their depth (the value of E'), metres
    point_car       int16 (P,)     the car each point belongs to: its index among the
                                   configuration's centre_pixels (the car whose circle
                                   gave the point its depth)
    target_offsets  int64 (N+1,)
    target_pixels   int16 (T, 2)   active pixels (row, col) of the target L, row-major
    centre_offsets  int64 (N+1,)
    centre_pixels   int16 (C, 2)   active pixels of E (car centres on screen), row-major
    centre_depth    float64 (C,)   their depth (the value of E), metres

Opening a file reads the fixed prefix, the header (checking its CRC-32) and the three offset arrays
(checking theirs); configurations are decoded one at a time from a
read-only memory map, and the first read of each array checks its CRC-32, so a
damaged file is refused before any of its configurations is used.
A file of another format version (version 1 had no ``point_car``) is refused,
naming the file, its version and how to rebuild it.
Writing is deterministic (no timestamp; the same inputs give the same bytes)
and atomic (temporary file + ``os.replace``).
"""
from __future__ import annotations

import dataclasses
import json
import struct
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import torch

from ...camera import Camera
from ...errors import SDMInputError
from ...io import write_bytes
from ...sky import SkyConfiguration, check_shift

#: First 8 bytes of every Sky file.
MAGIC = b"\x89SDMSKY\n"
#: The format version this module writes and reads (2: ``point_car`` added; 3: the header under its own CRC-32).
FORMAT_VERSION = 3
#: Value of the header's ``format`` key.
FORMAT_NAME = "sdm-sky"
#: Alignment of the data section and of each array, bytes.
ALIGN = 64

_PREFIX = struct.Struct("<8sIIQQ")
_ARRAYS = {
    "point_offsets": ("<i8", 1),
    "point_pixels": ("<i2", 2),
    "point_depth": ("<f8", 1),
    "point_car": ("<i2", 1),
    "target_offsets": ("<i8", 1),
    "target_pixels": ("<i2", 2),
    "centre_offsets": ("<i8", 1),
    "centre_pixels": ("<i2", 2),
    "centre_depth": ("<f8", 1),
}
_CAMERA_FIELDS = [f.name for f in dataclasses.fields(Camera)]
#: What a refused older version lacked, said after "this sdm reads version N".
_VERSION_NOTES = {1: "; version 1 does not record the car of each point",
                  2: "; version 2 keeps its header outside every checksum"}
#: What to do about a damaged Sky file; ends every "damaged" message.
REBUILD_HINT = (
    "delete it and run snakemake again to rebuild it (the 'sky' stage), "
    "or rebuild it in place with `snakemake --forcerun sky`"
)


def _damaged(path: Path, what: str) -> SDMInputError:
    """The error for a damaged Sky file: names the file, says what is wrong and how to rebuild it."""
    return SDMInputError(f"{path}: {what}; the Sky file is damaged: {REBUILD_HINT}")


def _header_json(header: dict) -> bytes:
    """The header as the file holds it: compact UTF-8 JSON, keys sorted (what ``header_crc32`` is taken of, without
    that key)."""
    return json.dumps(header, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _align(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


# -- writing -----------------------------------------------------------------------------


def write_sky_file(
    path: str | Path,
    configurations: Sequence[SkyConfiguration],
    shift: tuple[float, float],
    camera: Camera,
    metadata: dict | None = None,
) -> None:
    """Write configurations to a Sky file (format version :data:`FORMAT_VERSION`).

    Args:
        path: destination; written atomically by :func:`sdm.io.write_atomic`
            (a temporary file in the same folder, then ``os.replace``; mode
            ``0o666 & ~umask`` like any plain write).
        configurations: the configurations, stored in this order.
        shift: the true shift ``(a, b)`` (metres) they were built with.
        camera: the camera and screen they were built with.
        metadata: optional JSON-serialisable dict stored verbatim (keys
            sorted), e.g. provenance (source, seed); no timestamp is added.

    Raises:
        SDMInputError: a configuration with wrong shapes/dtypes, off-screen
            pixels, non-finite or non-positive depths, a target of the wrong
            size, no car index (``cars``) for its points or one that disagrees
            with the depths; a bad shift; metadata that is not a JSON object.
    """
    path = Path(path)
    if not isinstance(camera, Camera):
        raise SDMInputError(f"camera must be a Camera, got {type(camera).__name__}")
    a, b = check_shift(shift)
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, dict):
        raise SDMInputError(f"metadata must be a dict, got {type(metadata).__name__}")
    height, width = camera.screen_shape
    if max(height, width) > np.iinfo(np.int16).max:
        raise SDMInputError(f"screen {height}x{width} too large for int16 pixel storage")

    parts: dict[str, list[np.ndarray]] = {"point": [], "depth": [], "car": [], "target": [], "centre": [], "cdepth": []}
    ids = []
    for index, cfg in enumerate(configurations):
        pixels, depth, cars, target, centres, centre_depth = _check_configuration(cfg, index, camera)
        parts["point"].append(pixels)
        parts["depth"].append(depth)
        parts["car"].append(cars)
        parts["target"].append(target)
        parts["centre"].append(centres)
        parts["cdepth"].append(centre_depth)
        ids.append(cfg.image_id)

    def offsets(chunks: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([len(c) for c in chunks], dtype=np.int64)]).astype(np.int64)

    def stack(chunks: list[np.ndarray], shape: tuple[int, ...], dtype: str) -> np.ndarray:
        return np.concatenate(chunks).astype(dtype) if chunks else np.zeros(shape, dtype=dtype)

    arrays = {
        "point_offsets": offsets(parts["point"]),
        "point_pixels": stack(parts["point"], (0, 2), "<i2"),
        "point_depth": stack(parts["depth"], (0,), "<f8"),
        "point_car": stack(parts["car"], (0,), "<i2"),
        "target_offsets": offsets(parts["target"]),
        "target_pixels": stack(parts["target"], (0, 2), "<i2"),
        "centre_offsets": offsets(parts["centre"]),
        "centre_pixels": stack(parts["centre"], (0, 2), "<i2"),
        "centre_depth": stack(parts["cdepth"], (0,), "<f8"),
    }
    table = {}
    blobs = []
    position = 0
    for name, (dtype, _) in _ARRAYS.items():
        data = np.ascontiguousarray(arrays[name].astype(dtype)).tobytes()
        table[name] = {
            "dtype": dtype,
            "shape": list(arrays[name].shape),
            "offset": position,
            "nbytes": len(data),
            "crc32": zlib.crc32(data),
        }
        blobs.append((position, data))
        position = _align(position + len(data))
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "n_configurations": len(ids),
        "image_ids": ids,
        "shift": [a, b],
        "camera": {name: getattr(camera, name) for name in _CAMERA_FIELDS},
        "metadata": metadata,
        "arrays": table,
    }
    try:
        header["header_crc32"] = zlib.crc32(_header_json(header))
        header_bytes = _header_json(header)
    except (TypeError, ValueError) as exc:
        raise SDMInputError(f"{path}: metadata is not JSON-serialisable ({exc})") from None
    data_offset = _align(_PREFIX.size + len(header_bytes))
    total = data_offset + (blobs[-1][0] + len(blobs[-1][1]) if blobs else 0)
    out = bytearray(total)
    out[: _PREFIX.size] = _PREFIX.pack(MAGIC, FORMAT_VERSION, len(header_bytes), data_offset, total)
    out[_PREFIX.size : _PREFIX.size + len(header_bytes)] = header_bytes
    out[_PREFIX.size + len(header_bytes) : data_offset] = b" " * (data_offset - _PREFIX.size - len(header_bytes))
    for position, data in blobs:
        out[data_offset + position : data_offset + position + len(data)] = data
    write_bytes(path, bytes(out))


def _check_configuration(cfg, index: int, camera: Camera):
    """Validate one configuration; return numpy arrays (pixels, depth, cars, target pixels, centres, centre depth)."""
    if not isinstance(cfg, SkyConfiguration):
        raise SDMInputError(f"configurations[{index}] must be a SkyConfiguration, got {type(cfg).__name__}")
    where = f"configurations[{index}] (image {cfg.image_id!r})"
    if not isinstance(cfg.image_id, str):
        raise SDMInputError(f"{where}: image_id must be a string, got {type(cfg.image_id).__name__}")
    height, width = camera.screen_shape

    def pixel_array(tensor, name):
        if not isinstance(tensor, torch.Tensor) or tensor.ndim != 2 or tensor.shape[1] != 2:
            raise SDMInputError(f"{where}: {name} must be a (K, 2) tensor")
        if tensor.is_floating_point() or tensor.is_complex() or tensor.dtype == torch.bool:
            raise SDMInputError(f"{where}: {name} must be an integer tensor, got {tensor.dtype}")
        array = tensor.detach().cpu().numpy().astype(np.int64)
        if array.size and (array[:, 0].min() < 0 or array[:, 0].max() >= height or array[:, 1].min() < 0 or array[:, 1].max() >= width):
            raise SDMInputError(f"{where}: {name} has pixels off the {height}x{width} screen")
        return array

    def depth_array(tensor, name, n):
        if not isinstance(tensor, torch.Tensor) or tensor.shape != (n,) or not tensor.is_floating_point():
            raise SDMInputError(f"{where}: {name} must be a floating ({n},) tensor")
        array = tensor.detach().cpu().numpy().astype(np.float64)
        if array.size and not (np.isfinite(array).all() and (array > 0).all()):
            raise SDMInputError(f"{where}: {name} must be finite and positive (metres)")
        return array

    pixels = pixel_array(cfg.pixels, "pixels")
    depth = depth_array(cfg.depth, "depth", pixels.shape[0])
    centres = pixel_array(cfg.centres, "centres")
    centre_depth = depth_array(cfg.centre_depth, "centre_depth", centres.shape[0])
    target = cfg.target
    if not isinstance(target, torch.Tensor) or tuple(target.shape) != (height, width) or target.dtype != torch.bool:
        raise SDMInputError(f"{where}: target must be a ({height}, {width}) bool tensor")
    target_pixels = target.detach().cpu().nonzero().numpy().astype(np.int64).reshape(-1, 2)
    cars = _check_cars(cfg.cars, where, depth, centre_depth)
    return pixels, depth, cars, target_pixels, centres, centre_depth


def _check_cars(cars, where: str, depth: np.ndarray, centre_depth: np.ndarray) -> np.ndarray:
    """The car of each point as int64 numpy, checked: an index into the centres whose depth is the point's.

    Every point of ``E'`` carries the depth of the car that painted it, so a car index that
    disagrees with the depths is a wrong one, refused rather than stored.
    """
    n_points = depth.shape[0]
    if cars is None:
        if n_points == 0:
            return np.zeros(0, dtype=np.int64)
        raise SDMInputError(f"{where}: cars (the car of each point) is missing; build the configuration with "
                            f"sdm.sky.build_configuration, which records it")
    if not isinstance(cars, torch.Tensor) or tuple(cars.shape) != (n_points,):
        raise SDMInputError(f"{where}: cars must be a ({n_points},) tensor (the car of each point)")
    if cars.is_floating_point() or cars.is_complex() or cars.dtype == torch.bool:
        raise SDMInputError(f"{where}: cars must be an integer tensor, got {cars.dtype}")
    array = cars.detach().cpu().numpy().astype(np.int64)
    if array.size and (array.min() < 0 or array.max() >= centre_depth.shape[0]):
        raise SDMInputError(f"{where}: cars must index the {centre_depth.shape[0]} centres, "
                            f"got {array.min()}..{array.max()}")
    if array.size and array.max() > np.iinfo(np.int16).max:
        raise SDMInputError(f"{where}: {array.max() + 1} cars are too many for int16 storage")
    if not np.array_equal(depth, centre_depth[array]):
        raise SDMInputError(f"{where}: cars disagree with the depths (a point's depth must be its car's, "
                            f"centre_depth[cars])")
    return array


# -- reading -----------------------------------------------------------------------------


class SkyFile:
    """A Sky file opened for lazy, random access.

    ``len(sky)``, ``sky[i]`` (a :class:`~sdm.sky.SkyConfiguration`; negative
    indices allowed), iteration, ``sky.image_ids`` (list of str), ``sky.shift``
    (``(a, b)`` metres), ``sky.camera`` (:class:`~sdm.camera.Camera`),
    ``sky.version`` (int), ``sky.metadata`` (dict), ``sky.load_all()``.

    Opening validates the prefix, the header and the offset arrays (and that
    the file is not truncated); it does not decode configurations. Reads are
    verified: the first time a configuration is decoded, each array it reads
    is checked against the CRC-32 stored in the header (once per array and
    opened file: about 10 ms for the default 42.3 MB file). :meth:`verify` checks every
    array at once.

    Args:
        path: the file.
        checksums: verify the arrays' CRC-32 on read (the default). ``False``
            skips it (for measuring its cost; never in the workflow).

    Raises:
        SDMInputError: naming the file, if it is missing, not a Sky file,
            of another format version, truncated, inconsistent, or an array
            read fails its CRC-32 (damaged); the message says how to rebuild it.
    """

    def __init__(self, path: str | Path, checksums: bool = True):
        self.path = Path(path)
        self.checksums = bool(checksums)
        self._verified: set[str] = set()
        if not self.path.is_file():
            raise SDMInputError(f"{self.path}: Sky file not found")
        size = self.path.stat().st_size
        with self.path.open("rb") as stream:
            prefix = stream.read(_PREFIX.size)
            if len(prefix) < _PREFIX.size:
                raise _damaged(self.path, f"not a Sky file (only {len(prefix)} bytes; truncated or empty)")
            magic, version, header_len, data_offset, total = _PREFIX.unpack(prefix)
            if magic != MAGIC:
                raise SDMInputError(f"{self.path}: not a Sky file (bad magic {magic!r}, expected {MAGIC!r})")
            if version != FORMAT_VERSION:
                raise SDMInputError(
                    f"{self.path}: Sky file format version {version} is not supported (this sdm reads version "
                    f"{FORMAT_VERSION}{_VERSION_NOTES.get(version, '')}); {REBUILD_HINT}"
                )
            if total != size:
                raise _damaged(self.path, f"file is {size} bytes but its header says {total} (truncated)")
            if data_offset < _PREFIX.size + header_len or data_offset > size:
                raise _damaged(self.path, f"inconsistent header (data offset {data_offset}, header {header_len} bytes)")
            header_bytes = stream.read(header_len)
        try:
            header = json.loads(header_bytes.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise _damaged(self.path, f"damaged header ({exc})") from None
        stored = header.pop("header_crc32", None) if isinstance(header, dict) else None
        if isinstance(stored, bool) or not isinstance(stored, int) or stored != zlib.crc32(_header_json(header)):
            raise _damaged(self.path, "header fails its CRC-32 (a camera field, the shift or the array table changed)")
        self._header = header
        self.version = int(version)
        try:
            if header.get("format") != FORMAT_NAME or header.get("version") != FORMAT_VERSION:
                raise _damaged(self.path, f"header names format {header.get('format')!r} version {header.get('version')!r}")
            n = int(header["n_configurations"])
            self.image_ids: list[str] = [str(i) for i in header["image_ids"]]
            if len(self.image_ids) != n:
                raise _damaged(self.path, f"{len(self.image_ids)} image ids for {n} configurations")
            a, b = (float(v) for v in header["shift"])
            self.shift: tuple[float, float] = (a, b)
            self.camera: Camera = Camera(**{name: header["camera"][name] for name in _CAMERA_FIELDS})
            self.metadata: dict = dict(header.get("metadata", {}))
            table = header["arrays"]
        except SDMInputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise _damaged(self.path, f"damaged header ({type(exc).__name__}: {exc})") from None
        self._n = n
        self._data_offset = int(data_offset)
        self._table = table
        self._map = np.memmap(self.path, dtype=np.uint8, mode="r") if size else np.zeros(0, np.uint8)
        self._arrays = {name: self._array(name) for name in _ARRAYS}
        self._offsets = {}
        for kind, rows in (("point", "point_pixels"), ("target", "target_pixels"), ("centre", "centre_pixels")):
            offsets = np.array(self._arrays[f"{kind}_offsets"], dtype=np.int64)
            count = self._arrays[rows].shape[0]
            if (
                offsets.shape != (n + 1,)
                or offsets[0] != 0
                or offsets[-1] != count
                or (np.diff(offsets) < 0).any()
            ):
                raise _damaged(self.path, f"{kind}_offsets are inconsistent with {rows}")
            self._offsets[kind] = offsets
        for name in ("point_depth", "point_car"):
            if self._arrays[name].shape[0] != self._arrays["point_pixels"].shape[0]:
                raise _damaged(self.path, f"{name} and point_pixels differ in length")
        if self._arrays["centre_depth"].shape[0] != self._arrays["centre_pixels"].shape[0]:
            raise _damaged(self.path, "centre_depth and centre_pixels differ in length")
        if self.checksums:
            for name in ("point_offsets", "target_offsets", "centre_offsets"):
                self._check_crc(name)

    def _array(self, name: str) -> np.ndarray:
        dtype, ndim = _ARRAYS[name]
        try:
            entry = self._table[name]
            shape = tuple(int(v) for v in entry["shape"])
            offset, nbytes = int(entry["offset"]), int(entry["nbytes"])
        except (KeyError, TypeError, ValueError):
            raise _damaged(self.path, f"header has no valid entry for array {name!r}") from None
        if isinstance(entry.get("crc32"), bool) or not isinstance(entry.get("crc32"), int):
            raise _damaged(self.path, f"header has no CRC-32 for array {name!r}")
        if entry.get("dtype") != dtype or len(shape) != ndim or (ndim == 2 and shape[1] != 2):
            raise _damaged(self.path, f"array {name!r} has dtype {entry.get('dtype')!r} shape {shape}, expected {dtype}")
        start = self._data_offset + offset
        expected = int(np.prod(shape)) * np.dtype(dtype).itemsize
        if nbytes != expected or offset % ALIGN or start + nbytes > self._map.shape[0]:
            raise _damaged(self.path, f"array {name!r} lies outside the file or has the wrong size")
        return self._map[start : start + nbytes].view(dtype).reshape(shape)

    # -- container protocol ---------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    def __getitem__(self, index: int) -> SkyConfiguration:
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            raise TypeError(f"Sky file indices must be integers, got {type(index).__name__}")
        i = int(index)
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"configuration index {index} out of range for {self._n} configurations in {self.path}")
        return self._decode(i)

    def __iter__(self) -> Iterator[SkyConfiguration]:
        for i in range(self._n):
            yield self._decode(i)

    def _rows(self, kind: str, name: str, i: int) -> np.ndarray:
        if self._map is None:
            raise ValueError(f"{self.path}: Sky file is closed")
        if self.checksums and name not in self._verified:
            self._check_crc(name)
        lo, hi = self._offsets[kind][i], self._offsets[kind][i + 1]
        return np.array(self._arrays[name][lo:hi])

    def _decode(self, i: int) -> SkyConfiguration:
        height, width = self.camera.screen_shape
        pixels = torch.from_numpy(self._rows("point", "point_pixels", i).astype(np.int64))
        depth = torch.from_numpy(self._rows("point", "point_depth", i).astype(np.float64))
        target_pixels = self._rows("target", "target_pixels", i).astype(np.int64)
        target = torch.zeros(height, width, dtype=torch.bool)
        if target_pixels.size:
            if target_pixels.min() < 0 or target_pixels[:, 0].max() >= height or target_pixels[:, 1].max() >= width:
                raise _damaged(self.path, f"configuration {i} has target pixels off the screen")
            target[torch.from_numpy(target_pixels[:, 0]), torch.from_numpy(target_pixels[:, 1])] = True
        centres = torch.from_numpy(self._rows("centre", "centre_pixels", i).astype(np.int64))
        centre_depth = torch.from_numpy(self._rows("centre", "centre_depth", i).astype(np.float64))
        cars = torch.from_numpy(self._rows("point", "point_car", i).astype(np.int64))
        if cars.numel() and (int(cars.min()) < 0 or int(cars.max()) >= centre_depth.shape[0]):
            raise _damaged(self.path, f"configuration {i} has point_car outside its {centre_depth.shape[0]} centres")
        return SkyConfiguration(
            pixels=pixels.reshape(-1, 2),
            depth=depth,
            target=target,
            image_id=self.image_ids[i],
            centres=centres.reshape(-1, 2),
            centre_depth=centre_depth,
            cars=cars,
        )

    def load_all(self) -> list[SkyConfiguration]:
        """Decode every configuration (after checking every array's CRC-32)."""
        self.verify()
        return [self._decode(i) for i in range(self._n)]

    def verify(self) -> None:
        """Check every array's CRC-32; raise :class:`SDMInputError` naming the file and array on a mismatch."""
        if self._map is None:
            raise ValueError(f"{self.path}: Sky file is closed")
        self._verified.clear()
        for name in _ARRAYS:
            self._check_crc(name)

    def _check_crc(self, name: str) -> None:
        """Check one array against its stored CRC-32 (zlib reads the memory map directly, no copy)."""
        if zlib.crc32(self._arrays[name]) != self._table[name]["crc32"]:
            raise _damaged(self.path, f"array {name!r} fails its CRC-32 check")
        self._verified.add(name)

    @property
    def header(self) -> dict:
        """A copy of the parsed JSON header."""
        return json.loads(json.dumps(self._header))

    def close(self) -> None:
        """Release the memory map (configurations already decoded stay valid)."""
        self._arrays = {}
        self._map = None

    def __enter__(self) -> "SkyFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"SkyFile({str(self.path)!r}, n={self._n}, version={self.version}, shift={self.shift})"
