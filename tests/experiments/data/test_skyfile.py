"""The Sky dataset: sampling, the versioned file, lazy reading, determinism, damaged files."""
from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import pytest
import torch

from sdm.camera import APOLLO_CAMERA_5, Camera
from sdm.experiments.data import (
    FORMAT_VERSION,
    ImageCars,
    SkyFile,
    build_sky_dataset,
    read_apollo_camera,
    read_apollo_folder,
    synthetic_images,
    write_sky_file,
    write_synthetic_apollo,
)
from sdm.experiments.data import skyfile as skyfile_module
from sdm.errors import SDMInputError
from sdm.sky import SKY_SHIFT, SkyConfiguration, build_configuration


def same(a: SkyConfiguration, b: SkyConfiguration) -> bool:
    return (
        a.image_id == b.image_id
        and a.pixels.dtype == b.pixels.dtype == torch.int64
        and a.depth.dtype == b.depth.dtype == torch.float64
        and a.target.dtype == b.target.dtype == torch.bool
        and torch.equal(a.pixels, b.pixels)
        and torch.equal(a.depth, b.depth)
        and torch.equal(a.target, b.target)
        and torch.equal(a.centres, b.centres)
        and torch.equal(a.centre_depth, b.centre_depth)
        and a.cars.dtype == b.cars.dtype == torch.int64
        and torch.equal(a.cars, b.cars)
    )


@pytest.fixture(scope="module")
def images() -> list[ImageCars]:
    images = synthetic_images(120, seed=5)
    # an image whose only car is behind the camera and one with no car at all
    images.append(ImageCars("zz_behind", torch.tensor([[0.0, 1.0, -5.0]], dtype=torch.float64)))
    images.append(ImageCars("zz_empty", torch.zeros(0, 3, dtype=torch.float64)))
    return images


@pytest.fixture(scope="module")
def configurations(images) -> list[SkyConfiguration]:
    return build_sky_dataset(images, n_sample=len(images), seed=0, progress=False)


@pytest.fixture()
def sky_path(tmp_path, configurations) -> Path:
    path = tmp_path / "sky.bin"
    write_sky_file(path, configurations, SKY_SHIFT, APOLLO_CAMERA_5, {"source": "test", "seed": 5})
    return path


# -- sampling -----------------------------------------------------------------------------------


def test_sample_is_seeded_without_replacement_in_input_order(images):
    a = build_sky_dataset(images, n_sample=50, seed=1, progress=False)
    b = build_sky_dataset(images, n_sample=50, seed=1, progress=False)
    c = build_sky_dataset(images, n_sample=50, seed=2, progress=False)
    ids = [cfg.image_id for cfg in a]
    assert ids == [cfg.image_id for cfg in b] and all(same(x, y) for x, y in zip(a, b))
    assert ids != [cfg.image_id for cfg in c]
    order = {image.image_id: k for k, image in enumerate(images)}
    assert len(set(ids)) == 50 and [order[i] for i in ids] == sorted(order[i] for i in ids)


def test_sample_builds_the_configurations_of_the_core_library(images, configurations):
    for image, cfg in zip(images, configurations):
        assert same(cfg, build_configuration(image.centres, SKY_SHIFT, APOLLO_CAMERA_5, image.image_id))
    assert configurations[-1].num_points == 0 and configurations[-2].num_points == 0


def test_sample_larger_than_the_set_is_an_error(images):
    with pytest.raises(SDMInputError, match=r"n_sample = 500 is larger than the number of images \(122\)"):
        build_sky_dataset(images, n_sample=500, progress=False)


def test_sample_rejects_non_images():
    with pytest.raises(SDMInputError, match=r"images\[0\] must be ImageCars"):
        build_sky_dataset([torch.zeros(2, 3)], n_sample=1, progress=False)


# -- the file ---------------------------------------------------------------------------------


