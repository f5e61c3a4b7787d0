"""Readers for car annotations: ApolloCar3D folders and the PKU/Baidu ``train.csv``.

Both readers yield, per image, its id and the car centres ``(x, y, z)`` in the
camera frame (metres; x right, y down, z forward), as :class:`ImageCars`, sorted
by image id. Nothing else of the annotation (model, orientation) is used by the
Sky dataset.

Every malformed input raises :class:`~sdm.errors.SDMInputError` with a message
that names the file (and the car or CSV line) and says what is wrong.

An image whose annotation lists no car is kept, with an empty ``(0, 3)``
``centres`` tensor; so is an image whose cars are all behind the camera or off
screen. :func:`sdm.sky.build_configuration` turns such an image into an
*empty* configuration (no point, empty target), which every later stage
accepts.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from ...camera import APOLLO_CAMERA_5, Camera
from ...errors import SDMInputError

#: Name of the ApolloCar3D annotation sub-folder.
CAR_POSES = "car_poses"
#: Name of the ApolloCar3D intrinsics sub-folder.
CAMERA_DIR = "camera"
#: The intrinsics file that :func:`read_apollo_camera` prefers.
CAMERA_FILE = "Camera_5.txt"
#: Columns the PKU/Baidu car-pose CSV must have.
PKU_COLUMNS = ("ImageId", "PredictionString")
#: Fields per car in a PKU prediction string: ``model_type yaw pitch roll x y z``.
PKU_FIELDS = 7


@dataclass(frozen=True)
class ImageCars:
    """The labelled cars of one image.

    Attributes:
        image_id: image name (the JSON file's stem, or the CSV's ``ImageId``).
        centres: ``(M, 3)`` float64 car centres ``(x, y, z)`` in metres, camera
            frame; ``M`` may be 0. Cars behind the camera are kept here (the
            Sky construction drops them).
    """

    image_id: str
    centres: torch.Tensor

    def __post_init__(self) -> None:
        if not isinstance(self.image_id, str) or not self.image_id:
            raise SDMInputError(f"ImageCars.image_id must be a non-empty string, got {self.image_id!r}")
        centres = self.centres
        if not isinstance(centres, torch.Tensor):
            raise SDMInputError(f"ImageCars({self.image_id!r}).centres must be a torch.Tensor, got {type(centres).__name__}")
        if centres.ndim != 2 or centres.shape[1] != 3:
            raise SDMInputError(f"ImageCars({self.image_id!r}).centres must have shape (M, 3), got {tuple(centres.shape)}")
        if centres.dtype != torch.float64:
            raise SDMInputError(f"ImageCars({self.image_id!r}).centres must be float64, got {centres.dtype}")
        if not bool(torch.isfinite(centres).all()):
            raise SDMInputError(f"ImageCars({self.image_id!r}).centres must be finite")

    @property
    def num_cars(self) -> int:
        return int(self.centres.shape[0])


# -- ApolloCar3D folder -----------------------------------------------------------


def read_apollo_folder(folder: str | Path, camera_file: str | Path | None = None) -> list[ImageCars]:
    """Read an ApolloCar3D annotation folder.

    Layout::

        folder/car_poses/<image>.json   a JSON list of cars, each an object with
                                        "pose": [roll, pitch, yaw, x, y, z]
        folder/camera/Camera_5.txt      intrinsics (see read_apollo_camera)

    Other keys of a car (``car_id``, ``area``, ``visible_rate``) are ignored.

    Args:
        folder: the dataset folder (the one holding ``car_poses``).
        camera_file: optional intrinsics file; when given it must exist and
            parse (it is validated, not returned: the poses are already in the
            camera frame; use :func:`read_apollo_camera` for the camera).

    Returns:
        One :class:`ImageCars` per JSON file, sorted by image id (file stem).
        A file holding ``[]`` gives an image with no car.

    Raises:
        SDMInputError: missing folder or ``car_poses``, no JSON file, a file
            that is not JSON or not a list, a car without a pose of six finite
            numbers; the message names the file and the car's index.
    """
    folder = Path(folder)
    if not folder.exists():
        raise SDMInputError(f"{folder}: ApolloCar3D folder not found")
    if not folder.is_dir():
        raise SDMInputError(f"{folder}: not a folder (expected an ApolloCar3D folder holding '{CAR_POSES}/')")
    poses = folder / CAR_POSES
    if not poses.is_dir():
        raise SDMInputError(f"{poses}: no '{CAR_POSES}' folder in the ApolloCar3D folder {folder}")
    if camera_file is not None:
        Camera.from_file(camera_file)
    files = sorted(poses.glob("*.json"))
    if not files:
        raise SDMInputError(f"{poses}: no annotation files (*.json)")
    images = [ImageCars(path.stem, read_car_poses(path)) for path in files]
    return sorted(images, key=lambda image: image.image_id)


def read_car_poses(path: str | Path) -> torch.Tensor:
    """Car centres of one ApolloCar3D ``car_poses`` JSON file.

    The file is UTF-8 JSON; a leading byte-order mark is accepted (as for the CSV).

    Returns:
        ``(M, 3)`` float64 centres ``(x, y, z)`` in metres, in file order.

    Raises:
        SDMInputError: naming the file (and car index) for unreadable or
            invalid JSON (also nesting too deep to parse), a top level that is
            not a list, a car that is not an object, has no ``pose``, or whose
            pose is not six finite numbers (an integer too large for a float
            included).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise SDMInputError(f"{path}: annotation file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SDMInputError(f"{path}: cannot read annotation file ({exc})") from None
    try:
        cars = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise SDMInputError(f"{path}: bad JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except ValueError as exc:  # a NaN / Infinity literal, an integer of more than 4300 digits
        raise SDMInputError(f"{path}: {exc}") from None
    except RecursionError:
        raise SDMInputError(f"{path}: JSON nested too deeply to read (expected a list of car objects)") from None
    if not isinstance(cars, list):
        raise SDMInputError(f"{path}: expected a JSON list of cars, got a JSON {type(cars).__name__}")
    centres = []
    for index, car in enumerate(cars):
        where = f"{path}: car {index}"
        if not isinstance(car, dict):
            raise SDMInputError(f"{where}: expected an object with a 'pose', got {type(car).__name__}")
        if "pose" not in car:
            raise SDMInputError(f"{where}: no 'pose' key (expected 'pose': [roll, pitch, yaw, x, y, z])")
        pose = car["pose"]
        if not isinstance(pose, list) or len(pose) != 6:
            got = f"{len(pose)} values" if isinstance(pose, list) else repr(pose)
            raise SDMInputError(f"{where}: 'pose' must be a list of 6 numbers [roll, pitch, yaw, x, y, z], got {got}")
        numbers = []
        for name, value in zip(("roll", "pitch", "yaw", "x", "y", "z"), pose):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise SDMInputError(f"{where}: pose {name} is not a number: {value!r}")
            try:
                number = float(value)
            except OverflowError:  # a JSON integer beyond float range
                raise SDMInputError(f"{where}: pose {name} is too large for a float ({len(str(abs(value)))}-digit integer)") from None
            if not math.isfinite(number):
                raise SDMInputError(f"{where}: pose {name} is not finite: {value!r}")
            numbers.append(number)
        centres.append(numbers[3:])
    return torch.tensor(centres, dtype=torch.float64).reshape(-1, 3)


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name} (pose values must be finite)")


def read_apollo_camera(folder: str | Path) -> Camera:
    """The camera of an ApolloCar3D folder.

    Reads ``folder/camera/Camera_5.txt`` if present, else the only ``*.txt`` in
    ``folder/camera``; falls back to :data:`~sdm.camera.APOLLO_CAMERA_5` when
    the folder has no ``camera`` sub-folder (or it holds no ``.txt``).

    Raises:
        SDMInputError: missing ``folder``; several candidate intrinsics files
            and no ``Camera_5.txt``; an intrinsics file that does not parse.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SDMInputError(f"{folder}: ApolloCar3D folder not found")
    camera_dir = folder / CAMERA_DIR
    if not camera_dir.is_dir():
        return APOLLO_CAMERA_5
    preferred = camera_dir / CAMERA_FILE
    if preferred.is_file():
        return Camera.from_file(preferred)
    candidates = sorted(camera_dir.glob("*.txt"))
    if not candidates:
        return APOLLO_CAMERA_5
    if len(candidates) > 1:
        names = ", ".join(p.name for p in candidates)
        raise SDMInputError(f"{camera_dir}: several intrinsics files ({names}) and no {CAMERA_FILE}; pass camera_file")
    return Camera.from_file(candidates[0])


# -- PKU / Baidu car-pose CSV -------------------------------------------------------


def read_pku_csv(path: str | Path) -> list[ImageCars]:
    """Read the PKU/Baidu car-pose ``train.csv``.

    Columns ``ImageId, PredictionString`` (others are ignored); the string
    repeats ``model_type yaw pitch roll x y z`` (whitespace separated) per car.
    An empty prediction string is an image with no car. The camera is
    ``Camera_5`` (:data:`~sdm.camera.APOLLO_CAMERA_5`).

    Returns:
        One :class:`ImageCars` per row, sorted by image id.

    Raises:
        SDMInputError: naming the file (and line, 1-based, the header being
            line 1) for a missing file, missing columns, no row after the
            header, an empty image id, a
            repeated image id, a prediction string whose number of fields is
            not a multiple of 7, a non-numeric or non-finite field.
    """
    path = Path(path)
    if not path.is_file():
        raise SDMInputError(f"{path}: car-pose CSV not found")
    images: dict[str, ImageCars] = {}
    lines: dict[str, int] = {}
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if header is None:
                raise SDMInputError(f"{path}: empty file (expected a header with columns {', '.join(PKU_COLUMNS)})")
            header = [name.strip() for name in header]
            missing = [name for name in PKU_COLUMNS if name not in header]
            if missing:
                raise SDMInputError(
                    f"{path}: missing column(s) {', '.join(missing)} (header is {', '.join(header) or 'empty'})"
                )
            id_col, pred_col = (header.index(name) for name in PKU_COLUMNS)
            for row in reader:
                line = reader.line_num
                if not row or all(not cell.strip() for cell in row):
                    continue
                if len(row) != len(header):
                    raise SDMInputError(f"{path}: line {line}: {len(row)} fields, the header has {len(header)}")
                image_id = row[id_col].strip()
                if not image_id:
                    raise SDMInputError(f"{path}: line {line}: empty ImageId")
                if image_id in images:
                    raise SDMInputError(f"{path}: line {line}: ImageId {image_id!r} repeats line {lines[image_id]}")
                centres = parse_prediction_string(row[pred_col], f"{path}: line {line} (ImageId {image_id})")
                images[image_id] = ImageCars(image_id, centres)
                lines[image_id] = line
    except UnicodeDecodeError as exc:
        raise SDMInputError(f"{path}: not UTF-8 text ({exc})") from None
    except csv.Error as exc:
        raise SDMInputError(f"{path}: malformed CSV ({exc})") from None
    if not images:
        raise SDMInputError(f"{path}: no image: the CSV has a header but no row (expected one row per image)")
    return [images[key] for key in sorted(images)]


def parse_prediction_string(text: str, where: str = "prediction string") -> torch.Tensor:
    """Car centres of a PKU prediction string ``model_type yaw pitch roll x y z ...``.

    Args:
        text: whitespace-separated numbers, 7 per car; empty means no car.
        where: prefix of error messages (file and line).

    Returns:
        ``(M, 3)`` float64 centres ``(x, y, z)`` in metres.
    """
    fields = text.split()
    if len(fields) % PKU_FIELDS:
        raise SDMInputError(
            f"{where}: PredictionString has {len(fields)} fields, not a multiple of {PKU_FIELDS} "
            "(model_type yaw pitch roll x y z per car)"
        )
    names = ("model_type", "yaw", "pitch", "roll", "x", "y", "z")
    values = []
    for index, field in enumerate(fields):
        name = f"car {index // PKU_FIELDS} {names[index % PKU_FIELDS]}"
        try:
            value = float(field)
        except ValueError:
            raise SDMInputError(f"{where}: {name} is not a number: {field!r}") from None
        if not math.isfinite(value):
            raise SDMInputError(f"{where}: {name} is not finite: {field!r}")
        values.append(value)
    table = torch.tensor(values, dtype=torch.float64).reshape(-1, PKU_FIELDS)
    return table[:, 4:7].contiguous()


#: Annotation sources :func:`read_annotations` understands (``synthetic`` is an ApolloCar3D folder).
SOURCE_KINDS = ("synthetic", "apollo", "pku")


def read_annotations(source_kind: str, path: str | Path) -> tuple[list[ImageCars], Camera]:
    """Read a configured annotation source: its images and the camera they were taken with.

    Args:
        source_kind: ``"synthetic"`` or ``"apollo"`` (an ApolloCar3D folder, camera
            from its ``camera/`` folder) or ``"pku"`` (the PKU/Baidu ``train.csv``,
            taken with ApolloCar3D's ``Camera_5``).
        path: the folder or the CSV file.
    """
    if source_kind == "pku":
        return read_pku_csv(path), APOLLO_CAMERA_5
    if source_kind in ("synthetic", "apollo"):
        return read_apollo_folder(path), read_apollo_camera(path)
    raise SDMInputError(f"unknown annotation source {source_kind!r}; expected one of {', '.join(SOURCE_KINDS)}")
