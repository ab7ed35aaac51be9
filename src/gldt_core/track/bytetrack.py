"""ByteTrack (Zhang et al., ECCV 2022), the baseline of the paper's Table III.

The reference implementation's behaviour, checked against boxmot 25.0.0's ``ByteTrack`` on the
same detection streams (``tests/core/test_track_bytetrack_reference.py``):

* the Kalman filter on ``[cx, cy, a, h]`` with noise proportional to the height and a nearly
  fixed aspect ratio, no pixel floors (:data:`~gldt_core.track.kalman.BYTETRACK_MODEL`);
* the score split ``score > track_thresh`` (first stage) and ``low_thresh < score <
  track_thresh`` (second stage); new tracks from the remaining first-stage detections with
  ``score >= new_track_thresh``;
* IoU cost fused with the detection score in the first and the unconfirmed stage, plain IoU in
  the second; thresholds 0.8 / 0.5 / 0.7; matching as ``lap.lapjv`` with a cost limit;
* a new track is confirmed by a second detection in the next frame (else dropped), except on the
  first frame, where every new track is confirmed at once; its filter is not predicted before
  that second detection (only the first stage's pool is);
* a lost track keeps its box size while it coasts (the height's velocity is set to 0). Once more
  than ``track_buffer`` frames (scaled by ``frame_rate / 30``) have passed since its last
  detection it is removed, but the reference takes removed tracks out of its lost list only a
  frame later, so the first stage still matches it then: it comes back up to ``track_buffer + 2``
  frames after its last detection. A track that came back that way is forgotten at once the
  next time it is lost (its id is on the removed list);
* duplicates: a tracked (or new) and a lost track with IoU > 0.85 are one object; the one
  tracked for longer (first to last detection) stays, the lost one on a tie;
* the output: the confirmed tracks updated by this frame's detections, at their filtered boxes.

One deviation: time. The reference counts frames (one prediction per frame, the buffer in
frames); here the filter steps by the elapsed time and the buffer counts ``1 / frame_rate``
periods since the last detection, the same thing at a constant ``frame_rate`` and still right
when frames are dropped (see :mod:`.kalman`).

The defaults are the reference code's MOT17 settings; :meth:`ByteTrackConfig.boxmot` gives
boxmot 25.0.0's (``track_thresh`` 0.45, new tracks from 0.45, a 25-frame buffer).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gldt_core.track.base import TIME_SLACK_S, MultiStageTracker, iou_pair_cost
from gldt_core.track.boxes import iou_pairs_above
from gldt_core.track.kalman import BYTETRACK_MODEL
from gldt_core.track.state import Track, TrackState, box_rows

#: IoU above which a tracked and a lost track are the same object (reference: IoU distance < 0.15).
DUPLICATE_IOU = 0.85


@dataclass(frozen=True)
class ByteTrackConfig:
    """ByteTrack's parameters: the reference code's MOT17 settings (boxmot 25.0.0's name and
    default in brackets where they differ; :meth:`boxmot`)."""

    # First-stage detections: score > track_thresh (boxmot: track_thresh, 0.45).
    track_thresh: float = 0.5
    # Second-stage detections: low_thresh < score < track_thresh (boxmot: min_conf).
    low_thresh: float = 0.1
    # New tracks from first-stage detections left over with score >= new_track_thresh: the
    # reference code's track_thresh + 0.1 (boxmot: det_thresh = track_thresh, 0.45).
    new_track_thresh: float = 0.6
    # Largest cost (1 - IoU, times the score when fused) of a match: first stage (boxmot:
    # match_thresh), second stage, unconfirmed stage (both fixed in the reference code).
    match_thresh: float = 0.8
    second_match_thresh: float = 0.5
    unconfirmed_thresh: float = 0.7
    # Fuse the detection score into the first- and unconfirmed-stage cost (the reference's
    # MOT17 setting; off only with its mot20 switch; always on in boxmot).
    fuse_score: bool = True
    # Frames of misses a lost track survives, at 30 fps (boxmot: 25); scaled by frame_rate / 30.
    track_buffer: int = 30
    # The stream's frame rate: the buffer's scale, and the Kalman filter's reference step
    # (one step of the reference's noise per 1 / frame_rate seconds).
    frame_rate: float = 30.0
    history_len: int = 30
    image_size: tuple[int, int] = (1920, 1080)
    # Start a confirmed track from a low-score detection seen at the same place this many frames
    # running (0: off, the paper's behaviour; see gldt_core.track.birth).
    low_score_birth_frames: int = 0

    @classmethod
    def boxmot(cls, **changes: Any) -> ByteTrackConfig:
        """boxmot 25.0.0's ``ByteTrack()`` defaults, then ``changes``."""
        return replace(cls(track_thresh=0.45, new_track_thresh=0.45, track_buffer=25), **changes)

    @property
    def buffer_frames(self) -> int:
        """The buffer in frames at ``frame_rate``, as the reference rounds it."""
        return int(self.frame_rate / 30.0 * self.track_buffer)

    @property
    def removed_after_s(self) -> float:
        """Time since its last detection after which a lost track is removed: the reference
        removes it at the first frame more than ``buffer_frames`` frames later."""
        return (self.buffer_frames + 1) / self.frame_rate

    @property
    def lost_window_s(self) -> float:
        """How long after its last detection a lost track can still be matched: one frame more
        than :attr:`removed_after_s` (the reference's lost list keeps a removed track until the
        end of the next frame)."""
        return (self.buffer_frames + 2) / self.frame_rate