def test_round_trip(sky_path, configurations):
    sky = SkyFile(sky_path)
    assert len(sky) == len(configurations)
    assert sky.version == FORMAT_VERSION == 3
    assert sky.image_ids == [cfg.image_id for cfg in configurations]
    assert sky.shift == SKY_SHIFT and sky.camera == APOLLO_CAMERA_5
    assert sky.metadata == {"source": "test", "seed": 5}
    loaded = sky.load_all()
    assert all(same(a, b) for a, b in zip(loaded, configurations))
    assert same(sky[-1], configurations[-1]) and same(sky[7], configurations[7])
    assert sky[-1].num_points == 0 and not bool(sky[-1].target.any())
    with pytest.raises(IndexError):
        sky[len(configurations)]


def test_opening_is_lazy(sky_path, monkeypatch):
    decoded = []
    real = SkyFile._decode

    def counting(self, i):
        decoded.append(i)
        return real(self, i)

    monkeypatch.setattr(SkyFile, "_decode", counting)
    sky = SkyFile(sky_path)
    assert decoded == []
    sky[3]
    sky[-2]
    assert decoded == [3, len(sky) - 2]


def test_other_camera_and_shift_are_stored(tmp_path, images):
    camera = Camera(fx=2000.0, fy=2100.0, cx=1700.0, cy=1300.0)
    configurations = build_sky_dataset(images[:10], n_sample=10, shift=(-0.2, 0.4), camera=camera, progress=False)
    write_sky_file(tmp_path / "s.bin", configurations, (-0.2, 0.4), camera)
    sky = SkyFile(tmp_path / "s.bin")
    assert sky.camera == camera and sky.shift == (-0.2, 0.4) and sky.metadata == {}
    assert all(same(a, b) for a, b in zip(sky, configurations))


def test_empty_dataset(tmp_path):
    write_sky_file(tmp_path / "s.bin", [], SKY_SHIFT, APOLLO_CAMERA_5)
    sky = SkyFile(tmp_path / "s.bin")
    assert len(sky) == 0 and sky.load_all() == [] and sky.image_ids == []


def test_same_inputs_give_the_same_bytes(tmp_path, configurations):
    write_sky_file(tmp_path / "a.bin", configurations, SKY_SHIFT, APOLLO_CAMERA_5, {"seed": 5})
    write_sky_file(tmp_path / "b.bin", configurations, SKY_SHIFT, APOLLO_CAMERA_5, {"seed": 5})
    assert (tmp_path / "a.bin").read_bytes() == (tmp_path / "b.bin").read_bytes()


def test_same_seed_gives_a_byte_identical_sky_file_end_to_end(tmp_path):
    def pipeline(name: str, seed: int) -> bytes:
        folder = write_synthetic_apollo(tmp_path / name, n_images=80, seed=seed)
        configurations = build_sky_dataset(read_apollo_folder(folder), n_sample=60, seed=seed, progress=False)
        write_sky_file(tmp_path / f"{name}.bin", configurations, SKY_SHIFT, read_apollo_camera(folder), {"seed": seed})
        return (tmp_path / f"{name}.bin").read_bytes()

    first, again, other = pipeline("a", 11), pipeline("b", 11), pipeline("c", 12)
    assert first == again
    assert first != other


def test_write_is_atomic(tmp_path, configurations):
    path = tmp_path / "sky.bin"
    write_sky_file(path, configurations[:5], SKY_SHIFT, APOLLO_CAMERA_5)
    before = path.read_bytes()
    bad = SkyConfiguration(pixels=torch.tensor([[200, 3]]), depth=torch.tensor([10.0], dtype=torch.float64), target=torch.zeros(128, 256, dtype=torch.bool))
    with pytest.raises(SDMInputError, match=r"configurations\[5\] .*off the 128x256 screen"):
        write_sky_file(path, configurations[:5] + [bad], SKY_SHIFT, APOLLO_CAMERA_5)
    assert path.read_bytes() == before
    with pytest.raises(SDMInputError, match="not JSON-serialisable"):
        write_sky_file(path, configurations[:5], SKY_SHIFT, APOLLO_CAMERA_5, {"when": object()})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sky.bin"]


