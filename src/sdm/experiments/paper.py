"""The paper's published numbers, in one place (docs/method/paper.md, The paper's published numbers).

Tables 1 and 2, the experiment's sizes and the data statistics the paper gives. The data layer
(calibration of the synthetic default) and the report (our numbers beside the paper's) both read
them from here. Distances are in units of 1e-3 m (the paper's Table 2 unit), "Avg. Dist." in millimetres.
"""
from __future__ import annotations

#: ApolloCar3D: over 60K cars on 5,277 images (paper, section 3).
PAPER_CARS_PER_IMAGE = 11.4
#: Mean depth (m) of the Sky target points that reproduces Table 2's "Avg. Dist." (docs/method/paper.md, Experiments).
PAPER_TARGET_DEPTH = 50.95
#: Table 2's "Avg. Dist." column, millimetres, per noise level.
PAPER_AVG_DIST_MM = {1: 283.4, 2: 494.6, 3: 699.8, 4: 904.8}

#: Table 1: dev loss (mean false-positive pixels) per (n_epoch, learning rate).
TABLE1: dict[tuple[int, float], float] = {
    (1, 1e-4): 6.703,
    (1, 3e-4): 0.930,
    (1, 1e-3): 1.004,
    (2, 1e-4): 1.355,
    (2, 3e-4): 0.957,
    (2, 1e-3): 1.227,
}

#: The paper's pick: n_epoch = 1, lr = 3e-4.
TABLE1_BEST: tuple[int, float] = (1, 3e-4)

#: Table 2: per noise level, "Avg. Dist." (mm) and the mean, std, Q1, Q2, Q3 of 60 distances (1e-3 m).
TABLE2: dict[int, dict[str, float]] = {
    0: {"avg_dist": 0.0, "mean": 0.682, "std": 0.349, "q1": 0.410, "q2": 0.677, "q3": 0.915},
    1: {"avg_dist": PAPER_AVG_DIST_MM[1], "mean": 16.340, "std": 3.528, "q1": 13.525, "q2": 15.623, "q3": 19.270},
    2: {"avg_dist": PAPER_AVG_DIST_MM[2], "mean": 24.972, "std": 3.313, "q1": 22.794, "q2": 24.817, "q3": 27.642},
    3: {"avg_dist": PAPER_AVG_DIST_MM[3], "mean": 35.427, "std": 5.462, "q1": 30.867, "q2": 35.361, "q3": 39.371},
    4: {"avg_dist": PAPER_AVG_DIST_MM[4], "mean": 40.056, "std": 7.220, "q1": 36.594, "q2": 40.675, "q3": 43.795},
}

#: Runs per noise level in the paper.
RUNS_PER_LEVEL = 60

#: The experiment's sizes (paper, sections 3 and 5).
N_IMAGES_APOLLO = 5277
N_SKY = 4248
N_SELECTED, N_TRAIN, N_DEV = 768, 512, 256

__all__ = [
    "TABLE1", "TABLE1_BEST", "TABLE2", "RUNS_PER_LEVEL", "N_IMAGES_APOLLO", "N_SKY", "N_SELECTED", "N_TRAIN",
    "N_DEV", "PAPER_AVG_DIST_MM", "PAPER_CARS_PER_IMAGE", "PAPER_TARGET_DEPTH",
]
