"""The car files' writer (records_json) writes what json.dumps(indent=4, sort_keys=True) writes."""
import json

import numpy as np
import pytest

from sdm.experiments.data.scene import DEFAULT_MODEL, draw_image
from sdm.experiments.data.synthetic import APOLLO_CAMERA_5, car_records, image_rng, records_json


def reference(records) -> str:
    return json.dumps(records, indent=4, sort_keys=True)


def test_the_generated_images_are_written_as_json_writes_them():
    """200 images of the default scene (with their empty ones and every number json writes) to the character."""
    cars_seen = 0
    for index in range(200):
        rng = image_rng(0, index)
        records = car_records(draw_image(rng, DEFAULT_MODEL, APOLLO_CAMERA_5), rng)
        cars_seen += len(records)
        assert records_json(records) == reference(records)
    assert cars_seen > 1000


@pytest.mark.parametrize("records", [
    [],
    [{"area": 0, "car_id": 78, "pose": [-0.0, 0.0, 1e-06, -1e-07, 123456.789012, 5e-324], "visible_rate": 1.0}],
    [{"area": -3, "car_id": 0, "pose": [1.5, 2.0, 3.0, 4.0, 5.0, 6.0], "visible_rate": 0.1},
     {"area": 10**20, "car_id": 1, "pose": [1e300, -1e-300, 0.1, 0.2, 0.3, 0.30000000000000004], "visible_rate": 0.5}],
])
def test_edge_values_are_written_as_json_writes_them(records):
    assert records_json(records) == reference(records)


@pytest.mark.parametrize("records", [
    [{"area": 1, "car_id": 2, "pose": [float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0], "visible_rate": 0.5}],
    [{"area": 1, "car_id": 2, "pose": [0.0] * 6, "visible_rate": float("inf")}],
    [{"area": 1, "car_id": 2, "pose": [0.0] * 5, "visible_rate": 0.5}],
    [{"area": 1.0, "car_id": 2, "pose": [0.0] * 6, "visible_rate": 0.5}],
    [{"area": True, "car_id": 2, "pose": [0.0] * 6, "visible_rate": 0.5}],
    [{"area": 1, "car_id": 2, "pose": [0.0] * 6, "visible_rate": 0.5, "extra": "x"}],
    [{"car_id": 2, "pose": [0.0] * 6, "visible_rate": 0.5}],
    [{"area": 1, "car_id": 2, "pose": (0.0,) * 6, "visible_rate": 0.5}],
    [{"area": np.int64(1), "car_id": 2, "pose": [0.0] * 6, "visible_rate": 0.5}],
])
def test_records_of_another_form_are_handed_to_json(records):
    """NaN, infinity, a short pose, a float or bool area, an extra or missing key, a tuple: json.dumps writes them
    (or refuses them) itself."""
    try:
        expected = reference(records)
    except TypeError as error:  # numpy integers are not JSON serialisable
        with pytest.raises(TypeError, match=str(error)[:20]):
            records_json(records)
        return
    assert records_json(records) == expected
