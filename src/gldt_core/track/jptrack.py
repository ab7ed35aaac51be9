"""JPTrack: ByteTrack's staged association with the JCMA cost and PMR recovery (paper, Tracking).

``JPTrack(JPTrackConfig())`` is the full tracker; ``use_pmr=False`` is the ablation's middle row
(JCMA only) and ``use_jcma=False, use_pmr=False`` falls back to ByteTrack's IoU association. Every
Table I value is a config field with the paper's default. What the paper leaves open is decided in
:mod:`.jcma` and :mod:`.pmr` (their docstrings say what and why); the remaining choices:

* ``t_h = 0.5``, ``t_l = 0.1`` and the new-track threshold 0.6 are ByteTrack's (the paper names
  ``t_h``/``t_l`` but gives no values); JCMA's gates (``jcma_thresh_*``) play the role of
  ByteTrack's IoU thresholds.
* Lost tracks take part in JCMA's first stage for ``lost_window_s`` (ByteTrack's 30-frame
  buffer, 1 s); after that only PMR can bring them back, for ``pmr_memory_s`` more seconds. With
  PMR off, lost tracks are forgotten after ``lost_window_s`` exactly like ByteTrack.
* PMR considers the remaining high-score and (``pmr_use_low``) low-score detections, as the
  paper's stage 3 does; a recovered track keeps its id and is reported in state RECOVERED. It runs
  before ByteTrack's tentative-track step, so a lost track's memory outranks a one-hit newborn.
* PMR models a lost track only once it has been lost for ``pmr_min_lost_s`` (0.1 s, three frames
  at 30 Hz): shorter gaps are handled by JCMA, whose first stage sees every recently lost track,
  and fitting a mixture for every single missed frame of 50 targets would break the 10 ms budget.
  The mixture is then fitted once and kept until the track is updated again.
* A track lost this very frame, or less than ``pmr_min_lost_s`` ago, is not in PMR's
  competition, yet a detection within its :func:`recovery_radius` is most likely its target
  seen off its path for a frame (jitter, a part of it boxed). PMR leaves such a detection to the
  following frames (``pmr_defer_to_just_lost``) rather than hand it to a track lost long ago:
  otherwise an old identity surfaces on a tracked target for a frame, two identity switches.
* ByteTrack's first stage offers a tracked track only the high-score detections, so on a frame
  where its own target is scored low it takes a high-score detection of a neighbour within its
  gate: a target back from more than ``lost_window_s`` of misses next to a tracked one loses its
  detection to it, and both identities switch. The first stage therefore gives a tracked track no
  high-score detection more than a box size off its prediction while a low-score detection lies
  within half a box size of it (``defer_to_own_low``); stage 2 then matches that one, and the
  high-score detection goes to PMR. Seen on the `crossing` tuning profile (experiment-log.md,
  Tracking, 2026-12-07).
* PMR leaves out the history samples of a track's first ``PMR_SETTLING_HITS`` updates: the
  Kalman velocity starts at 0 and takes a few updates to converge (a constant 5 px/frame target
  reads 0, 1.0 and 2.5 px/frame on its first three), and extrapolated to the loss time those
  samples sit far behind the target. With them in, a target seen for 6-8 frames and hidden for
  a second came back under a new id.
* PMR's ``tau_t`` gate is strict (P_final > 0.6 accepts a return within about a sigma), and a small
  target that manoeuvres through a miss burst comes back several sigmas off: under a new id. So
  before a one-hit tentative track is confirmed, ``_relink`` asks whether a lost track would have
  been where both of its sightings are (within :func:`recovery_radius`, the pre-gate of stage 3)
  and, if so, the tentative track continues the lost track's identity with its own, fresh filter:
  the new id is never shown. Candidate pairs are chosen by the likelihood of both sightings under
  each lost track's PMR mixture, so a track lost a frame ago outranks a wide hypothesis lost for
  seconds, and of their sizes against the lost track's (``relink_size_std``). Two sightings
  where one was expected is the evidence a single detection cannot give (``pmr_relink``;
  measured in docs/experiment-log.md, Tracking, 2026-12-05).
* PMR scores position only, so a lost track could take any object that surfaces where it is
  expected: another drone of a different size, or a bird. Stage 3 therefore takes a detection
  only if its size ``sqrt(w h)`` is within ``pmr_size_ratio`` (2.5) of the lost track's, whose
  box coasts at its last size (size velocities are zeroed once a track is lost, as ByteTrack
  does with the height: extrapolated, a noisy size rate swells or collapses the box over a
  second of coasting, and the planner sees that box). On the synthetic tuning profiles nearly
  every right recovery is within a factor 1.5, and a tighter gate does better there; 2.5 is the
  tightest that keeps a return on the real tuning clips. The relink is not gated by size (two
  sightings are stronger evidence; gated, it lost a return on the real tuning clips).
* ``pmr_vel_std`` (2 px per reference frame) is the unmodelled velocity change allowed during an
  occlusion: on the benchmark's real drone clips a tighter gate recovered too few tracks after
  1-2 s bursts of misses, while wider gates start to pick clutter (docs/experiment-log.md).
* The Kalman filter is on ``[cx, cy, w, h]`` with pixel floors under its noise (``kf_*``, see
  :mod:`.kalman`), for small targets on a shaking camera; ByteTrack keeps the reference filter.
  It also trusts a measured size less than a measured position (``kf_size_measurement_factor``,
  5 times ByteTrack's measurement noise on ``w`` and ``h``): a detector boxes a small drone
  tightly on one frame and loosely on the next, and with ByteTrack's noise the track's box took
  each size as it came; its size velocity still follows a drone closing in.
* A large, close drone is sometimes boxed whole and sometimes as two or three parts (body halves,
  a wing) by the detector. One part then keeps the track and shrinks its box, and another part
  starts a second track on the same drone; the two ids then take turns on it. So before stage 1,
  detections that lie inside the predicted box of a confirmed track of at least
  ``part_merge_min_size_px`` (``sqrt(w h)``), each at most :data:`PART_AREA_MAX` of its area and
  :data:`PART_INSIDE` inside it, are merged into their union box when that union matches the
  predicted box clearly better than any one of them (by :data:`PART_IOU_GAIN` IoU). Small targets,
  the usual case, are never merged: two drones inside one small box are more likely two drones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gldt_core.track.assignment import assign
from gldt_core.track.base import REATTACHED_RECOVER, MultiStageTracker, iou_pair_cost
from gldt_core.track.boxes import iou, midpoint
from gldt_core.track.fastpath import ARRAYS, FLOATS, Ops, V, on_floats
from gldt_core.track.jcma import JcmaWeights, TrackMotion, jcma_cost
from gldt_core.track.kalman import KalmanModel
from gldt_core.track.pmr import PmrModel, c_time, fit_pmr, floor_variance, mode_density, p_match_many
from gldt_core.track.state import Track, TrackState, box_row, boxes_xyxy, update_tracks

#: History samples from a track's first this-many updates are not used by PMR (module docstring).
PMR_SETTLING_HITS = 3
#: Parts of one tracked object (module docstring): a detection counts as a part of a track's
#: predicted box when this share of its area lies inside it and its area is at most PART_AREA_MAX
#: of the box's; parts merge when their union's IoU with the box beats the best part's by PART_IOU_GAIN.
PART_INSIDE = 0.7
PART_AREA_MAX = 0.7
PART_IOU_GAIN = 0.1


def settled_history(track: Track) -> np.ndarray:
    """The track's history without the samples recorded before its velocity settled (at least
    the newest sample is kept). The history deque may already have dropped the oldest rows."""
    history = track.history_array()
    unsettled = max(0, PMR_SETTLING_HITS - (track.hits - len(history)))
    return history[min(unsettled, len(history) - 1) :]


@dataclass(frozen=True)
class JPTrackConfig:
    """All JPTrack switches and weights; defaults are the paper's (Table I) where it gives them."""

    use_jcma: bool = True
    use_pmr: bool = True
    # Score split: the paper names t_h and t_l without values. t_h and the new-track threshold are
    # chosen by `gldt bench tracking-tune` on the tuning profiles (by the worst of them, against
    # ByteTrack+DIoU); ByteTrack's 0.5 / 0.6 left the real detector's drones scored 0.4-0.6 without
    # a track. The GL-DT system sets its own, calibrated values (system.config).
    t_h: float = 0.4
    t_l: float = 0.1
    new_track_thresh: float = 0.4
    # JCMA weights (Table I): w1..w4 of eq. 9, beta1..beta3 of eq. 13.
    w1: float = 0.3
    w2: float = 0.3
    w3: float = 0.2
    w4: float = 0.2
    beta1: float = 0.4
    beta2: float = 0.4
    beta3: float = 0.2
    # JCMA gates per stage (maximum joint cost of a match).
    jcma_thresh_high: float = 0.7
    jcma_thresh_low: float = 0.6
    jcma_thresh_tentative: float = 0.6
    # PMR (Table I: gamma, tau_t).
    gamma: float = 0.1
    tau_t: float = 0.6
    pmr_pos_std_size: float = 0.5
    pmr_vel_std: float = 2.0
    pmr_use_low: bool = True
    pmr_memory_s: float = 3.0
    pmr_min_lost_s: float = 0.1
    # A lost track takes over a tentative track seen where it would be at both sightings, so that
    # a target missed for longer than PMR's gate forgives comes back under its id (module docstring).
    pmr_relink: bool = True
    # PMR gives no lost track a detection within reach of a track lost under pmr_min_lost_s ago
    # (module docstring).
    pmr_defer_to_just_lost: bool = True
    # Stage 1 gives a tracked track no high-score detection off its prediction while a low-score
    # detection lies on it (its own target, scored low this frame; module docstring).
    defer_to_own_low: bool = True
    pmr_backend: str = "numpy"  # "numpy" (same EM as scikit-learn, faster) or "sklearn"
    # PMR (stage 3) brings a lost track back only with a detection whose size sqrt(w h) is within
    # this factor of the track's own (module docstring); a large value (1e9) turns the gate off.
    pmr_size_ratio: float = 2.5
    # The relink ranks its candidate pairs by the likelihood of both sightings' positions and
    # sizes; a sighting's log size ratio to the lost track's is taken as Gaussian with this std.
    relink_size_std: float = 0.3
    # Shared.
    lost_window_s: float = 1.0
    ref_fps: float = 30.0
    history_len: int = 30
    image_size: tuple[int, int] = (1920, 1080)
    # ByteTrack's IoU thresholds, used only when use_jcma is False.
    iou_match_thresh: float = 0.8
    iou_second_thresh: float = 0.5
    iou_unconfirmed_thresh: float = 0.7
    # Start a confirmed track from a low-score detection seen at the same place this many frames
    # running (0: off, the paper's behaviour; see gldt_core.track.birth).
    low_score_birth_frames: int = 0
    # Floors of the Kalman filter's noise, in pixels (gldt_core.track.kalman, KalmanModel): the
    # smallest size-proportional std (keeps 2 px boxes well conditioned); the centre's process
    # noise per reference frame, how far the camera's shake and turn can move any target between
    # two frames (1/20 of the size reaches it at 30 px; chosen on the real validation clips with
    # the shipped detectors); a new track's centre-velocity std per reference frame, since a drone
    # can cross the image at a few pixels per frame whatever its size (10/160 of the size reaches
    # it at 32 px). docs/experiment-log.md (Tracking, 2026-12-03) has the measurements.
    kf_min_std_px: float = 0.5
    kf_centre_process_floor_px: float = 1.5
    kf_birth_velocity_floor_px: float = 2.0
    # The measurement noise of the box size (w, h) as a multiple of ByteTrack's 1/20 of the size
    # (KalmanModel.size_measurement_factor): chosen on the tuning profiles by their worst, beside
    # 1, 2, 3, 8 and 12 (docs/experiment-log.md, Tracking, 2026-12-07 evening).
    kf_size_measurement_factor: float = 5.0
    # Detections that are parts of one confirmed track at least this large (sqrt(w h), px) merge
    # into one before association (module docstring); 0 turns it off.
    part_merge_min_size_px: float = 40.0

    def __post_init__(self) -> None:
        if not self.part_merge_min_size_px >= 0.0:
            raise ValueError(f"part_merge_min_size_px must be >= 0 (0: off), got {self.part_merge_min_size_px!r}")
        if not self.pmr_size_ratio >= 1.0:
            raise ValueError(
                f"pmr_size_ratio must be >= 1 (a large value turns the size gate off), got {self.pmr_size_ratio!r}"
            )
        if not self.relink_size_std > 0.0:
            raise ValueError(
                f"relink_size_std must be > 0 (a large value ranks by position only), got {self.relink_size_std!r}"
            )

    def kalman_model(self) -> KalmanModel:
        """The filter of JPTrack's tracks: ``[cx, cy, w, h]`` with the ``kf_*`` floors."""
        return KalmanModel(
            min_std_px=self.kf_min_std_px,
            min_centre_process_std_px=self.kf_centre_process_floor_px,
            min_birth_centre_velocity_std_px=self.kf_birth_velocity_floor_px,
            size_measurement_factor=self.kf_size_measurement_factor,
        )

    def weights(self) -> JcmaWeights:
        return JcmaWeights(
            w_iou=self.w1,
            w_dist=self.w2,
            w_motion=self.w3,
            w_rel=self.w4,
            b_speed=self.beta1,
            b_direction=self.beta2,
            b_acceleration=self.beta3,
        )


