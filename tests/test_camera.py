import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from sdm.camera import APOLLO_CAMERA_5, Camera
from sdm.errors import SDMInputError
from sdm.representation import render_rmin
from sdm.sky import pixel_centre_points


def test_projection_matches_the_notes_formula():
    cam = APOLLO_CAMERA_5
    point = torch.tensor([1.5, 2.0, 25.0], dtype=torch.float64)
    u = cam.fx * 1.5 / 25 + cam.cx
    v = cam.fy * 2.0 / 25 + cam.cy
    row, col = cam.project(point).tolist()
    assert row == pytest.approx(v * 256 / 2710 - 128)
    assert col == pytest.approx(u * 256 / 3384)


@settings(max_examples=50, deadline=None)
@given(
    row=st.integers(0, 127), col=st.integers(0, 255), depth=st.floats(0.5, 300.0),
)
def test_pixel_centres_backproject_into_their_pixel(row, col, depth):
    pixels = torch.tensor([[row, col]])
    point = pixel_centre_points(pixels, torch.tensor([depth], dtype=torch.float64))
    screen = APOLLO_CAMERA_5.project(point)
    assert torch.equal(torch.floor(screen).long(), pixels)
    assert torch.allclose(screen, pixels.double() + 0.5, atol=1e-9)


@pytest.mark.parametrize("z", [0.0, -3.0])
def test_points_behind_the_camera_are_rejected(z):
    with pytest.raises(SDMInputError, match="behind the camera"):
        APOLLO_CAMERA_5.project(torch.tensor([[0.0, 1.0, z]]))


def test_non_finite_points_are_rejected():
    with pytest.raises(SDMInputError, match="non-finite"):
        APOLLO_CAMERA_5.project(torch.tensor([[math.nan, 1.0, 5.0]]))


def test_camera_file_of_the_real_sample(apollo_sample):
    cam = Camera.from_file(apollo_sample / "camera" / "Camera_5.txt")
    assert cam == APOLLO_CAMERA_5


@pytest.mark.parametrize(
    "text, message",
    [("fx = 1; fy = 2; cx = 3;", "no 'cy"), ("fx = a; fy = 2; cx = 3; cy = 4;", "fx is not a number"),
     ("fx = inf; fy = 2; cx = 3; cy = 4;", "fx is not finite")],
)
def test_malformed_camera_files(tmp_path, text, message):
    path = tmp_path / "Camera_5.txt"
    path.write_text(text)
    with pytest.raises(SDMInputError, match=message) as info:
        Camera.from_file(path)
    assert str(path) in str(info.value)


def test_rmin_takes_nearest_then_smallest_value():
    cam = APOLLO_CAMERA_5
    near = pixel_centre_points(torch.tensor([[10, 20]]), torch.tensor([30.0], dtype=torch.float64))
    far = pixel_centre_points(torch.tensor([[10, 20]]), torch.tensor([40.0], dtype=torch.float64))
    points = torch.cat((far, near, near))
    image = render_rmin(points, torch.tensor([1.0, 7.0, 5.0], dtype=torch.float64), cam)
    assert image[10, 20] == 5.0 and int((image > 0).sum()) == 1
