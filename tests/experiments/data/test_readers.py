"""Readers: the real ApolloCar3D sample, a PKU CSV written here, and every kind of malformed input."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from sdm.camera import APOLLO_CAMERA_5
from sdm.experiments.data import ImageCars, read_apollo_camera, read_apollo_folder, read_pku_csv
from sdm.errors import SDMInputError
from sdm.sky import build_configuration

SAMPLE = Path(__file__).resolve().parents[3] / "data" / "apollocar3d-sample"


def needs_sample():
    if not (SAMPLE / "car_poses").is_dir():
        pytest.skip(f"real ApolloCar3D sample not found at {SAMPLE}")


def car(x, y, z, roll=0.15, pitch=0.01, yaw=-3.1):
    return {"area": 1000, "car_id": 2, "pose": [roll, pitch, yaw, x, y, z], "visible_rate": 1.0}


def apollo_folder(root: Path, files: dict[str, object | str], camera: str | None = None) -> Path:
    """An ApolloCar3D folder with car_poses/<name>.json holding each value (JSON-dumped unless a str)."""
    (root / "car_poses").mkdir(parents=True)
    for name, content in files.items():
        text = content if isinstance(content, str) else json.dumps(content)
        (root / "car_poses" / f"{name}.json").write_text(text)
    if camera is not None:
        (root / "camera").mkdir()
        (root / "camera" / "Camera_5.txt").write_text(camera)
    return root


# -- the real sample ------------------------------------------------------------------


def test_real_sample_reads_every_car():
    needs_sample()
    images = read_apollo_folder(SAMPLE, camera_file=SAMPLE / "camera" / "Camera_5.txt")
    files = sorted((SAMPLE / "car_poses").glob("*.json"))
    assert len(images) == len(files) == 57
    assert [image.image_id for image in images] == sorted(p.stem for p in files)
    assert sum(image.num_cars for image in images) == 251
    for image, path in zip(images, files):
        poses = [c["pose"] for c in json.loads(path.read_text())]
        expected = torch.tensor([p[3:] for p in poses], dtype=torch.float64).reshape(-1, 3)
        assert image.centres.dtype == torch.float64
        assert torch.equal(image.centres, expected)


def test_real_sample_geometry_is_a_road_seen_from_a_roof_camera():
    needs_sample()
    centres = torch.cat([image.centres for image in read_apollo_folder(SAMPLE)])
    assert bool((centres[:, 2] > 5).all())
    # y grows with z: cars on a road plane below the camera
    slope = torch.linalg.lstsq(torch.stack([torch.ones(len(centres)), centres[:, 2]], 1), centres[:, 1:2]).solution
    assert 0.1 < float(slope[1]) < 0.25 and 0.5 < float(slope[0]) < 2.0


def test_real_sample_camera_is_camera_5():
    needs_sample()
    camera = read_apollo_camera(SAMPLE)
    assert camera == APOLLO_CAMERA_5


# -- a folder written here ----------------------------------------------------------------


def test_folder_sorted_ids_and_empty_image(tmp_path):
    folder = apollo_folder(
        tmp_path / "apollo",
        {"b_img": [car(1.0, 3.0, 20.0), car(-3.0, 5.0, 30.0)], "a_img": [], "c_img": [car(0.5, 2.0, 12.0)]},
    )
    images = read_apollo_folder(folder)
    assert [i.image_id for i in images] == ["a_img", "b_img", "c_img"]
    assert images[0].centres.shape == (0, 3) and images[0].centres.dtype == torch.float64
    assert images[1].centres.tolist() == [[1.0, 3.0, 20.0], [-3.0, 5.0, 30.0]]
    # an image with no car becomes an empty configuration
    empty = build_configuration(images[0].centres, image_id=images[0].image_id)
    assert empty.num_points == 0 and not bool(empty.target.any()) and empty.centres.shape == (0, 2)


def test_camera_falls_back_to_camera_5_and_reads_a_file(tmp_path):
    folder = apollo_folder(tmp_path / "a", {"x": []})
    assert read_apollo_camera(folder) == APOLLO_CAMERA_5
    other = apollo_folder(tmp_path / "b", {"x": []}, camera="fx = 2000.0;\nfy = 2001.0;\ncx = 1600.0;\ncy = 1300.0;\n")
    camera = read_apollo_camera(other)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (2000.0, 2001.0, 1600.0, 1300.0)


# -- malformed folders -----------------------------------------------------------------------


def test_missing_folder(tmp_path):
    with pytest.raises(SDMInputError, match=r"nowhere: ApolloCar3D folder not found"):
        read_apollo_folder(tmp_path / "nowhere")


def test_folder_is_a_file(tmp_path):
    path = tmp_path / "file"
    path.write_text("x")
    with pytest.raises(SDMInputError, match="not a folder"):
        read_apollo_folder(path)


def test_missing_car_poses(tmp_path):
    (tmp_path / "apollo").mkdir()
    with pytest.raises(SDMInputError, match=r"car_poses: no 'car_poses' folder"):
        read_apollo_folder(tmp_path / "apollo")


def test_no_annotation_files(tmp_path):
    (tmp_path / "apollo" / "car_poses").mkdir(parents=True)
    with pytest.raises(SDMInputError, match=r"no annotation files"):
        read_apollo_folder(tmp_path / "apollo")


@pytest.mark.parametrize(
    "content, message",
    [
        ('[{"pose": [0, 0, 0, 1, 2, 3]},', r"img\.json: bad JSON at line 1"),
        ('{"pose": [0, 0, 0, 1, 2, 3]}', r"img\.json: expected a JSON list of cars, got a JSON dict"),
        ("[[0, 0, 0, 1, 2, 3]]", r"img\.json: car 0: expected an object with a 'pose', got list"),
        ('[{"pose": [0, 0, 0, 1, 2, 3]}, {"car_id": 3}]', r"img\.json: car 1: no 'pose' key"),
        ('[{"pose": [0, 0, 0, 1, 2]}]', r"img\.json: car 0: 'pose' must be a list of 6 numbers .* got 5 values"),
        ('[{"pose": [0, 0, 0, 1, 2, 3, 4]}]', r"img\.json: car 0: 'pose' must be a list of 6 numbers .* got 7 values"),
        ('[{"pose": "0 0 0 1 2 3"}]', r"img\.json: car 0: 'pose' must be a list of 6 numbers"),
        ('[{"pose": [0, 0, 0, "1.5", 2, 3]}]', r"img\.json: car 0: pose x is not a number: '1\.5'"),
        ('[{"pose": [0, 0, 0, 1, true, 3]}]', r"img\.json: car 0: pose y is not a number: True"),
        ('[{"pose": [0, 0, 0, 1, 2, null]}]', r"img\.json: car 0: pose z is not a number: None"),
        ('[{"pose": [0, 0, 0, 1, 2, NaN]}]', r"img\.json: non-finite number NaN"),
        ('[{"pose": [0, 0, Infinity, 1, 2, 3]}]', r"img\.json: non-finite number Infinity"),
        ('[{"pose": [0, 0, 0, 1e999, 2, 3]}]', r"img\.json: car 0: pose x is not finite: inf"),
    ],
)
def test_malformed_annotation_file(tmp_path, content, message):
    folder = apollo_folder(tmp_path / "apollo", {"good": [car(0, 2, 10)], "img": content})
    with pytest.raises(SDMInputError, match=message):
        read_apollo_folder(folder)


def test_annotation_with_a_byte_order_mark_is_read(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {})
    (folder / "car_poses" / "img.json").write_bytes(b"\xef\xbb\xbf" + json.dumps([car(1.0, 2.0, 30.0)]).encode())
    (image,) = read_apollo_folder(folder)
    assert image.image_id == "img" and image.centres.tolist() == [[1.0, 2.0, 30.0]]


def test_huge_integer_in_an_annotation_names_the_file(tmp_path):
    text = '[{"pose": [0, 0, 0, 1%s, 2, 30]}]' % ("0" * 400)
    folder = apollo_folder(tmp_path / "apollo", {"good": [car(0, 2, 10)], "img": text})
    with pytest.raises(SDMInputError, match=r"img\.json: car 0: pose x is too large for a float \(401-digit integer\)"):
        read_apollo_folder(folder)
    # beyond Python's 4300-digit limit the JSON parser itself refuses it: still the file's name
    (folder / "car_poses" / "img.json").write_text('[{"pose": [0, 0, 0, 1%s, 2, 30]}]' % ("0" * 5000))
    with pytest.raises(SDMInputError, match=r"img\.json: .*4300"):
        read_apollo_folder(folder)


def test_deeply_nested_annotation_names_the_file(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": "[" * 100_000 + "]" * 100_000})
    with pytest.raises(SDMInputError, match=r"img\.json: JSON nested too deeply to read"):
        read_apollo_folder(folder)


def test_not_utf8_annotation(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {})
    (folder / "car_poses" / "img.json").write_bytes(b"\xff\xfe[\x00]")
    with pytest.raises(SDMInputError, match=r"img\.json: cannot read annotation file"):
        read_apollo_folder(folder)


def test_missing_camera_file(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": []})
    with pytest.raises(SDMInputError, match=r"cam\.txt: camera intrinsics file not found"):
        read_apollo_folder(folder, camera_file=tmp_path / "cam.txt")


def test_bad_camera_file(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": []}, camera="fx = 2304.5;\nfy = oops;\ncx = 1;\ncy = 2;\n")
    with pytest.raises(SDMInputError, match=r"Camera_5\.txt: fy is not a number"):
        read_apollo_camera(folder)


@pytest.mark.parametrize(
    "text, message",
    [
        ("fx = 0;\nfy = 2305.8;\ncx = 1686.2;\ncy = 1355.0;\n", r"fx must be a positive focal length in pixels, got '0'"),
        ("fx = 2304.5;\nfy = -2305.8;\ncx = 1686.2;\ncy = 1355.0;\n", r"fy must be a positive focal length"),
        ("fx = nan;\nfy = 2305.8;\ncx = 1686.2;\ncy = 1355.0;\n", r"fx is not finite: 'nan'"),
        ("fx = 1e999;\nfy = 2305.8;\ncx = 1686.2;\ncy = 1355.0;\n", r"fx is not finite: '1e999'"),
    ],
)
def test_camera_file_with_a_bad_focal_length_names_the_file(tmp_path, text, message):
    folder = apollo_folder(tmp_path / "apollo", {"img": []}, camera=text)
    with pytest.raises(SDMInputError, match=r"Camera_5\.txt: " + message):
        read_apollo_camera(folder)


def test_camera_file_not_utf8_names_the_file(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": []}, camera="")
    (folder / "camera" / "Camera_5.txt").write_bytes(b"fx = 2304.5;\xff\xfe fy = 1;")
    with pytest.raises(SDMInputError, match=r"Camera_5\.txt: camera intrinsics file is not UTF-8 text"):
        read_apollo_camera(folder)


def test_camera_file_with_a_byte_order_mark_is_read(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": []}, camera="")
    (folder / "camera" / "Camera_5.txt").write_bytes(b"\xef\xbb\xbffx=2304.5479;fy=2305.8757;cx=1686.2379;cy=1354.9849;")
    assert read_apollo_camera(folder) == APOLLO_CAMERA_5


def test_several_camera_files_without_camera_5(tmp_path):
    folder = apollo_folder(tmp_path / "apollo", {"img": []})
    (folder / "camera").mkdir()
    for name in ("Camera_6.txt", "Camera_7.txt"):
        (folder / "camera" / name).write_text("fx = 1;\nfy = 1;\ncx = 1;\ncy = 1;\n")
    with pytest.raises(SDMInputError, match=r"several intrinsics files"):
        read_apollo_camera(folder)


# -- PKU / Baidu CSV -----------------------------------------------------------------------------


def write_csv(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_pku_csv(tmp_path):
    path = write_csv(
        tmp_path / "train.csv",
        "ImageId,PredictionString\n"
        "ID_b,16 0.25 -3.1 -3.12 7.96 7.2 34.2 23 0.1 -3.0 -3.1 -2.5 6.0 25.0\n"
        "ID_a,5 0.1 0.2 0.3 -1.5 4.5 20.0\n"
        "ID_c,\n",
    )
    images = read_pku_csv(path)
    assert [i.image_id for i in images] == ["ID_a", "ID_b", "ID_c"]
    assert images[0].centres.tolist() == [[-1.5, 4.5, 20.0]]
    assert images[1].centres.tolist() == [[7.96, 7.2, 34.2], [-2.5, 6.0, 25.0]]
    assert images[2].centres.shape == (0, 3)
    assert all(i.centres.dtype == torch.float64 for i in images)


def test_pku_csv_extra_columns_quotes_and_bom(tmp_path):
    path = tmp_path / "train.csv"
    path.write_bytes('\ufeffPredictionString,Note,ImageId\n"1 0 0 0 1.0 2.0 30.0",x,ID_1\n'.encode("utf-8"))
    (image,) = read_pku_csv(path)
    assert image.image_id == "ID_1" and image.centres.tolist() == [[1.0, 2.0, 30.0]]


@pytest.mark.parametrize(
    "text, message",
    [
        ("", r"train\.csv: empty file"),
        ("Id,PredictionString\nID_1,1 0 0 0 1 2 3\n", r"train\.csv: missing column\(s\) ImageId"),
        ("ImageId,Prediction\nID_1,1 0 0 0 1 2 3\n", r"train\.csv: missing column\(s\) PredictionString"),
        (
            "ImageId,PredictionString\nID_1,1 0 0 0 1 2 3\nID_2,1 0 0 0 1 2\n",
            r"train\.csv: line 3 \(ImageId ID_2\): PredictionString has 6 fields, not a multiple of 7",
        ),
        (
            "ImageId,PredictionString\nID_1,1 0 0 0 1 two 3\n",
            r"train\.csv: line 2 \(ImageId ID_1\): car 0 y is not a number: 'two'",
        ),
        (
            "ImageId,PredictionString\nID_1,1 0 0 0 1 2 3 4 0 0 0 nan 2 3\n",
            r"train\.csv: line 2 \(ImageId ID_1\): car 1 x is not finite: 'nan'",
        ),
        ("ImageId,PredictionString\nID_1,1 0 0 0 1 2 inf\n", r"line 2 \(ImageId ID_1\): car 0 z is not finite: 'inf'"),
        ("ImageId,PredictionString\nID_1,\nID_1,\n", r"train\.csv: line 3: ImageId 'ID_1' repeats line 2"),
        ("ImageId,PredictionString\n,1 0 0 0 1 2 3\n", r"train\.csv: line 2: empty ImageId"),
        ("ImageId,PredictionString\nID_1,1 0 0 0 1 2 3,extra\n", r"train\.csv: line 2: 3 fields, the header has 2"),
        ("ImageId,PredictionString\n", r"train\.csv: no image: the CSV has a header but no row"),
        ("\ufeffImageId,PredictionString\r\n\r\n", r"train\.csv: no image: the CSV has a header but no row"),
    ],
)
def test_malformed_pku_csv(tmp_path, text, message):
    path = write_csv(tmp_path / "train.csv", text)
    with pytest.raises(SDMInputError, match=message):
        read_pku_csv(path)


def test_missing_pku_csv(tmp_path):
    with pytest.raises(SDMInputError, match=r"train\.csv: car-pose CSV not found"):
        read_pku_csv(tmp_path / "train.csv")


def test_image_cars_validates():
    with pytest.raises(SDMInputError, match="shape"):
        ImageCars("x", torch.zeros(3))
    with pytest.raises(SDMInputError, match="float64"):
        ImageCars("x", torch.zeros(1, 3, dtype=torch.float32))
    with pytest.raises(SDMInputError, match="finite"):
        ImageCars("x", torch.tensor([[0.0, 1.0, float("nan")]], dtype=torch.float64))


def test_read_annotations_dispatches_on_the_source_kind(tmp_path):
    from sdm.experiments.data import read_annotations

    csv_path = tmp_path / "train.csv"
    csv_path.write_text("ImageId,PredictionString\nID_a,5 0.1 0.2 0.3 1.0 2.0 30.0\n")
    images, camera = read_annotations("pku", csv_path)
    assert [image.image_id for image in images] == ["ID_a"] and camera == APOLLO_CAMERA_5
    with pytest.raises(SDMInputError, match="unknown annotation source 'kitti'"):
        read_annotations("kitti", csv_path)
