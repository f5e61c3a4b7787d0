import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))

#: The real ApolloCar3D sample shipped in the repository (data/apollocar3d-sample; tests needing it skip if it is removed).
APOLLO_SAMPLE = Path(__file__).resolve().parents[1] / "data" / "apollocar3d-sample"


@pytest.fixture(autouse=True)
def _single_thread():
    torch.set_num_threads(1)
    yield


@pytest.fixture(scope="session")
def apollo_sample() -> Path:
    if not (APOLLO_SAMPLE / "car_poses").is_dir():
        pytest.skip(f"real ApolloCar3D sample not found at {APOLLO_SAMPLE}")
    return APOLLO_SAMPLE


@pytest.fixture(scope="session")
def saved_set(tmp_path_factory) -> Path:
    """A 24-configuration set saved with torch.save, for the device probe's subprocesses (tests/device_probe.py)."""
    from scenes import configuration_set

    data = configuration_set(24, seed=31)
    path = tmp_path_factory.mktemp("probe") / "set.pt"
    torch.save({"points": data.points, "pixels": data.pixels, "offsets": data.offsets, "targets": data.targets}, path)
    return path


#: The fixtures that cost minutes (a run of the workflow, a touched project copy), longest first. Under
#: pytest-xdist (`make test`: ``-n 2 --dist loadfile``) a file's tests run on one worker, so each is built once.
HEAVY_FIXTURES = ("completed_run", "real_run", "touched_project")


def pytest_collection_modifyitems(config, items):
    """In an xdist worker: the files using a heavy fixture first, in that order, the others as collected, so
    that the longest chains start first (with ``--no-loadscope-reorder``, the files are handed out in this
    order). Without xdist nothing changes."""
    if not hasattr(config, "workerinput"):
        return
    rank = {}
    for item in items:
        file = item.nodeid.split("::")[0]
        heavy = [i for i, name in enumerate(HEAVY_FIXTURES) if name in item.fixturenames]
        rank[file] = min(rank.get(file, len(HEAVY_FIXTURES)), *heavy, len(HEAVY_FIXTURES))
    items.sort(key=lambda item: rank[item.nodeid.split("::")[0]])
