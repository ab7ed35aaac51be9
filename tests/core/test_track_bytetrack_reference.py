"""Our ByteTrack is the reference ByteTrack: boxmot 25.0.0's, run on the same detection streams.

boxmot is installed by scripts/setup.sh (without its torch/torchvision dependencies; the train
extra brings the CPU torch it imports). The streams are made from ground truth with the failure
modes of a real detector (gldt_core.eval.streams), so they exercise every stage: the low-score
second stage, one-hit tracks, lost tracks coming back or expiring, clutter.
"""

from __future__ import annotations

import functools
import inspect
from typing import Any

import numpy as np
import pytest
from boxmot import ByteTrack as BoxmotByteTrack
from boxmot.motion.kalman_filters.xyah import KalmanFilterXYAH

from gldt_core.eval import evaluate_many
from gldt_core.eval.streams import StreamParams, detections_from_gt, simple_multi_target_gt
from gldt_core.track import ByteTrack, ByteTrackConfig
from gldt_core.track.kalman import BYTETRACK_MODEL, ConstantVelocityKalman
from gldt_core.track.runner import track_detection_rows


class BoxmotAdapter:
    """boxmot's tracker behind our ``update(dets, t)`` (ids shifted to start at 1, like ours)."""

    def __init__(self, tracker: Any, image_size: tuple[int, int]) -> None:
        self._tracker = tracker
        self._image = np.zeros((image_size[1], image_size[0], 3), dtype=np.uint8)

    def update(self, dets: np.ndarray, t: float) -> np.ndarray:
        table = np.zeros((len(dets), 6), dtype=np.float32)  # x1 y1 x2 y2 score class
        table[:, :5] = dets[:, :5]
        out = np.asarray(self._tracker.update(table, self._image))
        if out.size == 0:
            return np.zeros((0, 6))
        return np.column_stack([out[:, :4], out[:, 4] + 1, out[:, 5]]).astype(np.float64)


#: name -> (image size, frames, fps, gt seed, detection seed, stream parameters)
STREAMS = {
    "1080p default": ((1920, 1080), 300, 30.0, 11, 1, StreamParams()),
    "1080p bursts and jitter": ((1920, 1080), 300, 30.0, 12, 2, StreamParams(jitter_frac=0.15, burst_rate=0.04)),
    "640x512 default": ((640, 512), 300, 30.0, 13, 3, StreamParams()),
    "640x512 low scores and clutter": (
        (640, 512),
        300,
        30.0,
        14,
        4,
        StreamParams(low_score_rate=0.5, fp_rate=1.0, miss_rate=0.1),
    ),
}

#: name -> (our config, boxmot's ByteTrack keyword arguments): boxmot's defaults, and the
#: reference code's MOT17 thresholds and buffer (boxmot starts new tracks at track_thresh).
CONFIGS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "boxmot defaults": ({}, {}),
    "MOT17 settings": (
        {"track_thresh": 0.5, "new_track_thresh": 0.5, "track_buffer": 30},
        {"track_thresh": 0.5, "track_buffer": 30},
    ),
}


def _sorted_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort((rows[:, 1], rows[:, 0]))]


