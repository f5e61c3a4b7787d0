"""Cost of verifying the Sky file on read (the per-array CRC-32 checks of ``SkyFile``).

Loads the 768 configurations of a default-size split (4,248 configurations, seed-0
synthetic ApolloCar3D) from one Sky file, once with ``SkyFile(path)`` (checks on,
as the workflow reads it) and once with ``SkyFile(path, checksums=False)``,
alternating, and prints the median of each and their ratio; then the same for the
stage's whole read (``load_split``: decode + the train and dev ``ConfigurationSet``).
One thread. Ratios are measured in the same run; the absolute figures are for reading only.

    python benchmarks/speed/bench_sky_verify.py [--sky results/sky/sky.bin] [--repeats 7]

Without ``--sky`` it builds the default-size file in a temporary folder first (about 15 s).
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from sdm.batch import ConfigurationSet
from sdm.experiments.data import SkyFile, build_sky_dataset, read_apollo_camera, read_apollo_folder, write_sky_file
from sdm.experiments.data import write_synthetic_apollo
from sdm.sky import SKY_SHIFT


def build_default(folder: Path) -> Path:
    """The default config's Sky file: 5,277 synthetic images, 4,248 sampled (seed 0)."""
    annotations = write_synthetic_apollo(folder / "synthetic_apollo", n_images=5277, seed=0)
    configurations = build_sky_dataset(read_apollo_folder(annotations), n_sample=4248, seed=0, progress=False)
    write_sky_file(folder / "sky.bin", configurations, SKY_SHIFT, read_apollo_camera(annotations))
    return folder / "sky.bin"


def median_ms(read, repeats: int) -> tuple[float, float]:
    """Median wall time (ms) of ``read(checksums)`` with checks off and on, alternating."""
    read(True)  # page cache warm for both
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(repeats):
        for checksums in (False, True):
            start = time.perf_counter()
            read(checksums)
            times[checksums].append(1000 * (time.perf_counter() - start))
    return statistics.median(times[False]), statistics.median(times[True])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sky", type=Path, help="an existing Sky file (default: build the default-size one)")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)  # as the workflow's jobs run; steadier timings on a shared machine
    with tempfile.TemporaryDirectory() as scratch:
        path = args.sky or build_default(Path(scratch))
        n = len(SkyFile(path))
        count = min(768, n)
        indices = np.sort(np.random.Generator(np.random.PCG64(0)).choice(n, count, replace=False)).tolist()
        n_train = count * 2 // 3

        def decode(checksums: bool) -> None:
            sky = SkyFile(path, checksums=checksums)
            [sky[i] for i in indices]

        def stage_read(checksums: bool) -> None:
            sky = SkyFile(path, checksums=checksums)
            ConfigurationSet.from_configurations([sky[i] for i in indices[:n_train]], sky.camera)
            ConfigurationSet.from_configurations([sky[i] for i in indices[n_train:]], sky.camera)

        size_mb = path.stat().st_size / 1e6
        print(f"{path}: {n} configurations, {size_mb:.1f} MB; reading {count} of them, median of {args.repeats}")
        for label, read in (("decode only", decode), ("decode + ConfigurationSets (load_split)", stage_read)):
            off, on = median_ms(read, args.repeats)
            print(f"  {label}: without checks {off:.1f} ms, with checks {on:.1f} ms, "
                  f"ratio {on / off:.3f} (+{on - off:.1f} ms)")


if __name__ == "__main__":
    main()
