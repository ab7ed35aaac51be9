"""JPTrack merges the parts of one large tracked object (a close drone boxed as two halves) into
one detection before association, so the second half does not start a second track on the same
drone; small targets and ByteTrack are left as they are."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, ByteTrackConfig, JPTrack, JPTrackConfig

FPS = 30.0


def whole(frame: int) -> np.ndarray:
    """A close drone, 140x80 px, moving right 2 px a frame."""
    x = 100.0 + 2 * frame
    return np.array([[x, 200.0, x + 140.0, 280.0, 0.9]])


def halves(frame: int, score: float = 0.8) -> np.ndarray:
    """The same drone boxed as its two halves (a little short of the whole, as detectors do)."""
    x = 100.0 + 2 * frame
    return np.array([[x + 4, 210.0, x + 72.0, 276.0, score], [x + 70.0, 208.0, x + 136.0, 274.0, score]])


def run(tracker: JPTrack | ByteTrack, frames: list[np.ndarray]) -> list[np.ndarray]:
    return [tracker.update(dets, i / FPS) for i, dets in enumerate(frames)]


def test_the_halves_of_a_large_tracked_drone_keep_its_one_track() -> None:
    frames = [whole(f) for f in range(8)] + [halves(f) for f in range(8, 16)]
    outputs = run(JPTrack(JPTrackConfig(image_size=(640, 512))), frames)
    ids = {int(row[4]) for out in outputs for row in out}
    assert ids == {1}, f"one drone, one id; got {sorted(ids)}"
    last = outputs[-1][0]
    assert last[2] - last[0] > 110, "the track keeps the whole drone's width, not a half's"


def test_without_the_merge_a_half_starts_a_second_track() -> None:
    """The failure the merge is for (and the reason the first test can fail)."""
    frames = [whole(f) for f in range(8)] + [halves(f) for f in range(8, 16)]
    outputs = run(JPTrack(JPTrackConfig(image_size=(640, 512), part_merge_min_size_px=0.0)), frames)
    assert len({int(row[4]) for out in outputs for row in out}) == 2


def test_two_small_targets_inside_a_small_track_are_not_merged() -> None:
    """Below part_merge_min_size_px (40 px) two detections near one track are two targets."""
    small = [np.array([[300.0 + f, 200.0, 330.0 + f, 220.0, 0.9]]) for f in range(8)]
    pair = [
        np.array([[300.0 + f, 200.0, 314.0 + f, 219.0, 0.9], [316.0 + f, 201.0, 330.0 + f, 220.0, 0.9]])
        for f in range(8, 12)
    ]
    outputs = run(JPTrack(JPTrackConfig(image_size=(640, 512))), small + pair)
    assert len(outputs[-1]) == 2, "both small targets are tracked"


def test_bytetrack_keeps_the_reference_behaviour() -> None:
    frames = [whole(f) for f in range(8)] + [halves(f) for f in range(8, 16)]
    outputs = run(ByteTrack(ByteTrackConfig()), frames)
    assert len({int(row[4]) for out in outputs for row in out}) == 2, "no merge in ByteTrack"


def test_a_negative_size_floor_is_refused() -> None:
    with pytest.raises(ValueError, match="part_merge_min_size_px"):
        JPTrackConfig(part_merge_min_size_px=-1.0)


def test_a_small_drone_crossing_in_front_of_a_large_one_keeps_its_own_track() -> None:
    """A second, far drone (20x14 px) passes through the large drone's box while the large one is
    boxed whole: it is one detection inside the track, not a part, so both keep their ids."""
    frames = []
    for f in range(60):
        small_x = 400.0 - 6 * f  # crosses the large drone's box (x 100+2f .. 240+2f) around frames 25-45
        frames.append(np.vstack([whole(f), [[small_x, 230.0, small_x + 20.0, 244.0, 0.85]]]))
    outputs = run(JPTrack(JPTrackConfig(image_size=(640, 512))), frames)
    assert {int(row[4]) for out in outputs for row in out} == {1, 2}, "two drones, two ids through the crossing"
    assert all(len(out) == 2 for out in outputs[2:]), "both drones are reported on every frame"


def test_the_merged_box_is_placed_in_its_roi_by_the_unions_centre() -> None:
    """PMR models where a track sits in its ROI (eq. 16): the merged detection's relative position
    is its union's centre in the ROI of its best part, not the best part's own centre."""
    roi = np.array([0.0, 100.0, 400.0, 400.0])
    tracker = JPTrack(JPTrackConfig(image_size=(640, 512)))
    for f in range(8):
        tracker.update(whole(f), f / FPS, rois=roi[None])
    parts = halves(8)
    parts[1, 4] = 0.85  # the right half is the best part
    tracker.update(parts, 8 / FPS, rois=np.vstack([roi, roi]))
    (track,) = tracker.tracks
    x_rel, y_rel = track.history[-1][3], track.history[-1][4]
    union_x, union_y = (parts[0, 0] + parts[1, 2]) / 2, (parts[1, 1] + parts[0, 3]) / 2
    assert x_rel == pytest.approx((union_x - roi[0]) / (roi[2] - roi[0]))
    assert y_rel == pytest.approx((union_y - roi[1]) / (roi[3] - roi[1]))
