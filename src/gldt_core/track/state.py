"""Track objects shared by ByteTrack and JPTrack: a Kalman filter plus the memory PMR needs."""

from __future__ import annotations

import enum
from collections import deque

import numpy as np

from gldt_core.track.boxes import centre_size, corners
from gldt_core.track.fastpath import on_floats
from gldt_core.track.kalman import ConstantVelocityKalman, KalmanModel, predict_many, update_many
from gldt_core.track.pmr import PmrModel


class TrackState(enum.Enum):
    """Life cycle: TENTATIVE until a second hit, CONFIRMED while matched, LOST while coasting,
    RECOVERED on the frame PMR brings a lost track back (CONFIRMED again at its next match)."""

    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    LOST = "lost"
    RECOVERED = "recovered"


#: Observations averaged into JCMA's historical velocity ``v_avg``.
MOTION_WINDOW = 10

#: One history sample: t, cx, cy, x_rel, y_rel, vx, vy (px/s from the filter), w, h.
HISTORY_FIELDS = ("t", "cx", "cy", "x_rel", "y_rel", "vx", "vy", "w", "h")


class Track:
    """A tracked object. Box, velocity and covariance come from the Kalman filter at the time of
    the last ``update`` call of the owning tracker (``now_t``)."""

    def __init__(
        self,
        track_id: int,
        box_xyxy: np.ndarray,
        score: float,
        t: float,
        state: TrackState,
        ref_fps: float,
        history_len: int,
        rel_xy: tuple[float, float],
        kalman: KalmanModel | None = None,
    ) -> None:
        self.track_id = int(track_id)
        self.state = state
        x1, y1, x2, y2 = np.asarray(box_xyxy, dtype=np.float64)[:4].tolist()
        cx, cy, w, h = centre_size(x1, y1, x2, y2)
        self.kf = ConstantVelocityKalman(np.array([cx, cy, w, h]), ref_fps, kalman)
        self.kf_t = float(t)
        self.score = float(score)
        self.hits = 1
        self.frames_since_update = 0
        self.start_t = float(t)
        self.last_update_t = float(t)
        self.now_t = float(t)
        self.lost_since_t: float | None = None
        #: Observed centres (cx, cy) and KF velocities at each update, newest last.
        self.history: deque[tuple[float, ...]] = deque(maxlen=history_len)
        #: Last observed centre ``(cx, cy)`` as Python floats (see ``last_obs_cxcy``).
        self.last_obs_xy: tuple[float, float] = (cx, cy)
        #: Last observed box size ``(w, h)`` px (the detection's; looming TTC measures it).
        self.last_obs_wh: tuple[float, float] = (w, h)
        self._recent_v: deque[tuple[float, float]] = deque()
        self._v_sum = [0.0, 0.0]
        self._record(t, rel_xy)
        #: Cached PMR mixture, fitted lazily once the track is lost (see pmr.py).
        self.pmr_model: PmrModel | None = None

    def continue_as(self, lost: Track) -> None:
        """Take over the identity of ``lost`` (its id and start), which this track has been found
        to be: the target back after a gap. This track keeps its own filter and history, fitted
        to where the target is now; it is reported as RECOVERED."""
        self.track_id = lost.track_id
        self.start_t = lost.start_t
        self.state = TrackState.RECOVERED

    # --- public read-only view -------------------------------------------------------------
    @property
    def box_xyxy(self) -> np.ndarray:
        """Filtered box ``[x1, y1, x2, y2]`` at ``now_t`` (a prediction while lost)."""
        return np.array(box_row(self))

    @property
    def velocity_px_s(self) -> np.ndarray:
        """Velocity ``(vx, vy)`` of the box centre in px/s."""
        return self.kf.mean[4:6].copy()

    @property
    def covariance(self) -> np.ndarray:
        """8x8 covariance of the Kalman state ``[cx, cy, w, h, vcx, vcy, vw, vh]``."""
        return self.kf.covariance.copy()

    @property
    def last_obs_cxcy(self) -> np.ndarray:
        """Last observed centre ``[cx, cy]`` (the detection's, not the filter's)."""
        return np.array(self.last_obs_xy)

    @property
    def age_s(self) -> float:
        """Seconds since the track was born."""
        return self.now_t - self.start_t

    @property
    def is_active(self) -> bool:
        return self.state in (TrackState.CONFIRMED, TrackState.RECOVERED)

    # --- used by the trackers -------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Predict the filter forward to ``t`` (called once per tracker update)."""
        self.kf.predict(t - self.kf_t)
        self.kf_t = t
        self.now_t = t

    def predicted_xyxy(self, t: float) -> np.ndarray:
        """Box predicted at ``t`` without changing the filter."""
        mean, _ = self.kf.predicted(t - self.kf_t)
        return np.array(corners(*mean[:4].tolist()))

    def _record_update(
        self, x1: float, y1: float, x2: float, y2: float, score: float, t: float, rel_xy: tuple[float, float]
    ) -> None:
        """The bookkeeping of a matched detection ``x1..y2`` at ``t``, after the filter has fused it
        (:func:`update_tracks` does both: the one way to update a track)."""
        cx, cy, w, h = centre_size(x1, y1, x2, y2)
        self.last_obs_xy = (cx, cy)
        self.last_obs_wh = (w, h)
        self.score = score
        self.hits += 1
        self.frames_since_update = 0
        self.last_update_t = t
        self.lost_since_t = None
        self.pmr_model = None
        self._record(t, rel_xy)

    def mark_missed(self) -> None:
        self.frames_since_update += 1

    def mark_lost(self) -> None:
        """Lost: the box coasts with the filter's velocities. The trackers then stop the size's
        velocities they do not trust: ByteTrack the height's, as its reference does; JPTrack both
        sides' (a noisy size rate swells or collapses a box coasted for seconds; see
        :mod:`gldt_core.track.jptrack`)."""
        if self.state is not TrackState.LOST:
            self.state = TrackState.LOST
            self.lost_since_t = self.last_update_t

    def _record(self, t: float, rel_xy: tuple[float, float]) -> None:
        cx, cy, w, h, vx, vy = self.kf.mean[:6].tolist()
        obs_x, obs_y = self.last_obs_xy
        self.history.append((t, obs_x, obs_y, rel_xy[0], rel_xy[1], vx, vy, w, h))
        # Running mean of the last MOTION_WINDOW filtered velocities (JCMA's v_avg), O(1) per update.
        self._recent_v.append((vx, vy))
        self._v_sum[0] += vx
        self._v_sum[1] += vy
        if len(self._recent_v) > MOTION_WINDOW:
            old_x, old_y = self._recent_v.popleft()
            self._v_sum[0] -= old_x
            self._v_sum[1] -= old_y

    def mean_velocity_px_s(self) -> tuple[float, float]:
        """Mean filtered velocity over the last MOTION_WINDOW observations (px/s)."""
        n = len(self._recent_v)
        return self._v_sum[0] / n, self._v_sum[1] / n

    def last_velocity_px_s(self) -> tuple[float, float]:
        """Filtered velocity right after the last observation (px/s)."""
        return self._recent_v[-1]

    def history_array(self) -> np.ndarray:
        """History as an ``(n, 9)`` array in :data:`HISTORY_FIELDS` order."""
        return np.asarray(self.history, dtype=np.float64)


