"""Synthetic scenes: determinism, random access, ground truth agreeing with the drawn pixels."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.sim import SceneRenderer, SceneSpec, render_scene, scene_ground_truth
from gldt_core.sim.scene_geometry import SceneGeometry

SMALL = (480, 270)


def _diff(renderer: SceneRenderer, frame: int) -> np.ndarray:
    drawn = renderer.render(frame).astype(np.int16)
    empty = renderer.render(frame, draw_objects=False).astype(np.int16)
    return np.abs(drawn - empty).max(axis=2)


def test_same_seed_gives_identical_bytes_and_other_seed_differs() -> None:
    spec = SceneSpec(seed=7, frames=4, size=SMALL, targets=2)
    first = [image.tobytes() for image, _ in SceneRenderer(spec)]
    second = [image.tobytes() for image, _ in SceneRenderer(spec)]
    assert first == second
    other = SceneRenderer(spec.with_(seed=8)).render(0)
    assert other.tobytes() != first[0]


def test_frame_k_renders_alone_exactly_as_in_sequence() -> None:
    spec = SceneSpec(seed=3, frames=12, size=SMALL, targets=3)
    sequential = list(SceneRenderer(spec))
    alone = SceneRenderer(spec)
    for frame in (11, 4, 0):
        image, rows = alone.render_with_truth(frame)
        assert np.array_equal(image, sequential[frame][0])
        assert np.array_equal(rows, sequential[frame][1])


def test_scene_ground_truth_equals_rendered_ground_truth() -> None:
    kwargs = dict(seed=5, frames=20, size=SMALL, targets=3)
    fast = scene_ground_truth(**kwargs)
    renderer = SceneRenderer(SceneSpec(**kwargs))
    rendered = np.concatenate([rows for _, rows in renderer if len(rows)])
    assert np.array_equal(fast, rendered)
    frames, gt = render_scene(**kwargs)
    assert np.array_equal(gt, fast)
    assert len(frames) == 20
    assert np.array_equal(frames[7], renderer.render(7))
    assert np.array_equal(frames[-1], renderer.render(19))
    assert len(frames[2:5]) == 3
    with pytest.raises(IndexError):
        frames[20]


def test_ground_truth_layout_ids_classes_and_ranges() -> None:
    gt = scene_ground_truth(seed=11, frames=120, size=(1920, 1080), targets=3, birds=2)
    assert gt.shape[1] == 10
    assert set(np.unique(gt[:, 7])) <= {1.0, 2.0}
    drones, birds = gt[gt[:, 7] == 1], gt[gt[:, 7] == 2]
    assert set(np.unique(drones[:, 1])) <= {1.0, 2.0, 3.0}
    assert len(birds) > 0 and birds[:, 1].min() >= 1001
    assert gt[:, 0].min() >= 1 and gt[:, 0].max() <= 120
    assert np.all(gt[:, 2] >= 0) and np.all(gt[:, 3] >= 0)
    assert np.all(gt[:, 2] + gt[:, 4] <= 1920 + 1e-6) and np.all(gt[:, 3] + gt[:, 5] <= 1080 + 1e-6)
    assert np.all((gt[:, 8] >= 0) & (gt[:, 8] <= 1))
    assert np.all(gt[:, 6] == 1) and np.all(gt[:, 9] == -1)
    # One (frame, id) pair per row.
    pairs = {(int(f), int(i)) for f, i in gt[:, :2]}
    assert len(pairs) == len(gt)


def test_target_spans_respect_the_requested_range() -> None:
    gt = scene_ground_truth(seed=2, frames=60, targets=3, birds=0, target_size=(4.0, 10.0))
    inside = gt[gt[:, 8] > 0.99]  # fully in view and unoccluded: box is the whole airframe
    assert len(inside) > 0
    # The span is the larger side of the airframe at level attitude; any pose fits within it.
    assert inside[:, 4].max() <= 10.0 * 1.05


@pytest.mark.parametrize("seed", [0, 4, 9, 21])
def test_boxes_lie_on_drawn_pixels_and_nothing_is_drawn_elsewhere(seed: int) -> None:
    spec = SceneSpec(seed=seed, frames=40, size=(960, 540), targets=3, target_size=(5.0, 40.0))
    renderer = SceneRenderer(spec)
    checked = 0
    for frame in (0, 13, 39):
        diff = _diff(renderer, frame)
        rows = renderer.ground_truth(frame)
        covered = np.zeros_like(diff, dtype=bool)
        for row in rows:
            x, y, w, h = row[2:6]
            pad = int(max(8, 0.6 * max(w, h)))
            covered[max(0, int(y) - pad) : int(y + h) + pad + 1, max(0, int(x) - pad) : int(x + w) + pad + 1] = True
            if row[8] >= 0.5:
                box = diff[int(y) : int(np.ceil(y + h)) + 1, int(x) : int(np.ceil(x + w)) + 1]
                assert box.max() >= 6, f"seed {seed} frame {frame} id {int(row[1])}: nothing drawn in box"
                checked += 1
        # Objects leaving the view by less than a pixel are drawn but not in gt: skip the border.
        inner = np.zeros_like(covered)
        inner[4:-4, 4:-4] = True
        assert not np.any(diff[inner & ~covered] > 0), f"seed {seed} frame {frame}: pixels drawn outside gt"
    assert checked > 0


def test_cloud_occlusion_lowers_visibility_and_fades_the_pixels() -> None:
    found = None
    for seed in range(60):
        geometry = SceneGeometry(SceneSpec(seed=seed, frames=90, size=(960, 540), targets=3))
        for frame in range(0, 90, 3):
            for state in geometry.objects(frame):
                inside = state.box[0] >= 0 and state.box[1] >= 0 and state.box[2] <= 960 and state.box[3] <= 540
                if state.class_id == 1 and inside and 0.3 < state.occlusion < 0.95:
                    found = (seed, frame, state)
                    break
            if found:
                break
        if found:
            break
    assert found is not None, "no cloud-occluded target in 60 seeds"
    seed, frame, state = found
    assert state.visibility == pytest.approx(1 - state.occlusion)
    rows = SceneRenderer(SceneSpec(seed=seed, frames=90, size=(960, 540), targets=3)).ground_truth(frame)
    row = rows[rows[:, 1] == state.track_id][0]
    assert row[8] == pytest.approx(round(1 - state.occlusion, 3))


def test_ego_motion_moves_background_and_ground_truth_together() -> None:
    geometry = SceneGeometry(SceneSpec(seed=1, frames=200, size=SMALL, targets=1))
    camera = geometry.camera
    assert np.ptp(camera[:, 0]) + np.ptp(camera[:, 1]) > 0, "camera never moves"
    margin = geometry.style.margin
    assert np.all(np.abs(camera[:, 0]) <= margin[0]) and np.all(np.abs(camera[:, 1]) <= margin[1])
    track = geometry.targets[0]
    for frame in (0, 100, 199):
        for state in geometry.objects(frame):
            if state.track_id == 1:
                assert np.allclose(state.centre, track.centre[frame] - camera[frame])


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(frames=0), "frames"),
        (dict(size=(20, 20)), "too small"),
        (dict(target_size=(10.0, 400.0), size=(640, 480)), "bigger than half the frame"),
        (dict(target_size=(10.0, 5.0)), "target_size"),
        (dict(targets=-1), "targets"),
        (dict(fps=0.0), "fps"),
        (dict(seed=-3), "seed"),
    ],
)
def test_impossible_specs_raise_value_errors_naming_the_field(fields: dict, message: str) -> None:
    base = dict(seed=1, frames=10)
    base.update(fields)
    with pytest.raises(ValueError, match=message):
        SceneSpec(**base)


def test_render_rejects_frames_outside_the_scene() -> None:
    renderer = SceneRenderer(SceneSpec(seed=1, frames=5, size=SMALL))
    with pytest.raises(ValueError, match="out of range"):
        renderer.render(5)


def test_jpeg_quality_adds_compression_artefacts() -> None:
    spec = SceneSpec(seed=2, frames=2, size=SMALL, targets=2)
    clean = SceneRenderer(spec).render(1).astype(np.int16)
    compressed = SceneRenderer(spec.with_(jpeg_quality=40)).render(1).astype(np.int16)
    assert 0.3 < np.abs(clean - compressed).mean() < 10


def test_camera_matrix_matches_the_field_of_view() -> None:
    renderer = SceneRenderer(SceneSpec(seed=4, frames=2, size=(1920, 1080)))
    k = renderer.camera_matrix()
    hfov = 2 * np.degrees(np.arctan(960 / k[0, 0]))
    assert hfov == pytest.approx(renderer.style.hfov_deg)
    assert k[0, 2] == pytest.approx(959.5) and k[1, 2] == pytest.approx(539.5)


def test_targets_behind_the_skyline_are_hidden_pixel_by_pixel() -> None:
    for seed in range(80):
        spec = SceneSpec(seed=seed, frames=150, size=(640, 360), targets=3, birds=0)
        geometry = SceneGeometry(spec)
        if not any(t.behind_terrain for t in geometry.targets):
            continue
        for frame in range(150):
            for state in geometry.objects(frame):
                if state.track.behind_terrain and 0.15 < state.visibility < 0.85 and state.occlusion == 0:
                    renderer = SceneRenderer(spec)
                    diff = _diff(renderer, frame)
                    margin_x, margin_y = geometry.style.margin
                    offset = geometry.camera[frame]
                    rows, cols = np.nonzero(diff > 2)
                    canvas_rows = rows + offset[1] + margin_y
                    canvas_cols = np.clip(cols + offset[0] + margin_x, 0, len(geometry.ridge) - 1)
                    below = canvas_rows > geometry.ridge[canvas_cols] + 1.5
                    assert len(rows) > 0
                    assert not np.any(below), f"seed {seed} frame {frame}: drawn below the skyline"
                    return
    pytest.fail("no partly terrain-hidden target found in 80 seeds")