@functools.cache
def _runs(config: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """stream name -> (gt, our track rows, boxmot's track rows)."""
    ours_kwargs, boxmot_kwargs = CONFIGS[config]
    out = {}
    for name, (size, frames, fps, gt_seed, det_seed, params) in STREAMS.items():
        gt = simple_multi_target_gt(gt_seed, frames, size, targets=4, fps=fps)
        dets = detections_from_gt(gt, det_seed, size, params)
        ours = ByteTrack(ByteTrackConfig.boxmot(image_size=size, **ours_kwargs))
        theirs = BoxmotAdapter(BoxmotByteTrack(**boxmot_kwargs), size)
        out[name] = (
            gt,
            track_detection_rows(ours, dets, fps, num_frames=frames),
            track_detection_rows(theirs, dets, fps, num_frames=frames),
        )
    return out


@pytest.mark.parametrize("config", CONFIGS)
def test_on_the_same_streams_our_bytetrack_scores_as_boxmots(config: str) -> None:
    """The issue's bar: IDSW within 5 % of boxmot's (at least 1), MOTA within 0.005."""
    runs = _runs(config)
    ours = evaluate_many({name: (gt, mine) for name, (gt, mine, _) in runs.items()})
    theirs = evaluate_many({name: (gt, other) for name, (gt, _, other) in runs.items()})
    for name in runs:
        a, b = ours["per_sequence"][name], theirs["per_sequence"][name]
        assert abs(a["IDSW"] - b["IDSW"]) <= max(1.0, 0.05 * b["IDSW"]), (name, a["IDSW"], b["IDSW"])
        assert abs(a["MOTA"] - b["MOTA"]) <= 0.005, (name, a["MOTA"], b["MOTA"])
    a, b = ours["combined"], theirs["combined"]
    assert b["IDSW"] >= 20, "the streams should make the reference switch identities"
    assert abs(a["IDSW"] - b["IDSW"]) <= max(1.0, 0.05 * b["IDSW"]), (a["IDSW"], b["IDSW"])
    assert abs(a["MOTA"] - b["MOTA"]) <= 0.005, (a["MOTA"], b["MOTA"])
    assert abs(a["IDF1"] - b["IDF1"]) <= 0.005, (a["IDF1"], b["IDF1"])


@pytest.mark.parametrize("config", CONFIGS)
def test_frame_by_frame_the_same_tracks_as_boxmot(config: str) -> None:
    """Stronger than the metrics: every frame reports the same ids at the same boxes (boxmot
    works in float32, hence the tolerance)."""
    for name, (_, mine, other) in _runs(config).items():
        mine, other = _sorted_rows(mine), _sorted_rows(other)
        assert mine.shape == other.shape, (name, mine.shape, other.shape)
        np.testing.assert_array_equal(mine[:, :2], other[:, :2], err_msg=name)
        np.testing.assert_allclose(mine[:, 2:6], other[:, 2:6], atol=0.01, err_msg=name)


def test_the_boxmot_config_is_boxmots_defaults() -> None:
    params = inspect.signature(BoxmotByteTrack.__init__).parameters
    ours = ByteTrackConfig.boxmot()
    assert ours.track_thresh == params["track_thresh"].default
    assert ours.new_track_thresh == params["track_thresh"].default  # boxmot: det_thresh = track_thresh
    assert ours.low_thresh == params["min_conf"].default
    assert ours.match_thresh == params["match_thresh"].default
    assert ours.track_buffer == params["track_buffer"].default
    assert ours.frame_rate == params["frame_rate"].default


def test_the_filter_is_the_reference_kalman_filter_xyah() -> None:
    """Step for step boxmot's KalmanFilterXYAH (one step per frame, velocities per frame) at
    30 Hz: our velocities are per second, 30 times theirs."""
    rng = np.random.default_rng(4)
    box = np.array([200.0, 150.0, 18.0, 11.0])  # cx cy w h
    ours = ConstantVelocityKalman(box, ref_fps=30.0, model=BYTETRACK_MODEL)
    ref = KalmanFilterXYAH()
    mean, cov = ref.initiate(np.array([box[0], box[1], box[2] / box[3], box[3]]))
    scale = np.array([1.0] * 4 + [30.0] * 4)
    for step in range(60):
        ours.predict(1 / 30)
        mean, cov = ref.predict(mean, cov)
        if step % 7 != 6:  # some frames without a detection
            z = np.array([200.0 + 3 * step, 150.0 - step, 18.0 + 0.1 * step, 11.0 + 0.05 * step]) + rng.normal(
                0, 0.5, 4
            )
            ours.update(z)
            mean, cov = ref.update(mean, cov, np.array([z[0], z[1], z[2] / z[3], z[3]]))
        np.testing.assert_allclose(ours.state, mean * scale, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.state_covariance, cov * np.outer(scale, scale), rtol=1e-7, atol=1e-9)


def _gap_stream(gap: int, gap2: int) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """One target, seen 10 frames, missed ``gap`` frames, seen 5, missed ``gap2``, seen 5; the
    det rows and the (first, last) frame of each seen segment."""
    segments = [(1, 10), (11 + gap, 15 + gap), (16 + gap + gap2, 20 + gap + gap2)]
    rows = [
        [f, -1, 100.0 + 3.0 * f, 200.0, 20.0, 14.0, 0.9, -1, -1, -1]
        for first, last in segments
        for f in range(first, last + 1)
    ]
    return np.array(rows), segments


@pytest.mark.parametrize("gap2", [1, 3])
@pytest.mark.parametrize("gap", [24, 25, 26, 27, 28])
def test_a_lost_track_comes_back_or_expires_as_in_the_reference(gap: int, gap2: int) -> None:
    """boxmot's buffer is 25 frames: a track missed for up to 26 frames comes back (the reference
    removes it after the 26th miss but drops it from its lost list one frame later), and one that
    came back after 26 is forgotten at once when it is lost again."""
    dets, segments = _gap_stream(gap, gap2)
    frames = segments[-1][1]
    mine = track_detection_rows(ByteTrack(ByteTrackConfig.boxmot(image_size=(640, 512))), dets, 30.0, num_frames=frames)
    other = track_detection_rows(BoxmotAdapter(BoxmotByteTrack(), (640, 512)), dets, 30.0, num_frames=frames)
    np.testing.assert_array_equal(_sorted_rows(mine)[:, :2], _sorted_rows(other)[:, :2])
    ids = [set(mine[(mine[:, 0] >= first) & (mine[:, 0] <= last), 1].astype(int)) for first, last in segments]
    assert ids[0] == {1}
    assert ids[1] == ({1} if gap <= 26 else {2})
    assert ids[2] == ({1} if gap <= 25 else {2})


def test_at_15_hz_with_its_frame_rate_the_same_tracks_as_boxmot() -> None:
    size, fps = (640, 512), 15.0
    gt = simple_multi_target_gt(21, 200, size, targets=4, fps=4 * fps)  # slow targets: 1-8 px a frame
    dets = detections_from_gt(gt, 5, size, StreamParams(jitter_frac=0.04))
    mine = track_detection_rows(ByteTrack(ByteTrackConfig.boxmot(image_size=size, frame_rate=fps)), dets, fps)
    other = track_detection_rows(BoxmotAdapter(BoxmotByteTrack(frame_rate=15), size), dets, fps)
    assert len(other) > 300
    mine, other = _sorted_rows(mine), _sorted_rows(other)
    np.testing.assert_array_equal(mine[:, :2], other[:, :2])
    np.testing.assert_allclose(mine[:, 2:6], other[:, 2:6], atol=0.01)