def one_car(**change) -> SkyConfiguration:
    cfg = build_configuration(torch.tensor([[1.0, 3.0, 30.0]], dtype=torch.float64), image_id="one")
    return dataclasses.replace(cfg, **change)


def two_cars_swapped() -> SkyConfiguration:
    """Two cars whose points are given each other's car: the depths give the lie away."""
    cfg = build_configuration(torch.tensor([[-4.0, 3.0, 30.0], [4.0, 3.0, 40.0]], dtype=torch.float64))
    return dataclasses.replace(cfg, cars=1 - cfg.cars)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: SkyConfiguration(torch.zeros(1, 2, dtype=torch.int64), torch.tensor([-1.0], dtype=torch.float64), torch.zeros(128, 256, dtype=torch.bool)), "depth must be finite and positive"),
        (lambda: SkyConfiguration(torch.zeros(1, 2, dtype=torch.int64), torch.tensor([1.0, 2.0], dtype=torch.float64), torch.zeros(128, 256, dtype=torch.bool)), r"depth must be a floating \(1,\) tensor"),
        (lambda: SkyConfiguration(torch.zeros(1, 2), torch.tensor([1.0], dtype=torch.float64), torch.zeros(128, 256, dtype=torch.bool)), "pixels must be an integer tensor"),
        (lambda: SkyConfiguration(torch.zeros(0, 2, dtype=torch.int64), torch.zeros(0, dtype=torch.float64), torch.zeros(64, 256, dtype=torch.bool)), r"target must be a \(128, 256\) bool tensor"),
        (lambda: "not a configuration", r"configurations\[0\] must be a SkyConfiguration"),
        (lambda: one_car(cars=None), r"configurations\[0\] \(image 'one'\): cars \(the car of each point\) is missing"),
        (lambda: one_car(cars=torch.zeros(3, dtype=torch.int64)), r"cars must be a \(57,\) tensor"),
        (lambda: one_car(cars=torch.zeros(57)), r"cars must be an integer tensor"),
        (lambda: one_car(cars=torch.ones(57, dtype=torch.int64)), r"cars must index the 1 centres, got 1\.\.1"),
        (lambda: one_car(cars=torch.full((57,), -1, dtype=torch.int64)), r"cars must index the 1 centres"),
        (lambda: two_cars_swapped(), r"cars disagree with the depths"),
    ],
)
def test_bad_configurations_are_rejected(tmp_path, make, message):
    with pytest.raises(SDMInputError, match=message):
        write_sky_file(tmp_path / "s.bin", [make()], SKY_SHIFT, APOLLO_CAMERA_5)
    assert not (tmp_path / "s.bin").exists()


def test_bad_shift_is_rejected(tmp_path):
    with pytest.raises(SDMInputError, match="shift must be finite"):
        write_sky_file(tmp_path / "s.bin", [], (float("nan"), 0.0), APOLLO_CAMERA_5)


# -- damaged or foreign files -------------------------------------------------------------------


def damage(path: Path, edit) -> Path:
    data = bytearray(path.read_bytes())
    path.write_bytes(bytes(edit(data)))
    return path


def test_missing_file(tmp_path):
    with pytest.raises(SDMInputError, match=r"nothing\.bin: Sky file not found"):
        SkyFile(tmp_path / "nothing.bin")


def test_empty_file(tmp_path):
    (tmp_path / "e.bin").write_bytes(b"")
    with pytest.raises(SDMInputError, match=r"e\.bin: not a Sky file \(only 0 bytes"):
        SkyFile(tmp_path / "e.bin")


def test_wrong_magic(sky_path):
    damage(sky_path, lambda d: b"PK\x03\x04" + d[4:])
    with pytest.raises(SDMInputError, match=r"sky\.bin: not a Sky file \(bad magic"):
        SkyFile(sky_path)


def test_other_version(sky_path):
    damage(sky_path, lambda d: d[:8] + struct.pack("<I", 4) + d[12:])
    with pytest.raises(SDMInputError, match=r"sky\.bin: Sky file format version 4 is not supported \(this sdm reads version 3\)"):
        SkyFile(sky_path)