def box_row(tr: Track) -> tuple[float, float, float, float]:
    """``tr.box_xyxy`` as Python floats."""
    cx, cy, w, h = tr.kf.mean[:4].tolist()
    return corners(cx, cy, w, h)


def box_rows(tracks: list[Track]) -> list[tuple[float, float, float, float]]:
    """:func:`box_row` of each track."""
    return [box_row(tr) for tr in tracks]


def boxes_xyxy(tracks: list[Track]) -> np.ndarray:
    """``(len(tracks), 4)`` array of ``tr.box_xyxy``."""
    if not tracks:
        return np.zeros((0, 4))
    if on_floats(len(tracks)):
        return np.array(box_rows(tracks), dtype=np.float64)
    m = np.array([tr.kf.mean[:4] for tr in tracks], dtype=np.float64)
    return np.column_stack(corners(m[:, 0], m[:, 1], m[:, 2], m[:, 3]))


def advance_tracks(tracks: list[Track], t: float) -> None:
    """``advance(t)`` for every track, vectorised over their filters."""
    if not tracks:
        return
    predict_many([tr.kf for tr in tracks], np.array([t - tr.kf_t for tr in tracks]))
    for tr in tracks:
        tr.kf_t = t
        tr.now_t = t


def update_tracks(
    tracks: list[Track], boxes_xyxy: np.ndarray, scores: np.ndarray, t: float, rels: list[tuple[float, float]]
) -> None:
    """Fuse one matched detection ``[x1, y1, x2, y2]`` (with its score and relative position) into
    each track at ``t``, the filters already predicted to ``t``: one batched Kalman step, then each
    track's bookkeeping."""
    if not tracks:
        return
    boxes = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4).tolist()
    measured = np.array([centre_size(x1, y1, x2, y2) for x1, y1, x2, y2 in boxes])
    update_many([tr.kf for tr in tracks], measured)
    for tr, (x1, y1, x2, y2), score, rel in zip(tracks, boxes, np.asarray(scores, dtype=np.float64).tolist(), rels):
        tr._record_update(x1, y1, x2, y2, score, t, rel)
