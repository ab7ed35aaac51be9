"""Properties of the ground truth that must hold for every scene (hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gldt_core.sim import scene_ground_truth


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    frames=st.integers(1, 40),
    width=st.integers(64, 1920),
    height=st.integers(64, 1080),
    targets=st.integers(0, 5),
)
def test_ground_truth_is_valid_for_any_scene(seed: int, frames: int, width: int, height: int, targets: int) -> None:
    gt = scene_ground_truth(seed=seed, frames=frames, size=(width, height), targets=targets)
    assert gt.shape[1] == 10
    if len(gt) == 0:
        return
    assert np.all((gt[:, 0] >= 1) & (gt[:, 0] <= frames))
    assert np.all(gt[:, 4] >= 0.99) and np.all(gt[:, 5] >= 0.99)
    assert np.all(gt[:, 2] >= 0) and np.all(gt[:, 3] >= 0)
    assert np.all(gt[:, 2] + gt[:, 4] <= width + 0.011) and np.all(gt[:, 3] + gt[:, 5] <= height + 0.011)
    assert np.all((gt[:, 8] >= 0) & (gt[:, 8] <= 1))
    drones = gt[gt[:, 7] == 1]
    assert np.all((drones[:, 1] >= 1) & (drones[:, 1] <= targets))
    assert np.all(gt[gt[:, 7] == 2][:, 1] >= 1001)
    assert np.all(np.diff(gt[:, 0]) >= 0)
    again = scene_ground_truth(seed=seed, frames=frames, size=(width, height), targets=targets)
    assert np.array_equal(gt, again)
