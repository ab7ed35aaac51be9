"""The shipped detectors find real drones in held-out Halmstad clips (never trained on)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gldt_core.detect import DRONE_CLASS_ID, GlobalDetector, LocalDetector
from gldt_core.eval.detection_metrics import box_iou
from gldt_core.eval.halmstad_split import halmstad_split
from gldt_core.io.mot import read_mot
from gldt_core.paths import halmstad_root

ROOT = halmstad_root()
CLIPS = ("V_DRONE_004", "V_DRONE_064")

pytestmark = pytest.mark.skipif(not (ROOT / "videos").is_dir(), reason=f"needs the real Halmstad clips in {ROOT}")


def sampled_frames(clip: str, every: int = 30):
    """(previous, current, drone gt box) for every ``every``-th frame that has a drone."""
    gt = read_mot(ROOT / "gt" / f"{clip}.txt")
    cap = cv2.VideoCapture(str(ROOT / "videos" / f"{clip}.mp4"))
    previous = None
    try:
        for k in range(1, 301):
            ok, frame = cap.read()
            if not ok:
                break
            rows = gt[(gt[:, 0] == k) & (gt[:, 7] == 1)]
            if k % every == 0 and len(rows) and previous is not None:
                x, y, w, h = rows[0, 2:6]
                yield previous, frame, np.array([[x, y, x + w, y + h]])
            previous = frame
    finally:
        cap.release()


def test_clips_used_here_are_held_out() -> None:
    assert set(CLIPS) <= set(halmstad_split(ROOT)["val"])


def test_local_detector_finds_the_drone_in_an_roi_around_it() -> None:
    detector = LocalDetector(num_threads=1)  # the default threshold: 0.5 of the calibrated probability
    hits = extra = total = 0
    for clip in CLIPS:
        for _, frame, gt in sampled_frames(clip):
            cx, cy = (
                (gt[0, 0] + gt[0, 2]) / 2 + 25,
                (gt[0, 1] + gt[0, 3]) / 2 - 20,
            )  # target off-centre, as after a prediction error
            dets = detector.detect_rois(frame, np.array([[cx - 150, cy - 150, cx + 150, cy + 150]]).round())
            dets = dets[dets[:, 5] == DRONE_CLASS_ID]
            total += 1
            matched = len(dets) > 0 and box_iou(dets[:, :4], gt).max() >= 0.5
            hits += int(matched)
            extra += len(dets) - int(matched)
    assert total == 20
    # With the second stage at its default threshold: 18 of 20 and 4 second boxes (2026-12-03).
    assert hits >= 16, f"local detector found {hits}/{total} drones"
    assert extra <= 4


def test_global_detector_finds_drones_in_full_frames() -> None:
    detector = GlobalDetector(num_threads=1)  # the default threshold: 0.5 of the calibrated probability
    hits = extra = total = 0
    for clip in CLIPS:
        for previous, frame, gt in sampled_frames(clip):
            dets = detector.detect(previous, frame)
            dets = dets[dets[:, 5] == DRONE_CLASS_ID]
            total += 1
            matched = len(dets) > 0 and box_iou(dets[:, :4], gt).max() >= 0.5
            hits += int(matched)
            extra += len(dets) - int(matched)
    assert total == 20
    # The shipped CPU-trained model is far from the paper's numbers (see its model card); this
    # guards against regressions in the model, export or the runtime mapping, not a target.
    # With the second stage at its default threshold: 18 of 20 and 3 second boxes (2026-12-03).
    assert hits >= 16, f"global detector found {hits}/{total} drones"
    assert extra <= 4


def test_an_roi_of_a_small_frame_runs_at_a_smaller_side_and_finds_the_same_drones() -> None:
    """On these 640x512 clips the ROI is 142 px (Table I's 300 px of 1080 lines, scaled), 121 px at
    the local model's scale: the shipped model, whose sides are dynamic, runs it at 128 px instead
    of 256 px of mostly padding, and boxes the drones as at 256 px."""
    detector = LocalDetector(num_threads=1, second_stage=None, score_threshold=0.25)
    assert detector.batch_side([142, 143]) == 128 and detector.batch_side([300]) == detector.input_side == 256
    sides: list[int] = []
    run = detector.session.run
    detector.session.run = lambda names, feed: (sides.append(next(iter(feed.values())).shape[2]), run(names, feed))[1]

    found = {128: 0, 256: 0}
    for clip in CLIPS:
        for _, frame, gt in sampled_frames(clip):
            cx, cy = (gt[0, 0] + gt[0, 2]) / 2 + 25, (gt[0, 1] + gt[0, 3]) / 2 - 20
            roi = np.array([[cx - 71, cy - 71, cx + 71, cy + 71]]).round()
            for side in (128, 256):
                detector.batch_side = lambda _sides, side=side: side  # type: ignore[method-assign]
                dets = detector.detect_rois(frame, roi)
                found[side] += int(len(dets) > 0 and box_iou(dets[:, :4], gt).max() >= 0.5)
    assert sides == [128, 256] * 20
    assert found[256] >= 15 and found[128] >= found[256] - 1, found
