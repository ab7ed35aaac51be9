"""The multi-stage association loop shared by ByteTrack and JPTrack.

ByteTrack (Zhang et al., 2022) and JPTrack differ only in the cost of a (track, detection) pair
and in JPTrack's third, PMR stage, so both run this loop:

1. high-score detections (``score >= t_h``) vs active tracks and recently lost tracks;
2. remaining active tracks vs low-score detections (``t_l <= score < t_h``); active tracks still
   unmatched become LOST;
3. (JPTrack with PMR) lost tracks vs the remaining detections by :mod:`.pmr`;
4. tentative (one-hit) tracks vs the remaining high-score detections; unmatched tentative tracks
   are dropped (ByteTrack's "unconfirmed" step); (JPTrack) one confirmed where a lost track
   would have been at both of its sightings continues that track's identity (``_relink``);
5. remaining high-score detections with ``score >= new_track_thresh`` start tentative tracks,
   low-score ones are dropped; lost tracks older than their memory are removed.
6. (optional, ``low_score_birth_frames`` = K > 0) a remaining low-score detection that has
   reappeared at the same place in each of the last K frames starts a *confirmed* track: K
   consistent sightings confirm it as the one-hit tentative step would, but without ever needing
   a high score. With an under-confident detector, a drone it sees steadily at 0.15-0.25 would
   otherwise never get a track (see :mod:`gldt_core.track.birth`). Off by default: with the
   shipped detectors, birds come back at the same place as steadily as drones do.

Time is the caller's timestamp in seconds; nothing counts frames except ``frames_since_update``.

Three switches for ByteTrack's reference, off for JPTrack: the filter of new tracks
(``kalman``, a :class:`~gldt_core.track.kalman.KalmanModel`), the strict score split
(``strict_score_split``: high is ``score > t_h``, low ``t_l < score < t_h``, as in the reference
code; otherwise ``>=``), and whether a one-hit tentative track's filter is predicted before its
second detection is matched (``predict_tentative``; the reference predicts only the tracks of its
first-stage pool, so that match corrects the filter as it was born).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gldt_core.track.assignment import assign
from gldt_core.track.birth import LowScoreBirth
from gldt_core.track.boxes import (
    corners,
    iou_pairs_above,
    iou_xyxy,
    relative_centre,
    validate_detections,
    validate_time,
)
from gldt_core.track.fastpath import on_floats
from gldt_core.track.kalman import KalmanModel, predicted_many, stop_velocities
from gldt_core.track.state import (
    Track,
    TrackState,
    advance_tracks,
    box_rows,
    boxes_xyxy,
    update_tracks,
)

OUTPUT_STATES = (TrackState.CONFIRMED, TrackState.RECOVERED)
#: Tolerance of the lost-track windows, against floating-point time differences.
TIME_SLACK_S = 1e-9
#: How a lost track came back (``MultiStageTracker.reattachments``): matched in the first stage
#: (within the lost window), by the tracker's ``_recover`` (JPTrack's PMR), or by ``_relink``.
REATTACHED_FIRST_STAGE = "first stage"
REATTACHED_RECOVER = "PMR"
REATTACHED_RELINK = "relink"
REATTACHMENTS = (REATTACHED_FIRST_STAGE, REATTACHED_RECOVER, REATTACHED_RELINK)


class MultiStageTracker:
    """Base class: state, validation, the stage loop. Subclasses provide ``_pair_cost``."""

    #: Stage names passed to ``_pair_cost``.
    STAGE_HIGH, STAGE_LOW, STAGE_TENTATIVE = "high", "low", "tentative"

    def __init__(
        self,
        *,
        t_high: float,
        t_low: float,
        new_track_thresh: float,
        jcma_window_s: float,
        memory_s: float,
        ref_fps: float,
        history_len: int,
        image_size: tuple[int, int],
        low_score_birth_frames: int = 0,
        kalman: KalmanModel | None = None,
        strict_score_split: bool = False,
        predict_tentative: bool = True,
        coasting_stops: tuple[int, ...] = (),
    ) -> None:
        if not 0.0 <= t_low <= t_high <= 1.0:
            raise ValueError(f"need 0 <= t_l <= t_h <= 1, got t_l={t_low}, t_h={t_high}")
        if ref_fps <= 0 or memory_s < 0 or jcma_window_s < 0:
            raise ValueError("ref_fps must be > 0 and lost-track windows >= 0")
        self._t_high = t_high
        self._t_low = t_low
        self._new_thresh = new_track_thresh
        # A nanosecond of slack: a gap of exactly 30 frames at 30 fps is 1.0 s, but t = f / 30
        # makes (f + 30) / 30 - f / 30 land a rounding error above or below it depending on f.
        self._window_s = jcma_window_s + TIME_SLACK_S
        self._memory_s = max(memory_s, jcma_window_s) + TIME_SLACK_S
        self._ref_fps = ref_fps
        self._history_len = history_len
        self._image_size = (float(image_size[0]), float(image_size[1]))
        if low_score_birth_frames < 0:
            raise ValueError(f"low_score_birth_frames must be >= 0 (0: off), got {low_score_birth_frames}")
        self._low_birth = LowScoreBirth(low_score_birth_frames) if low_score_birth_frames > 0 else None
        self._kalman = kalman if kalman is not None else KalmanModel()
        self._strict_scores = strict_score_split
        self._predict_tentative = predict_tentative
        #: Velocity columns of the filter state set to 0 once a track is lost (they stay 0 until
        #: it is updated again): what of its motion a coasting box does not extrapolate.
        self._coasting_stops = coasting_stops
        #: Set to a list to record how lost tracks come back: ``(t, track_id, how)`` with ``how``
        #: one of :data:`REATTACHMENTS` (``gldt bench tracking`` splits its recoveries by it).
        self.reattachments: list[tuple[float, int, str]] | None = None
        self.reset()

    # --- public API -------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget every track; ids restart at 1 (ids are per tracker instance)."""
        self._tracks: list[Track] = []
        self._next_id = 1
        self._last_t: float | None = None
        self._updates = 0
        if self._low_birth is not None:
            self._low_birth.reset()

    @property
    def tracks(self) -> list[Track]:
        """Live tracks (tentative, confirmed, recovered and lost), oldest first."""
        return list(self._tracks)

    def predict(self, t: float) -> np.ndarray:
        """Predicted ``[x1, y1, x2, y2, track_id]`` at ``t`` of confirmed/recovered tracks and of
        lost tracks within the association window; never changes any state."""
        t = float(t)
        shown = [
            tr
            for tr in self._tracks
            if tr.state in OUTPUT_STATES or (tr.state is TrackState.LOST and t - tr.last_update_t <= self._window_s)
        ]
        means, _ = predicted_many([tr.kf for tr in shown], np.array([t - tr.kf_t for tr in shown]))
        out = np.empty((len(shown), 5))
        out[:, 0], out[:, 1], out[:, 2], out[:, 3] = corners(means[:, 0], means[:, 1], means[:, 2], means[:, 3])
        out[:, 4] = [tr.track_id for tr in shown]
        return out

    def update(
        self,
        dets: np.ndarray | None,
        t: float,
        *,
        rois: np.ndarray | None = None,
        frame: int | None = None,
    ) -> np.ndarray:
        """Process one frame: ``dets`` ``(N, 5)`` ``[x1, y1, x2, y2, score]`` px at ``t`` seconds.

        ``rois`` (optional, ``(N, 4)`` xyxy) is the detection window each detection came from (the
        local-detection ROI); ``frame`` is only used in error messages. An empty ``dets`` is a valid
        empty frame: tracks coast on their prediction. Returns ``(M, 6)``
        ``[x1, y1, x2, y2, track_id, score]`` of the confirmed/recovered tracks updated now.
        """
        t = validate_time(t, self._last_t, frame)
        dets = validate_detections(dets, t, frame)
        rois = self._checked_rois(dets, rois, t, frame)
        self._last_t = t
        first_frame = self._updates == 0
        self._updates += 1
        if self._predict_tentative:
            advance_tracks(self._tracks, t)
        else:
            advance_tracks([tr for tr in self._tracks if tr.state is not TrackState.TENTATIVE], t)
            for tr in self._tracks:
                if tr.state is TrackState.TENTATIVE:  # its filter stays as born (module docstring)
                    tr.kf_t = tr.now_t = t

        active = [tr for tr in self._tracks if tr.state in OUTPUT_STATES]
        dets, rois = self._merge_parts(dets, rois, active)
        rel = self._relative_positions(dets, rois)
        high, low = self._score_split(dets[:, 4])
        lost = [tr for tr in self._tracks if tr.state is TrackState.LOST]
        tentative = [tr for tr in self._tracks if tr.state is TrackState.TENTATIVE]
        updated: set[int] = set()

        def apply(
            tracks: Sequence[Track], det_idx: np.ndarray, pairs: list[tuple[int, int]], new_state: TrackState | None
        ) -> tuple[list[Track], np.ndarray]:
            if not pairs:  # nothing matched: everything stays (the common case for stages 2-4)
                return list(tracks), det_idx
            matched = [tracks[r] for r, _ in pairs]
            rows = [int(det_idx[c]) for _, c in pairs]
            update_tracks(matched, dets[rows, :4], dets[rows, 4], t, [rel[d] for d in rows])
            used_t = set()
            keep_d = np.ones(len(det_idx), dtype=bool)
            for tr, (r, c) in zip(matched, pairs):
                if tr.state is TrackState.LOST and self.reattachments is not None:
                    self.reattachments.append((t, tr.track_id, REATTACHED_FIRST_STAGE))
                if new_state is not None:
                    tr.state = new_state
                elif tr.state in (TrackState.LOST, TrackState.RECOVERED):
                    tr.state = TrackState.CONFIRMED
                updated.add(id(tr))
                used_t.add(r)
                keep_d[c] = False
            rest_t = [tr for i, tr in enumerate(tracks) if i not in used_t]
            return rest_t, np.asarray(det_idx, dtype=np.int64)[keep_d]

        # Stage 1: high-score detections vs active and recently lost tracks.
        pool = active + [tr for tr in lost if t - tr.last_update_t <= self._window_s]
        cost, allowed, limit = self._pair_cost(self.STAGE_HIGH, pool, dets, high, t)
        rest_pool, rest_high = apply(pool, high, assign(cost, allowed, limit), None)

        # Stage 2: remaining active tracks vs low-score detections.
        rest_active = [tr for tr in rest_pool if tr.state in OUTPUT_STATES]
        cost, allowed, limit = self._pair_cost(self.STAGE_LOW, rest_active, dets, low, t)
        still_active, rest_low = apply(rest_active, low, assign(cost, allowed, limit), None)
        for tr in still_active:
            tr.mark_lost()

        # Stage 3: memory recovery of lost tracks (JPTrack's PMR; ByteTrack has none). It runs
        # before tentative tracks claim detections: a lost track's memory outranks a one-hit track.
        lost_now = [tr for tr in self._tracks if tr.state is TrackState.LOST and id(tr) not in updated]
        rest_high, rest_low = self._recover(lost_now, dets, rest_high, rest_low, t, rel, updated)

        # Tentative tracks vs the remaining high-score detections (ByteTrack's unconfirmed step).
        cost, allowed, limit = self._pair_cost(self.STAGE_TENTATIVE, tentative, dets, rest_high, t)
        confirming = assign(cost, allowed, limit)
        # (JPTrack) a tentative track about to be confirmed may be a lost target back: it then
        # continues the lost track's identity with its own, fresh filter, and the lost track goes.
        back = self._relink([(tentative[r], int(rest_high[c])) for r, c in confirming], dets, t, updated)
        dead_tentative, rest_high = apply(tentative, rest_high, confirming, TrackState.CONFIRMED)
        for newcomer, returned in back:
            newcomer.continue_as(returned)
            if self.reattachments is not None:
                self.reattachments.append((t, newcomer.track_id, REATTACHED_RELINK))
        dead_ids = {id(tr) for tr in dead_tentative} | {id(returned) for _, returned in back}

        # New tracks from the remaining confident detections.
        for d in rest_high:
            if dets[d, 4] >= self._new_thresh:
                self._start_track(dets, int(d), t, TrackState.CONFIRMED if first_frame else TrackState.TENTATIVE, rel)
                updated.add(id(self._tracks[-1]))

        # Confirmed tracks from low-score detections seen at the same place K frames running.
        if self._low_birth is not None:
            unclaimed = np.concatenate([rest_low, [d for d in rest_high if dets[d, 4] < self._new_thresh]]).astype(
                np.int64
            )
            for d in self._low_birth.update(dets, unclaimed):
                self._start_track(dets, int(d), t, TrackState.CONFIRMED, rel)
                updated.add(id(self._tracks[-1]))

        kept = []
        for tr in self._tracks:
            if id(tr) in dead_ids:
                continue
            if id(tr) not in updated:
                tr.mark_missed()
                if tr.state is TrackState.LOST and t - tr.last_update_t > self._memory_s:
                    continue
            kept.append(tr)
        self._tracks = self._remove_duplicates(kept)
        if self._coasting_stops:
            coasting = [tr.kf for tr in self._tracks if tr.state is TrackState.LOST and tr.frames_since_update == 1]
            stop_velocities(coasting, self._coasting_stops)

        shown = [tr for tr in self._tracks if tr.state in OUTPUT_STATES and id(tr) in updated]
        if not shown:
            return np.empty((0, 6))
        return np.array(
            [(*box, float(tr.track_id), tr.score) for box, tr in zip(box_rows(shown), shown)], dtype=np.float64
        )

    def _score_split(self, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the high-score and of the low-score detections (module docstring)."""
        if self._strict_scores:
            high = (scores > self._t_high).nonzero()[0]
            low = ((scores > self._t_low) & (scores < self._t_high)).nonzero()[0]
        else:
            high = (scores >= self._t_high).nonzero()[0]  # np.flatnonzero without its wrapper
            low = ((scores >= self._t_low) & (scores < self._t_high)).nonzero()[0]
        return high, low

    # --- hooks ------------------------------------------------------------------------------
    def _pair_cost(
        self, stage: str, tracks: Sequence[Track], dets: np.ndarray, det_idx: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Cost ``(len(tracks), len(det_idx))``, the mask of pairs allowed to match and the stage's
        cost limit (see :func:`assign`)."""
        raise NotImplementedError

    def _merge_parts(
        self, dets: np.ndarray, rois: np.ndarray | None, active: list[Track]
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Before stage 1, with the ``active`` (confirmed) tracks predicted to this frame:
        detections that are parts of one tracked object, merged into one (JPTrack), with the ROIs
        they came from (``rois``, ``(N, 4)`` or None); ByteTrack takes the detections as they come."""
        return dets, rois

    def _recover(
        self,
        lost: list[Track],
        dets: np.ndarray,
        rest_high: np.ndarray,
        rest_low: np.ndarray,
        t: float,
        rel: list[tuple[float, float]],
        updated: set[int],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Stage 3; the default (ByteTrack) recovers nothing."""
        return rest_high, rest_low

    def _relink(
        self, confirming: list[tuple[Track, int]], dets: np.ndarray, t: float, updated: set[int]
    ) -> list[tuple[Track, Track]]:
        """Between stages 4 and 5: ``confirming`` are the tentative tracks about to be confirmed,
        each with its second detection. Returns ``(tentative track, lost track)`` pairs, each
        tentative track being the lost target back (it takes over the lost track's identity);
        the default (ByteTrack) finds none."""
        return []

    # --- helpers ----------------------------------------------------------------------------
    def _start_track(
        self, dets: np.ndarray, d: int, t: float, state: TrackState, rel: list[tuple[float, float]]
    ) -> None:
        """Append a new track on detection ``d``, with the next id and this tracker's filter."""
        self._tracks.append(
            Track(
                self._next_id,
                dets[d, :4],
                dets[d, 4],
                t,
                state,
                self._ref_fps,
                self._history_len,
                rel[d],
                self._kalman,
            )
        )
        self._next_id += 1

    def _relative_positions(self, dets: np.ndarray, r: np.ndarray | None) -> list[tuple[float, float]]:
        """(x_rel, y_rel) of each detection centre inside its ROI (the image when no ROI); ``r``
        as :meth:`_checked_rois` returns it, one row per detection."""
        if len(dets) == 0:
            return []
        boxes = dets[:, 0], dets[:, 1], dets[:, 2], dets[:, 3]
        if r is None:  # the image
            w, h = self._image_size
            if on_floats(len(dets)):
                return [relative_centre(x1, y1, x2, y2, 0.0, 0.0, w, h) for x1, y1, x2, y2, _ in dets.tolist()]
            x, y = relative_centre(*boxes, 0.0, 0.0, w, h)
            return list(zip(x.tolist(), y.tolist()))
        # A degenerate ROI counts as 1e-9 px wide.
        window = r[:, 0], r[:, 1], np.maximum(r[:, 2] - r[:, 0], 1e-9), np.maximum(r[:, 3] - r[:, 1], 1e-9)
        if on_floats(len(dets)):
            rows = zip(dets.tolist(), np.column_stack(window).tolist())
            return [relative_centre(*box[:4], *win) for box, win in rows]
        x, y = relative_centre(*boxes, *window)
        return list(zip(x.tolist(), y.tolist()))

    @staticmethod
    def _checked_rois(dets: np.ndarray, rois: np.ndarray | None, t: float, frame: int | None) -> np.ndarray | None:
        """``rois`` as a float array, one finite xyxy row per detection (None stays None); else
        a one-line ValueError naming the frame."""
        if rois is None:
            return None
        r = np.asarray(rois, dtype=np.float64)
        if r.shape != (len(dets), 4) or not np.all(np.isfinite(r)):
            where = f"frame {frame}" if frame is not None else f"t={t:.6f} s"
            raise ValueError(f"{where}: rois must be a finite ({len(dets)}, 4) xyxy array, got shape {r.shape}")
        return r

    def _remove_duplicates(self, tracks: list[Track]) -> list[Track]:
        """The tracks kept at the end of a frame (JPTrack; ByteTrack has the reference's rule): an
        active and a lost track on the same spot (IoU > 0.85) are one object; keep the older one."""
        active = [tr for tr in tracks if tr.state in OUTPUT_STATES]
        lost = [tr for tr in tracks if tr.state is TrackState.LOST]
        if not active or not lost:
            return tracks
        drop = set()
        for i, j in iou_pairs_above(box_rows(active), box_rows(lost), 0.85):
            a, b = active[i], lost[j]
            drop.add(id(b) if a.age_s >= b.age_s else id(a))
        return [tr for tr in tracks if id(tr) not in drop]


def iou_pair_cost(
    tracks: Sequence[Track], dets: np.ndarray, det_idx: np.ndarray, thresh: float, fuse_score: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    """ByteTrack's cost: ``1 - IoU`` (times the detection score when fused), allowed if <= thresh,
    with ``thresh`` as the limit."""
    if len(tracks) == 0 or len(det_idx) == 0:
        return np.zeros((len(tracks), len(det_idx))), np.zeros((len(tracks), len(det_idx)), dtype=bool), thresh
    boxes = boxes_xyxy(list(tracks))
    sub = dets[det_idx]
    iou = iou_xyxy(boxes, sub[:, :4])
    cost = 1.0 - iou * sub[None, :, 4] if fuse_score else 1.0 - iou
    return cost, cost <= thresh, thresh