class ByteTrack(MultiStageTracker):
    """``ByteTrack(config).update(dets, t) -> (M, 6) [x1, y1, x2, y2, track_id, score]``."""

    def __init__(self, config: ByteTrackConfig | None = None) -> None:
        self.config = config or ByteTrackConfig()
        c = self.config
        if c.frame_rate <= 0 or c.track_buffer < 0:
            raise ValueError(f"need frame_rate > 0 and track_buffer >= 0, got {c.frame_rate}, {c.track_buffer}")
        super().__init__(
            t_high=c.track_thresh,
            t_low=c.low_thresh,
            new_track_thresh=c.new_track_thresh,
            jcma_window_s=c.lost_window_s,
            memory_s=c.lost_window_s,
            ref_fps=c.frame_rate,
            history_len=c.history_len,
            image_size=c.image_size,
            low_score_birth_frames=c.low_score_birth_frames,
            kalman=BYTETRACK_MODEL,
            strict_score_split=True,
            predict_tentative=False,
            coasting_stops=(7,),  # a lost box keeps its height (the reference's prediction of lost tracks)
        )

    def reset(self) -> None:
        super().reset()
        #: Ids of the tracks that came back after they were removed (class docstring).
        self._removed_ids: set[int] = set()

    def update(
        self,
        dets: np.ndarray | None,
        t: float,
        *,
        rois: np.ndarray | None = None,
        frame: int | None = None,
    ) -> np.ndarray:
        lost = [(tr, tr.last_update_t) for tr in self._tracks if tr.state is TrackState.LOST]
        out = super().update(dets, t, rois=rois, frame=frame)
        removed_after = self.config.removed_after_s + TIME_SLACK_S
        self._removed_ids.update(
            tr.track_id
            for tr, last in lost
            if tr.state is not TrackState.LOST and tr.last_update_t - last > removed_after  # back after removal
        )
        return out

    def _pair_cost(
        self, stage: str, tracks: Sequence[Track], dets: np.ndarray, det_idx: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, float]:
        c = self.config
        if stage == self.STAGE_HIGH:
            return iou_pair_cost(tracks, dets, det_idx, c.match_thresh, c.fuse_score)
        if stage == self.STAGE_LOW:
            return iou_pair_cost(tracks, dets, det_idx, c.second_match_thresh, False)
        return iou_pair_cost(tracks, dets, det_idx, c.unconfirmed_thresh, c.fuse_score)

    def _remove_duplicates(self, tracks: list[Track]) -> list[Track]:
        """The reference's end of a frame: its lost list loses the tracks removed before (lost
        for more than :attr:`ByteTrackConfig.removed_after_s`, or lost again after coming back
        from removal), then remove_duplicate_stracks: a tracked track (new ones included) and a
        lost one with IoU > 0.85 are one object; the one tracked for longer (first to last
        detection) stays, the lost one on a tie."""
        removed_after = self.config.removed_after_s + TIME_SLACK_S
        tracks = [
            tr
            for tr in tracks
            if tr.state is not TrackState.LOST
            or (tr.now_t - tr.last_update_t <= removed_after and tr.track_id not in self._removed_ids)
        ]
        if self._removed_ids:  # only live tracks' ids matter
            self._removed_ids &= {tr.track_id for tr in tracks}
        tracked = [tr for tr in tracks if tr.state is not TrackState.LOST]
        lost = [tr for tr in tracks if tr.state is TrackState.LOST]
        if not tracked or not lost:
            return tracks
        drop = set()
        for i, j in iou_pairs_above(box_rows(tracked), box_rows(lost), DUPLICATE_IOU):
            a, b = tracked[i], lost[j]
            a_span, b_span = a.last_update_t - a.start_t, b.last_update_t - b.start_t
            drop.add(id(b) if a_span > b_span + TIME_SLACK_S else id(a))
        return [tr for tr in tracks if id(tr) not in drop]
