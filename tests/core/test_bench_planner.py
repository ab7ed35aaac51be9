"""``gldt bench planner``: its ground-truth judge of approach and a short run on the sample bag."""

from __future__ import annotations

import numpy as np

from gldt_core.bench.planner import _holes, truth_approaching
from gldt_core.cli import main


def box_track(object_id: int, sizes: np.ndarray) -> np.ndarray:
    frames = np.arange(1, len(sizes) + 1)
    rows = np.full((len(sizes), 10), -1.0)
    rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = frames, object_id, 100.0, 100.0
    rows[:, 4] = rows[:, 5] = sizes
    rows[:, 6], rows[:, 7] = 1, 1
    return rows


def test_ground_truth_approach_follows_the_inverse_size() -> None:
    fps = 30.0
    t = np.arange(150) / fps
    approaching = box_track(1, 10.0 / (1.0 - t / 8.0))  # TTC 8 s at the start
    receding = box_track(2, 40.0 / (1.0 + t / 3.0))
    steady = box_track(3, np.full(150, 20.0))
    brief = box_track(4, np.linspace(10.0, 30.0, 10))  # 10 frames: too little ground truth to judge
    judged = truth_approaching(np.vstack([approaching, receding, steady, brief]), fps)
    middle = range(40, 110)
    assert all(judged[(f, 1)] for f in middle)
    assert not any(judged[(f, 2)] for f in middle)
    assert not any(judged[(f, 3)] for f in middle)
    assert not any(key[1] == 4 for key in judged)


def test_holes_count_each_gap_once() -> None:
    assert _holes([3, 4, 5]) == 0
    assert _holes([3, 4, 8, 9, 12]) == 2


def test_planner_bench_runs_on_the_sample_bag(capsys) -> None:
    assert main(["bench", "planner", "--clips", "0", "--clip-frames", "60"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.strip().startswith("halmstad_v_drone_001"))
    fields = row.split()
    assert fields[1] == "60"  # frames
    assert int(fields[5]) == 0  # the planner stream has no id holes