class JPTrack(MultiStageTracker):
    """``JPTrack(config).update(dets, t) -> (M, 6) [x1, y1, x2, y2, track_id, score]``."""

    def __init__(self, config: JPTrackConfig | None = None) -> None:
        self.config = config or JPTrackConfig()
        c = self.config
        self._weights = c.weights()
        memory = c.lost_window_s + (c.pmr_memory_s if c.use_pmr else 0.0)
        super().__init__(
            t_high=c.t_h,
            t_low=c.t_l,
            new_track_thresh=c.new_track_thresh,
            jcma_window_s=c.lost_window_s,
            memory_s=memory,
            ref_fps=c.ref_fps,
            history_len=c.history_len,
            image_size=c.image_size,
            low_score_birth_frames=c.low_score_birth_frames,
            kalman=c.kalman_model(),
            coasting_stops=(6, 7),  # a lost box coasts at its last size (module docstring)
        )
        #: Number of PMR mixtures fitted since construction (the bench reports it).
        self.pmr_fits = 0
        if c.pmr_backend not in ("numpy", "sklearn"):
            raise ValueError(f"pmr_backend must be 'numpy' or 'sklearn', got {c.pmr_backend!r}")
        if c.use_pmr and c.pmr_backend == "sklearn":
            import sklearn.mixture  # noqa: F401  (import now, not on the first lost track)

    def reset(self) -> None:
        super().reset()
        #: Per-frame cache of :meth:`_motion_row`: ``id(track) -> (hits, row)`` for time ``_motion_t``.
        self._motion_rows: dict[int, tuple[int, tuple[float, ...]]] = {}
        self._motion_t: float | None = None

    # --- stage costs ------------------------------------------------------------------------
    def _pair_cost(
        self, stage: str, tracks: Sequence[Track], dets: np.ndarray, det_idx: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, float]:
        c = self.config
        if not c.use_jcma:
            thresh = {self.STAGE_HIGH: c.iou_match_thresh, self.STAGE_LOW: c.iou_second_thresh}.get(
                stage, c.iou_unconfirmed_thresh
            )
            return iou_pair_cost(tracks, dets, det_idx, thresh, stage != self.STAGE_LOW)
        thresh = {self.STAGE_HIGH: c.jcma_thresh_high, self.STAGE_LOW: c.jcma_thresh_low}.get(
            stage, c.jcma_thresh_tentative
        )
        n_t, n_d = len(tracks), len(det_idx)
        if n_t == 0 or n_d == 0:
            return np.zeros((n_t, n_d)), np.zeros((n_t, n_d), dtype=bool), thresh
        motion = TrackMotion(self._motion_rows_for(tracks, t), [tr.hits >= 2 for tr in tracks])
        # Eq. 15's other objects: the pool's tracks at their predicted centres.
        cost, gate = jcma_cost(motion, dets[det_idx, :4], None, None, self._weights)
        allowed = gate & (cost <= thresh)
        if stage == self.STAGE_HIGH and c.defer_to_own_low:
            self._defer_to_own_low(tracks, motion, dets, det_idx, allowed)
        return cost, allowed, thresh

    def _defer_to_own_low(
        self, tracks: Sequence[Track], motion: TrackMotion, dets: np.ndarray, det_idx: np.ndarray, allowed: np.ndarray
    ) -> None:
        """Disallow (in ``allowed``, stage 1's mask) the pairs of a tracked (not lost) track and a
        high-score detection more than a box size off its prediction while a low-score detection
        lies within half a box size of it (module docstring). Plain Python over the few tracks
        that have such a pair: this runs on every frame."""
        _, low_rows = self._score_split(dets[:, 4])
        candidates = np.flatnonzero(allowed.any(axis=1))
        if len(low_rows) == 0 or len(candidates) == 0:
            return
        low = [((x1 + x2) / 2, (y1 + y2) / 2) for x1, y1, x2, y2 in dets[low_rows, :4].tolist()]
        high: list[tuple[float, float]] | None = None
        for i in candidates.tolist():
            if tracks[i].state is TrackState.LOST:
                continue
            x1, y1, x2, y2 = motion.rows[i][:4]
            px, py = (x1 + x2) / 2, (y1 + y2) / 2
            size = max(0.5 * ((x2 - x1) + (y2 - y1)), 1.0)
            if not any((lx - px) ** 2 + (ly - py) ** 2 < (0.5 * size) ** 2 for lx, ly in low):
                continue
            if high is None:
                high = [((x1 + x2) / 2, (y1 + y2) / 2) for x1, y1, x2, y2 in dets[det_idx, :4].tolist()]
            off = [j for j, (hx, hy) in enumerate(high) if (hx - px) ** 2 + (hy - py) ** 2 > size**2]
            allowed[i, off] = False

    def _motion_rows_for(self, tracks: Sequence[Track], t: float) -> list[tuple[float, ...]]:
        """:meth:`_motion_row` of each track (the :class:`TrackMotion` rows of the pool). A row is
        kept for the frame (stage 2 re-costs the tracks stage 1 left unmatched); any update in
        between bumps ``hits`` and so invalidates it."""
        if t != self._motion_t:
            self._motion_rows.clear()
            self._motion_t = t
        cache = self._motion_rows
        rows = []
        for tr in tracks:
            hit = cache.get(id(tr))
            if hit is None or hit[0] != tr.hits:
                hit = (tr.hits, self._motion_row(tr, t))
                cache[id(tr)] = hit
            rows.append(hit[1])
        return rows

    def _motion_row(self, tr: Track, t: float) -> tuple[float, ...]:
        """One track's motion row, the :data:`gldt_core.track.jcma.MOTION_COLUMNS`: predicted box,
        last observed centre, elapsed reference frames, mean and last velocity."""
        x1, y1, x2, y2 = box_row(tr)
        (ax, ay), (lx, ly) = self._velocities(tr)
        ox, oy = tr.last_obs_xy
        elapsed = max((t - tr.last_update_t) * self.config.ref_fps, 1e-6)
        return (x1, y1, x2, y2, ox, oy, elapsed, ax, ay, lx, ly)

    def _velocities(self, tr: Track) -> tuple[tuple[float, float], tuple[float, float]]:
        """Mean (over ``state.MOTION_WINDOW`` observations) and last filtered velocity, in px per
        reference frame."""
        ref = self.config.ref_fps
        ax, ay = tr.mean_velocity_px_s()
        lx, ly = tr.last_velocity_px_s()
        return (ax / ref, ay / ref), (lx / ref, ly / ref)

    # --- before stage 1: parts of one object -------------------------------------------------
    def _merge_parts(
        self, dets: np.ndarray, rois: np.ndarray | None, active: list[Track]
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Merge the detections that are parts of one large confirmed track into their union box
        (module docstring), with the best part's score and ROI (the union's centre is placed in it)."""
        floor = self.config.part_merge_min_size_px
        if floor <= 0.0 or len(dets) < 2:
            return dets, rois
        boxes = boxes_xyxy(active)
        if not len(boxes):
            return dets, rois
        box_areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        large = np.flatnonzero(box_areas >= floor * floor)
        if not len(large):
            return dets, rois
        det_areas = np.maximum((dets[:, 2] - dets[:, 0]) * (dets[:, 3] - dets[:, 1]), 1e-9)
        scored = dets[:, 4] >= self._t_low
        taken = np.zeros(len(dets), dtype=bool)
        merged: list[tuple[np.ndarray, int]] = []  # the union row, its best part
        for k in large[np.argsort(-box_areas[large], kind="stable")]:  # the largest first
            box = boxes[k]
            inside_w = np.clip(np.minimum(dets[:, 2], box[2]) - np.maximum(dets[:, 0], box[0]), 0.0, None)
            inside_h = np.clip(np.minimum(dets[:, 3], box[3]) - np.maximum(dets[:, 1], box[1]), 0.0, None)
            inside = inside_w * inside_h
            parts = np.flatnonzero(
                scored & ~taken & (inside >= PART_INSIDE * det_areas) & (det_areas <= PART_AREA_MAX * box_areas[k])
            )
            if len(parts) < 2:
                continue
            union = [*dets[parts, :2].min(axis=0).tolist(), *dets[parts, 2:4].max(axis=0).tolist()]
            best_part = float(np.max(inside[parts] / (det_areas[parts] + box_areas[k] - inside[parts])))
            if iou(FLOATS, *union, *box.tolist()) < best_part + PART_IOU_GAIN:
                continue
            best = int(parts[np.argmax(dets[parts, 4])])
            merged.append((np.array([*union, dets[best, 4]]), best))
            taken[parts] = True
        if not merged:
            return dets, rois
        rows = np.vstack([dets[~taken], np.array([row for row, _ in merged])])
        if rois is None:
            return rows, None
        return rows, np.vstack([rois[~taken], rois[[best for _, best in merged]]])

    # --- stage 3: PMR -----------------------------------------------------------------------
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
        c = self.config
        if not c.use_pmr or not lost:
            return rest_high, rest_low
        cand = np.concatenate([rest_high, rest_low]) if c.pmr_use_low else rest_high
        if len(cand) == 0:
            return rest_high, rest_low
        # Gaps shorter than pmr_min_lost_s are JCMA's job (the lost track is in its first-stage
        # pool every frame); modelling them would fit a mixture for every single missed frame.
        long_lost = [i for i, tr in enumerate(lost) if t - tr.last_update_t >= c.pmr_min_lost_s - 1e-9]
        if not long_lost and c.tau_t >= 0.0:
            return rest_high, rest_low  # every score would be 0: nothing can pass the gate
        centres = midpoint(dets[cand, :2], dets[cand, 2:4])
        rows = []
        if long_lost:
            worth = self._worth_modelling([lost[i] for i in long_lost], centres, t)
            rows = [i for i, w in zip(long_lost, worth) if w]
        if not rows and c.tau_t >= 0.0:
            return rest_high, rest_low  # every score is 0, nothing can pass the gate
        models = self._pmr_models([lost[i] for i in rows])
        score = np.zeros((len(lost), len(cand)))
        if rows:
            final = self._p_final(models, centres, t)
            final *= self._size_consistent([lost[i] for i in rows], dets[cand, 2:4] - dets[cand, :2])
            if c.tau_t >= 0.0 and not (final > c.tau_t).any():
                return rest_high, rest_low  # no candidate passes the gate (most frames)
            score[rows] = final
        allowed = score > c.tau_t
        just_lost = [tr for tr in lost if t - tr.last_update_t < c.pmr_min_lost_s - 1e-9]
        if just_lost and c.pmr_defer_to_just_lost:  # only on the rare frames where a pair passes
            allowed[:, self._near_prediction(just_lost, centres, t).any(axis=0)] = False
        # As a cost 1 - P_final with limit 1 - tau_t: a pair is worth matching exactly when it
        # passes the gate, and a conflict goes to the largest total margin sum(P_final - tau_t).
        pairs = assign(1.0 - score, allowed, 1.0 - c.tau_t)
        if not pairs:
            return rest_high, rest_low
        recovered = [lost[r] for r, _ in pairs]
        used = [int(cand[col]) for _, col in pairs]
        update_tracks(recovered, dets[used, :4], dets[used, 4], t, [rel[d] for d in used])
        for tr in recovered:
            tr.state = TrackState.RECOVERED
            updated.add(id(tr))
            if self.reattachments is not None:
                self.reattachments.append((t, tr.track_id, REATTACHED_RECOVER))
        keep_high = np.asarray([d for d in rest_high if d not in used], dtype=np.int64)
        keep_low = np.asarray([d for d in rest_low if d not in used], dtype=np.int64)
        return keep_high, keep_low

    def _relink(
        self, confirming: list[tuple[Track, int]], dets: np.ndarray, t: float, updated: set[int]
    ) -> list[tuple[Track, Track]]:
        """A tentative track about to be confirmed is a lost target back when both of its
        sightings (its first detection and the confirming one) lie within
        :func:`recovery_radius` of the lost track's prediction at their times. It then continues
        the lost track's identity (id, start; reported RECOVERED) with its own filter, fitted to
        where the target is now (the lost track's, updated with one detection after the gap, kept
        its old velocity and lost the target again at once), and the lost track is dropped; the
        tentative track's new id is never shown. Every lost track competes, the recently lost
        ones (within ``pmr_min_lost_s``) included, but only one lost before the first sighting;
        pairs are chosen jointly by the likelihood of both sightings under each lost track's PMR
        mixture (its density, not P_final: P_final is relative to each mixture's own mode and
        would prefer the widest, longest-lost hypothesis to a track lost a frame ago), times the
        likelihood of both sightings' sizes (``relink_size_std``): two lost tracks in reach are
        told apart by the size of what came back."""
        c = self.config
        if not confirming or not c.use_pmr or not c.pmr_relink:
            return []
        lost = [tr for tr in self._tracks if tr.state is TrackState.LOST and id(tr) not in updated]
        if not lost:
            return []
        second = midpoint(dets[[d for _, d in confirming], :2], dets[[d for _, d in confirming], 2:4])
        allowed = self._near_prediction(lost, second, t)
        lost_t = np.array([tr.last_update_t for tr in lost])
        first_ts = np.array([tent.last_update_t for tent, _ in confirming])
        allowed &= lost_t[:, None] < first_ts[None, :]
        for first_t in set(first_ts[allowed.any(axis=0)].tolist()):
            cols = (first_ts == first_t).nonzero()[0]
            first = np.array([confirming[i][0].last_obs_xy for i in cols], dtype=np.float64)
            allowed[:, cols] &= self._near_prediction(lost, first, first_t)
        keep = np.flatnonzero(allowed.any(axis=1))
        if len(keep) == 0:
            return []
        lost = [lost[i] for i in keep]
        allowed = allowed[keep]
        models = self._pmr_models(lost)
        cost = self._negative_log_density(models, second, t)
        for first_t in set(first_ts.tolist()):
            cols = (first_ts == first_t).nonzero()[0]
            first = np.array([confirming[i][0].last_obs_xy for i in cols], dtype=np.float64)
            cost[:, cols] += self._negative_log_density(models, first, first_t)
        second_boxes = dets[[d for _, d in confirming], :4]
        for wh in (second_boxes[:, 2:4] - second_boxes[:, :2], np.array([tent.last_obs_wh for tent, _ in confirming])):
            cost += 0.5 * (self._log_size_ratio(lost, wh) / c.relink_size_std) ** 2
        allowed &= np.isfinite(cost)
        if not allowed.any():
            return []
        pairs = assign(cost, allowed, float(cost[allowed].max()) + 1.0)
        return [(confirming[col][0], lost[row]) for row, col in pairs]

    def _size_consistent(self, lost: list[Track], wh: np.ndarray) -> np.ndarray:
        """``(len(lost), len(wh))``: whether each detection of width and height ``wh`` has a size
        ``sqrt(w h)`` within a factor ``pmr_size_ratio`` of each lost track's."""
        return self._log_size_ratio(lost, wh) <= np.log(self.config.pmr_size_ratio)

    @staticmethod
    def _log_size_ratio(lost: list[Track], wh: np.ndarray) -> np.ndarray:
        """``(len(lost), len(wh))``: ``|log|`` of each detection's size ``sqrt(w h)`` over each lost
        track's (its filter's size, held while lost)."""
        held = np.array([tr.kf.mean[2] * tr.kf.mean[3] for tr in lost], dtype=np.float64)
        area = np.asarray(wh, dtype=np.float64).reshape(-1, 2).prod(axis=1)
        return 0.5 * np.abs(np.log(np.maximum(area, 1e-12)[None, :] / np.maximum(held, 1e-12)[:, None]))

    def _negative_log_density(self, models: list[PmrModel], centres: np.ndarray, t: float) -> np.ndarray:
        """``-log(P_final * mode density)`` of each model (row) at each centre (column) at ``t``:
        the time-weighted mixture density, without the common ``1 / 2 pi``."""
        c = self.config
        density = (
            self._p_final(models, centres, t)
            * mode_density(models, t, c.ref_fps, c.pmr_pos_std_size, c.pmr_vel_std)[:, None]
        )
        with np.errstate(divide="ignore"):
            return -np.log(density)  # inf where the density underflows

    def _pmr_models(self, tracks: list[Track]) -> list[PmrModel]:
        """Each lost track's PMR mixture, fitted on first use and kept until the track is updated."""
        c = self.config
        models = []
        for tr in tracks:
            if tr.pmr_model is None:
                tr.pmr_model = fit_pmr(settled_history(tr), tr.last_update_t, c.gamma, c.ref_fps, backend=c.pmr_backend)
                self.pmr_fits += 1
            models.append(tr.pmr_model)
        return models

    def lost_track_p_final(self, track: Track, centres: np.ndarray, t: float) -> np.ndarray:
        """PMR's P_final (eq. 22) of the lost ``track`` for detection centres ``(D, 2)`` at ``t``, as
        stage 3 scores them; fits the track's mixture if it has none yet, without keeping it."""
        c = self.config
        model = track.pmr_model or fit_pmr(
            settled_history(track), track.last_update_t, c.gamma, c.ref_fps, backend=c.pmr_backend
        )
        return self._p_final([model], np.asarray(centres, dtype=np.float64).reshape(-1, 2), t)[0]

    def _p_final(self, models: list[PmrModel], centres: np.ndarray, t: float) -> np.ndarray:
        """Eq. 22, ``P_match * C_time``, of each model (row) for each detection centre (column) at ``t``."""
        c = self.config
        p = p_match_many(models, centres, t, c.ref_fps, c.pmr_pos_std_size, c.pmr_vel_std)
        return p * np.array([c_time(m, t, c.gamma) for m in models])[:, None]

    def _worth_modelling(self, lost: list[Track], centres: np.ndarray, t: float) -> list[bool]:
        """Cheap pre-gate, one boolean per lost track: fit/evaluate a mixture only if some candidate
        centre lies within :func:`recovery_radius` of the track's Kalman prediction. P_final > tau_t
        needs the detection within about one sigma of a component, and components sit near the
        constant-velocity prediction, so this rejects only hopeless pairs; it keeps EM off frames
        where nothing is near a lost track."""
        c = self.config
        if on_floats(len(lost) * len(centres)):
            points = centres.tolist()
            worth = []
            for tr in lost:
                cx, cy, w, h, vx, vy = tr.kf.mean[:6].tolist()
                ahead = t - tr.kf_t  # 0 in a frame's update: the filters are advanced to it
                cx, cy = cx + vx * ahead, cy + vy * ahead
                steps = (t - tr.last_update_t) * c.ref_fps
                radius = recovery_radius(FLOATS, w, h, vx, vy, steps, c)
                worth.append(any(squared_distance(x, y, cx, cy) <= radius * radius for x, y in points))
            return worth
        return np.any(self._near_prediction(lost, centres, t), axis=1).tolist()

    def _near_prediction(self, lost: list[Track], centres: np.ndarray, t: float) -> np.ndarray:
        """``(len(lost), len(centres))``: whether each centre, seen at ``t``, lies within
        :func:`recovery_radius` of each lost track's Kalman prediction for ``t`` (the filter's
        constant-velocity path, also for a ``t`` before the filter's own time)."""
        c = self.config
        means = np.array([tr.kf.mean[:6] for tr in lost])
        ahead = t - np.array([tr.kf_t for tr in lost])
        x = means[:, 0] + means[:, 4] * ahead
        y = means[:, 1] + means[:, 5] * ahead
        since_loss = (t - np.array([tr.last_update_t for tr in lost])) * c.ref_fps
        radii = recovery_radius(ARRAYS, means[:, 2], means[:, 3], means[:, 4], means[:, 5], since_loss, c)
        d2 = squared_distance(centres[None, :, 0], centres[None, :, 1], x[:, None], y[:, None])
        return d2 <= (radii * radii)[:, None]


def recovery_radius(ops: Ops[V], w: V, h: V, vx: V, vy: V, steps: V | float, c: JPTrackConfig) -> V:
    """How far from its Kalman prediction (box ``w x h``, velocity ``vx, vy`` px/s) a lost track's
    detection may lie, ``steps`` reference frames after the loss, and still be worth modelling:
    three sigmas of PMR's floor (:func:`gldt_core.track.pmr.floor_variance`), half the distance
    travelled since the loss, and two box sizes."""
    size = 0.5 * (w + h)
    speed = ops.hypot(vx, vy) / c.ref_fps
    floor = floor_variance(size, steps, c.pmr_pos_std_size, c.pmr_vel_std)
    return 3.0 * ops.sqrt(floor) + 0.5 * speed * steps + 2.0 * size


def squared_distance(x1: V, y1: V, x2: V, y2: V) -> V:
    """``|(x1, y1) - (x2, y2)|^2``."""
    dx = x1 - x2
    dy = y1 - y2
    return dx * dx + dy * dy
