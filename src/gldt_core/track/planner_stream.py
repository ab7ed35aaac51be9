"""The planner's view of the tracks: every live track in every frame, and each id's life whole.

A tracker reports the tracks it matched in a frame (the MOT rows that metrics count). An avoidance
planner needs more: an obstacle must not vanish because the detector missed it once. So each frame
the stream holds

* every matched track (``confirmed``, or ``recovered`` on the frame a lost track came back),
* every coasting track (``lost``: the filter's predicted box and its growing covariance, with
  ``frames_since_update`` > 0), for as long as the tracker keeps it for recovery,
* once, a final ``removed`` entry for each id the tracker gave up (expired, merged into a
  duplicate, or dropped by a restart of the stream), at its last prediction.

A frame no detector measured (:meth:`PlannerStream.predicted`: the graph skipped it by plan
because the global detector was still busy) gets every live track at its prediction for that
frame's time, in the state of the last measured frame: the tracker is not updated, so a skip is
never counted as a miss.

From its first entry to its ``removed`` one an id is in every frame: no holes. Tentative tracks
(one hit so far) are not in the stream. Ids are never reused within one stream: after a restart
(the tracker is re-initialised and its ids start again at 1) the published ids continue above the
largest one published so far; before any restart they equal the tracker's, so the stream's
matched entries are exactly the tracker's output rows.

Each entry also carries what a planner steers by: the track's class from the evidence of its whole
life (:mod:`.class_evidence`), a filtered time to collision with its standard deviation
(:mod:`.looming`) and, given a camera model, the bearing of the box centre with its covariance
(:mod:`gldt_core.camera`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from gldt_core.camera import CameraModel, bearing, bearing_covariance, bearing_rate, line_of_sight
from gldt_core.track.class_evidence import ClassEvidence
from gldt_core.track.kalman import predicted_many
from gldt_core.track.looming import NO_ESTIMATE, LoomingEstimate, LoomingTracks
from gldt_core.track.state import Track, TrackState

#: State names of the stream and their codes in ``gldt_msgs/Track`` (``STATE_*``).
STATE_CODES = {"tentative": 0, "confirmed": 1, "lost": 2, "recovered": 3, "removed": 4}
#: States of entries matched with a detection in their frame (the tracker's output rows).
MATCHED_STATES = ("confirmed", "recovered")

_STREAM_STATE = {TrackState.CONFIRMED: "confirmed", TrackState.LOST: "lost", TrackState.RECOVERED: "recovered"}


@dataclass(frozen=True)
class Bearing:
    """Direction of a box centre seen from the camera (conventions: :mod:`gldt_core.camera`)."""

    line_of_sight: tuple[float, float, float]
    azimuth: float
    elevation: float
    azimuth_rate: float
    elevation_rate: float
    #: 2x2 row-major covariance of (azimuth, elevation) [rad^2].
    covariance: tuple[float, float, float, float]


@dataclass(frozen=True)
class PlannerTrack:
    """One entry of the stream: a track as a planner consumes it in one frame."""

    track_id: int
    state: str
    center_x: float
    center_y: float
    width: float
    height: float
    velocity_x: float
    velocity_y: float
    #: 8x8 Kalman covariance of ``[cx, cy, w, h, vx, vy, vw, vh]``.
    covariance: np.ndarray
    age_s: float
    hits: int
    frames_since_update: int
    score: float
    class_id: int
    class_confidence: float
    looming: LoomingEstimate
    bearing: Bearing | None

    @property
    def matched(self) -> bool:
        """Matched with a detection in this frame (one of the tracker's output rows)."""
        return self.state in MATCHED_STATES and self.frames_since_update == 0


class PlannerStream:
    """Builds each frame's entries from the tracker's tracks; :meth:`step` once per frame."""

    def __init__(self, class_evidence: ClassEvidence | None = None, looming: LoomingTracks | None = None) -> None:
        self.class_evidence = class_evidence if class_evidence is not None else ClassEvidence()
        self.looming = looming if looming is not None else LoomingTracks()
        #: Tracks in the stream now, by the tracker's id, with the entry they were last published as.
        self._open: dict[int, tuple[Track, PlannerTrack]] = {}
        self._closing: list[PlannerTrack] = []
        self._id_offset = 0
        self._largest_id = 0

    def step(
        self,
        tracks: Sequence[Track],
        t: float,
        matched_rows: np.ndarray,
        detections: np.ndarray,
        probabilities: np.ndarray,
        camera: CameraModel | None = None,
        source: object = None,
    ) -> list[PlannerTrack]:
        """This frame's entries, oldest track first, then the ids removed since the last frame.

        ``tracks`` are the tracker's live tracks after its update at ``t``, ``matched_rows`` its
        output ``(M, >=5)`` ``[x1, y1, x2, y2, id, ...]``, ``detections`` ``(N, >=4)`` and
        ``probabilities`` ``(N, 3)`` the frame's detections and their class probabilities;
        ``source`` names the detector that produced them (the frame's mode), whose boxes' scale
        the time to collision must not take for a change of range (:mod:`.looming`).
        """
        self.class_evidence.update(matched_rows, detections, probabilities)
        live = [tr for tr in tracks if tr.state in _STREAM_STATE]
        sizes = [(self.published_id(tr), _measured_size(tr)) for tr in live]
        estimates = self.looming.update(t, sizes, source)
        entries = [
            self._entry(tr, _STREAM_STATE[tr.state], estimates[pid], camera) for tr, (pid, _) in zip(live, sizes)
        ]
        return self._publish(live, entries)

    def absorb(self, matched_rows: np.ndarray, detections: np.ndarray, probabilities: np.ndarray) -> None:
        """Take the class evidence of a frame whose answer was already published (by prediction, at
        a deadline) when its detections came: the tracker was updated with them, nothing is
        published for them, and the next frame's entries show the tracks as they are now (ids
        ended meanwhile close there, ids born meanwhile open there)."""
        self.class_evidence.update(matched_rows, detections, probabilities)

    def predicted(self, tracks: Sequence[Track], t: float, camera: CameraModel | None = None) -> list[PlannerTrack]:
        """The entries of a frame at ``t`` that no detector measured: every live track of the
        tracker (which was not updated) at its filter's prediction for ``t``, box, velocity and
        covariance, in its last state; the time to collision coasts. Ids removed by a restart
        since the last frame close here, as in :meth:`step`."""
        live = [tr for tr in tracks if tr.state in _STREAM_STATE]
        means, covariances = predicted_many([tr.kf for tr in live], np.array([t - tr.kf_t for tr in live]))
        estimates = self.looming.update(t, [(self.published_id(tr), None) for tr in live])
        entries = [
            self._entry(tr, _STREAM_STATE[tr.state], estimates[self.published_id(tr)], camera, mean, covariance)
            for tr, mean, covariance in zip(live, means, covariances)
        ]
        return self._publish(live, entries)

    def _publish(self, live: list[Track], entries: list[PlannerTrack]) -> list[PlannerTrack]:
        """Note ``entries`` as each live track's last, close the ids no longer live; the frame's
        entries followed by the ``removed`` ones."""
        now = {tr.track_id for tr in live}
        for track_id, (track, last) in list(self._open.items()):
            if track_id not in now:
                self._closing.append(_removed(last, track))
                del self._open[track_id]
        for tr, entry in zip(live, entries):
            self._open[tr.track_id] = (tr, entry)
            self._largest_id = max(self._largest_id, entry.track_id)
        closing, self._closing = self._closing, []
        return entries + closing

    def restart(self) -> None:
        """The tracker was re-initialised (its ids start again): every open id gets its final
        ``removed`` entry in the next frame, and later ids continue above the largest one."""
        self._closing.extend(_removed(last, track) for track, last in self._open.values())
        self._open.clear()
        self._id_offset = self._largest_id
        self.class_evidence.reset()
        self.looming.reset()

    def published_id(self, track: Track) -> int:
        """The id ``track`` is published with (the tracker's, above the ids before the last restart)."""
        return track.track_id + self._id_offset

    def _entry(
        self,
        track: Track,
        state: str,
        looming: LoomingEstimate,
        camera: CameraModel | None,
        mean: np.ndarray | None = None,
        covariance: np.ndarray | None = None,
    ) -> PlannerTrack:
        """The entry of ``track``: at its filter's state, or at ``mean`` / ``covariance`` (a prediction)."""
        cx, cy, w, h, vx, vy = (track.kf.mean if mean is None else mean)[:6].tolist()
        covariance = track.covariance if covariance is None else np.array(covariance)
        class_id, confidence = self.class_evidence.label(track.track_id)
        return PlannerTrack(
            track_id=self.published_id(track),
            state=state,
            center_x=cx,
            center_y=cy,
            width=w,
            height=h,
            velocity_x=vx,
            velocity_y=vy,
            covariance=covariance,
            age_s=track.age_s,
            hits=track.hits,
            frames_since_update=track.frames_since_update,
            score=track.score,
            class_id=class_id,
            class_confidence=confidence,
            looming=looming,
            bearing=None if camera is None else bearing_of(camera, cx, cy, vx, vy, covariance[:2, :2]),
        )


def bearing_of(
    camera: CameraModel, u: float, v: float, du_dt: float, dv_dt: float, pixel_covariance: np.ndarray
) -> Bearing:
    """The :class:`Bearing` of pixel ``(u, v)`` moving at ``(du/dt, dv/dt)`` px/s."""
    azimuth, elevation = bearing(camera, u, v)
    azimuth_rate, elevation_rate = bearing_rate(camera, u, v, du_dt, dv_dt)
    ray = np.asarray(line_of_sight(camera, u, v), dtype=np.float64).reshape(3)
    covariance = np.asarray(bearing_covariance(camera, u, v, pixel_covariance), dtype=np.float64).reshape(4)
    return Bearing(
        line_of_sight=(float(ray[0]), float(ray[1]), float(ray[2])),
        azimuth=float(azimuth),
        elevation=float(elevation),
        azimuth_rate=float(azimuth_rate),
        elevation_rate=float(elevation_rate),
        covariance=(float(covariance[0]), float(covariance[1]), float(covariance[2]), float(covariance[3])),
    )


def _measured_size(track: Track) -> float | None:
    """The geometric size ``sqrt(w h)`` of the detection matched now; ``None`` while coasting."""
    if track.frames_since_update != 0:
        return None
    w, h = track.last_obs_wh
    return float(np.sqrt(max(w, 0.0) * max(h, 0.0)))


def _removed(last: PlannerTrack, track: Track) -> PlannerTrack:
    """The final entry of an id: its last published entry, at the track's last prediction."""
    cx, cy, w, h, vx, vy = track.kf.mean[:6].tolist()
    return replace(
        last,
        state="removed",
        center_x=cx,
        center_y=cy,
        width=w,
        height=h,
        velocity_x=vx,
        velocity_y=vy,
        covariance=track.covariance,
        frames_since_update=track.frames_since_update,
        looming=NO_ESTIMATE,
    )
