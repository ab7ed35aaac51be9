"""ByteTrack (Zhang et al., ECCV 2022), the baseline of the paper's Table III.

Faithful to the reference implementation's association: IoU cost fused with the detection score
in the first and the unconfirmed stage, thresholds 0.8 / 0.5 / 0.7, new tracks at
``track_thresh + 0.1``, lost tracks kept for ``track_buffer`` (30 frames = 1 s at 30 Hz, here in
seconds), duplicate removal between tracked and lost tracks. Deviations: the Kalman filter works on
``[cx, cy, w, h]`` (BoT-SORT's variant, better for small boxes than ``[cx, cy, a, h]``) and uses
real elapsed time (see :mod:`.kalman`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gldt_core.track.base import MultiStageTracker, iou_pair_cost
from gldt_core.track.state import Track


@dataclass(frozen=True)
class ByteTrackConfig:
    """ByteTrack's defaults (MOT17 settings of the reference code)."""

    track_thresh: float = 0.5
    low_thresh: float = 0.1
    new_track_thresh: float = 0.6
    match_thresh: float = 0.8
    second_match_thresh: float = 0.5
    unconfirmed_thresh: float = 0.7
    fuse_score: bool = True
    track_buffer_s: float = 1.0
    ref_fps: float = 30.0
    history_len: int = 30
    image_size: tuple[int, int] = (1920, 1080)
    # Start a confirmed track from a low-score detection seen at the same place this many frames
    # running (0: off, the paper's behaviour; see gldt_core.track.birth).
    low_score_birth_frames: int = 0


class ByteTrack(MultiStageTracker):
    """``ByteTrack(config).update(dets, t) -> (M, 6) [x1, y1, x2, y2, track_id, score]``."""

    def __init__(self, config: ByteTrackConfig | None = None) -> None:
        self.config = config or ByteTrackConfig()
        c = self.config
        super().__init__(
            t_high=c.track_thresh,
            t_low=c.low_thresh,
            new_track_thresh=c.new_track_thresh,
            jcma_window_s=c.track_buffer_s,
            memory_s=c.track_buffer_s,
            ref_fps=c.ref_fps,
            history_len=c.history_len,
            image_size=c.image_size,
            low_score_birth_frames=c.low_score_birth_frames,
        )

    def _pair_cost(
        self, stage: str, tracks: Sequence[Track], dets: np.ndarray, det_idx: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, float]:
        c = self.config
        if stage == self.STAGE_HIGH:
            return iou_pair_cost(tracks, dets, det_idx, c.match_thresh, c.fuse_score)
        if stage == self.STAGE_LOW:
            return iou_pair_cost(tracks, dets, det_idx, c.second_match_thresh, False)
        return iou_pair_cost(tracks, dets, det_idx, c.unconfirmed_thresh, c.fuse_score)