def test_a_version_1_file_is_refused_saying_how_to_rebuild_it(tmp_path, configurations, monkeypatch):
    """A file written in the old layout (no point_car) is refused, naming the file, its version and the rebuild."""
    path = tmp_path / "old.bin"
    with monkeypatch.context() as old:
        old.setattr(skyfile_module, "FORMAT_VERSION", 1)
        old.setattr(skyfile_module, "_ARRAYS", {k: v for k, v in skyfile_module._ARRAYS.items() if k != "point_car"})
        write_sky_file(path, configurations[:4], SKY_SHIFT, APOLLO_CAMERA_5)
    assert struct.unpack("<I", path.read_bytes()[8:12]) == (1,)
    with pytest.raises(SDMInputError) as error:
        SkyFile(path)
    assert str(error.value) == (
        f"{path}: Sky file format version 1 is not supported (this sdm reads version 3; version 1 does not record "
        f"the car of each point); {skyfile_module.REBUILD_HINT}"
    )
    # the old layout under the new version number is refused too, never read without its car index
    damage(path, lambda d: d[:8] + struct.pack("<I", 3) + d[12:])
    with pytest.raises(SDMInputError, match=rf"old\.bin: header names format 'sdm-sky' version 1.*{REBUILD}"):
        SkyFile(path)


def test_a_header_without_point_car_is_refused(tmp_path, configurations):
    path = tmp_path / "s.bin"
    write_sky_file(path, configurations[:4], SKY_SHIFT, APOLLO_CAMERA_5)
    damage(path, lambda d: d.replace(b'"point_car"', b'"point_cat"'))  # the header's CRC-32 no longer matches
    with pytest.raises(SDMInputError, match=rf"s\.bin: header fails its CRC-32.*{REBUILD}"):
        SkyFile(path)


@pytest.mark.parametrize("edit", [(b'"fx":2304', b'"fx":3304'), (b'[0.517,', b'[0.617,')], ids=["camera", "shift"])
def test_a_header_changed_by_one_byte_is_refused(tmp_path, configurations, edit):
    """The header is under its own CRC-32: on main a camera or shift changed by one byte was read (and verify()
    passed), moving every point."""
    path = tmp_path / "s.bin"
    write_sky_file(path, configurations[:4], SKY_SHIFT, APOLLO_CAMERA_5)
    data = path.read_bytes()
    assert data.count(edit[0]) == 1
    damage(path, lambda d: bytes(d).replace(edit[0], edit[1], 1))
    with pytest.raises(SDMInputError, match=rf"s\.bin: header fails its CRC-32.*{REBUILD}"):
        SkyFile(path).verify()


def test_a_car_index_outside_the_centres_is_refused_on_read(tmp_path, configurations, monkeypatch):
    """A file whose point_car passes its CRC-32 but points past a configuration's centres is refused on read."""
    path = tmp_path / "s.bin"
    real = skyfile_module._check_cars
    with monkeypatch.context() as writer:  # the writer refuses such an index: let one through
        writer.setattr(skyfile_module, "_check_cars", lambda *args: real(*args) + 1)
        write_sky_file(path, configurations[:4], SKY_SHIFT, APOLLO_CAMERA_5)
    first = next(i for i, cfg in enumerate(configurations[:4]) if cfg.num_points)
    with pytest.raises(SDMInputError, match=rf"s\.bin: configuration {first} has point_car outside its \d+ centres.*{REBUILD}"):
        SkyFile(path)[first]


REBUILD = r"delete it and run snakemake again to rebuild it \(the 'sky' stage\)"


@pytest.mark.parametrize("keep", [10, 40, 300, -1])
def test_truncated(sky_path, keep):
    damage(sky_path, lambda d: d[:keep])
    with pytest.raises(SDMInputError, match=rf"sky\.bin: .*(truncated|not a Sky file).*{REBUILD}"):
        SkyFile(sky_path)


def test_damaged_header(sky_path):
    damage(sky_path, lambda d: d[:40] + b"\x00\x00\x00" + d[43:])
    with pytest.raises(SDMInputError, match=r"sky\.bin: damaged header"):
        SkyFile(sky_path)


def test_damaged_data_fails_the_checksum(sky_path):
    damage(sky_path, lambda d: d[:-9] + bytes([d[-9] ^ 0xFF]) + d[-8:])
    sky = SkyFile(sky_path)  # the damage is in the data, not the header: found by verify / load_all
    with pytest.raises(SDMInputError, match=r"sky\.bin: array 'centre_depth' fails its CRC-32 check"):
        sky.load_all()


def flip_byte(path: Path, array: str, where: float = 0.5) -> int:
    """Flip every bit of one byte of ``array`` (at the fraction ``where`` of its bytes); return the byte's index."""
    sky = SkyFile(path, checksums=False)
    entry = sky._table[array]
    assert entry["nbytes"] > 0, array
    index = sky._data_offset + entry["offset"] + int(where * (entry["nbytes"] - 1))
    damage(path, lambda d: d[:index] + bytes([d[index] ^ 0xFF]) + d[index + 1:])
    return index


def test_one_flipped_depth_byte_is_refused_on_read_naming_the_file(sky_path, configurations):
    # the flip is in the last configuration with points; reading the first one already refuses the file,
    # since the check covers the whole array it reads from
    flip_byte(sky_path, "point_depth", where=0.99)
    sky = SkyFile(sky_path)  # opening reads only the header and the offsets
    with pytest.raises(SDMInputError, match=rf"sky\.bin: array 'point_depth' fails its CRC-32 check.*{REBUILD}"):
        sky[0]
    with pytest.raises(SDMInputError, match=r"sky\.bin: array 'point_depth' fails"):
        list(SkyFile(sky_path))
    # the damage is real: without the checks the file decodes to other depths, silently
    unchecked = list(SkyFile(sky_path, checksums=False))
    changed = [k for k, cfg in enumerate(unchecked) if not torch.equal(cfg.depth, configurations[k].depth)]
    assert len(changed) == 1


@pytest.mark.parametrize("array", list(skyfile_module._ARRAYS))
def test_one_flipped_byte_in_any_array_is_refused_naming_the_file(sky_path, array):
    flip_byte(sky_path, array)
    with pytest.raises(SDMInputError) as error:
        sky = SkyFile(sky_path)
        sky[len(sky) // 2]
    message = str(error.value)
    assert message.startswith(f"{sky_path}: ")
    assert "damaged" in message and "snakemake --forcerun sky" in message
    if not array.endswith("_offsets"):  # a flipped offset may already break the offsets' consistency check
        assert f"array {array!r} fails its CRC-32 check" in message


def test_verified_arrays_are_checked_once_per_opened_file(sky_path, monkeypatch):
    checked = []
    real = SkyFile._check_crc
    monkeypatch.setattr(SkyFile, "_check_crc", lambda self, name: (checked.append(name), real(self, name))[1])
    sky = SkyFile(sky_path)
    assert sorted(checked) == ["centre_offsets", "point_offsets", "target_offsets"]
    sky[0], sky[5], sky[-1]
    assert sorted(checked) == sorted(skyfile_module._ARRAYS)
    checked.clear()
    SkyFile(sky_path, checksums=False)[0]
    assert checked == []


def test_inconsistent_offsets(tmp_path, configurations):
    path = tmp_path / "s.bin"
    write_sky_file(path, configurations[:4], SKY_SHIFT, APOLLO_CAMERA_5)
    sky = SkyFile(path)
    start = sky._data_offset + sky._table["point_offsets"]["offset"]
    damage(path, lambda d: d[:start + 8] + struct.pack("<q", 10**9) + d[start + 16:])
    with pytest.raises(SDMInputError, match=r"s\.bin: point_offsets are inconsistent"):
        SkyFile(path)


def test_format_constants_are_documented():
    docs = Path(__file__).resolve().parents[3] / "docs" / "data.md"
    text = docs.read_text()
    assert skyfile_module.MAGIC.decode("latin-1").strip("\x89\n") in text
    for name in skyfile_module._ARRAYS:
        assert name in text, name
